"""Every Python block of README.md runs as written, each in a fresh namespace.

A block runs in a temporary working directory (what it writes, a mesh or a sweep's records,
lands there; ``examples/`` there links to the repository's, which the blocks read). Where a
block runs for minutes as written, the test shrinks it by a documented substitution of the
block's text, the rest of it unchanged: the MPC loop plans eagerly for a few steps instead of
compiling and running to success, the sweep runs one short eager trial instead of five.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from torchcontact.environments import environment
from torchcontact.environments.presets import MPCSettings

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

FENCE = re.compile(r"^```python\n(.*?)^```$", re.MULTILINE | re.DOTALL)

SHRINK = [
    # the sweep: one trial of 3 steps, planned eagerly, in this process
    ("seeds=range(5))", "seeds=range(1), max_steps=3, settings=_eager('trifinger'))"),
    ("workers=2,", "workers=1,"),
    # the MPC loop: 3 steps, planned eagerly (compiling takes minutes)
    ("range(env.criterion.max_steps)", "range(3)"),
    ("from_env(env, plant)  # `torchcontact run`", "from_env(env, plant, settings=_eager(env))  #"),
]
"""(text in a block, what the test runs instead): each must occur in some block."""


def blocks() -> list[tuple[int, str]]:
    """``(line, code)`` of each Python block of the README (line: its fence's, 1-based)."""
    text = README.read_text(encoding="utf-8")
    return [(text.count("\n", 0, m.start()) + 1, m.group(1)) for m in FENCE.finditer(text)]


def shrunk(code: str) -> str:
    for old, new in SHRINK:
        code = code.replace(old, new)
    return code


def _eager(env) -> MPCSettings:
    """The default preset of ``env`` (an environment or its name), not compiled."""
    env = environment(env) if isinstance(env, str) else env
    return dataclasses.replace(env.preset(), compile=False)


def test_the_readme_has_its_blocks_and_every_substitution_applies():
    found = blocks()
    assert len(found) >= 6
    for old, _ in SHRINK:
        assert any(old in code for _, code in found), f"no README block holds {old!r}"


@pytest.fixture
def in_scratch(tmp_path, monkeypatch):
    """A temporary working directory whose ``examples`` is the repository's; the registry of
    environments restored afterwards (a block registers one)."""
    from torchcontact.environments import ENVIRONMENTS

    (tmp_path / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    registered = dict(ENVIRONMENTS)
    yield tmp_path
    ENVIRONMENTS.clear()
    ENVIRONMENTS.update(registered)


@pytest.mark.parametrize("line, code", blocks(), ids=[f"line{line}" for line, _ in blocks()])
def test_a_readme_block_runs(line, code, in_scratch, capsys):
    namespace = {"__name__": "__readme__", "_eager": _eager}  # the block's names its own
    exec(compile(shrunk(code), f"README.md:{line}", "exec"), namespace)
    if "run_trials(" in code:  # its records went to the scratch folder, none to results/
        assert list((in_scratch / "results" / "trifinger" / "trials").glob("*.json"))
    if "SuccessTracker(" in code:  # the loop says whether it succeeded and its errors
        said = capsys.readouterr().out
        assert re.search(r"success (True|False) in 3 steps, [\d.]+ mm, [\d.]+°", said), said
