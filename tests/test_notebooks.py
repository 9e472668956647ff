"""Every notebook in notebooks/ runs top to bottom without error."""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).parents[1] / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path, tmp_path):
    notebook = nbformat.read(path, as_version=4)
    NotebookClient(
        notebook,
        timeout=300,
        kernel_name="python3",
        resources={"metadata": {"path": str(tmp_path)}},
    ).execute()
    errors = [o for c in notebook.cells for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors


def test_quickstart_is_present():
    assert any(p.name == "quickstart.ipynb" for p in NOTEBOOKS)


def test_own_data_is_stored_executed_with_its_figures():
    """The own-data notebook is stored with the outputs a reader sees: its one-step table and
    the resting drift it explains."""
    notebook = nbformat.read(Path(__file__).parents[1] / "notebooks" / "own_data.ipynb", 4)
    text = "".join(
        o.get("text", "") for c in notebook.cells if c.cell_type == "code" for o in c.outputs
    )
    for expected in ("hold still", "Anitescu QP", "learned K(q), D(q)", "resting drift per step"):
        assert expected in text
