"""Reporting shared by the studies: text and markdown tables, JSON/CSV/text files, figures and
the command line.

Files are written atomically (:mod:`torchcontact.results`); JSON gets ``None`` for NaN and ±inf,
which JSON has no numbers for. Figures are :class:`matplotlib.figure.Figure` objects, never
pyplot's, so no backend is chosen and nothing is left open.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from torchcontact import results


def format_table(header: Sequence[str], rows: Iterable[Sequence[str]], left: int = 0) -> str:
    """A plain-text table: columns two spaces apart, the first ``left`` of them left-aligned
    (labels), the others right-aligned (numbers); cells are already formatted strings."""
    lines = [list(header), *(list(row) for row in rows)]
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    return "\n".join(
        "  ".join(
            cell.ljust(width) if i < left else cell.rjust(width)
            for i, (cell, width) in enumerate(zip(line, widths, strict=True))
        )
        for line in lines
    )


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A markdown table of already formatted cells."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def json_ready(value: Any) -> Any:
    """``value`` with every NaN and ±inf float, in nested dicts, lists and tuples, as None."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Mapping):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    return value


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` (:func:`json_ready`) as indented JSON, atomically."""
    return results.write_json(path, json_ready(data))


def write_csv(path: str | Path, rows: Iterable[Mapping[str, Any]]) -> Path:
    """Write dict rows as CSV (header: the union of keys in first-seen order), atomically."""
    return results.write_csv(path, rows)


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (a markdown report, ...) atomically."""
    return results.atomic_write(path, lambda f: f.write(text))


def figure(rows: int = 1, columns: int = 1, size: tuple[float, float] = (6.4, 4.8), **kwargs):
    """``(figure, axes)``: a matplotlib figure of ``size`` [inches] and its ``(rows, columns)``
    axes, squeezed as :meth:`~matplotlib.figure.Figure.subplots` does unless told otherwise;
    ``kwargs`` go to ``subplots`` (``sharex``, ``squeeze``, ...)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    return fig, fig.subplots(rows, columns, **kwargs)


def save_figure(fig, path: str | Path, dpi: int = 120) -> Path:
    """Save ``fig`` as PNG at ``dpi`` [dots per inch], atomically."""
    return results.save_figure(fig, path, dpi=dpi)


def written(paths: Iterable[str | Path]) -> None:
    """Say on stderr which files a study wrote (stdout keeps its tables)."""
    print("wrote " + ", ".join(str(p) for p in paths), file=sys.stderr)


def positive_int(text: str) -> int:
    """An argparse type: an integer ≥ 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {value}")
    return value


def parser(prog: str, description: str, out: str | Path) -> argparse.ArgumentParser:
    """An argument parser with the options every study has: ``--out`` (the output folder,
    default ``out``) and ``--no-progress``."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument(
        "--out", type=Path, default=Path(out), help=f"output folder (default {out})"
    )
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bars")
    return parser


def run_main(main: Callable[[Sequence[str] | None], int | None]) -> None:
    """Run a study's ``main`` on the command line's arguments with one torch thread, and exit
    with its status (the ``if __name__ == "__main__"`` of every study)."""
    import torch

    torch.set_num_threads(1)
    raise SystemExit(main(sys.argv[1:]) or 0)
