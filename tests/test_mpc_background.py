"""Compiling in a child process while the caller plans eagerly: which graphs are ready when."""

import functools
import operator
import os
import time

import pytest

from torchcontact.mpc import background
from torchcontact.mpc.background import BackgroundCompile, describe, graph_key
from torchcontact.mpc.planners import LBFGS


@pytest.fixture
def marks(tmp_path, monkeypatch):
    monkeypatch.setattr(background, "_marks", lambda: tmp_path)
    return tmp_path


def _never():
    raise AssertionError("a marked graph must not be compiled again")


def test_a_marked_graph_is_ready_at_once(marks):
    (marks / "k").touch()
    compiler = BackgroundCompile()
    assert compiler.ready("k", _never) and not compiler.compiling


def test_an_unmarked_graph_compiles_in_a_child_and_is_marked(marks):
    compiler = BackgroundCompile()
    slow = functools.partial(time.sleep, 1.0)
    assert not compiler.ready("k", slow) and compiler.compiling
    assert not compiler.ready("other", slow)  # one child at a time
    compiler.wait()
    assert (marks / "k").exists() and not (marks / "other").exists()
    assert compiler.ready("k", _never)


def test_a_cancelled_child_leaves_its_graph_unmarked(marks):
    compiler = BackgroundCompile()
    assert not compiler.ready("k", functools.partial(time.sleep, 60.0))
    time.sleep(0.2)
    assert compiler.compiling and compiler.elapsed > 0
    compiler.cancel()
    assert not compiler.compiling and compiler.elapsed == 0.0
    assert not (marks / "k").exists()


def test_a_failing_child_is_an_error(marks):
    compiler = BackgroundCompile()
    assert not compiler.ready("k", functools.partial(operator.truediv, 1, 0))
    with pytest.raises(RuntimeError, match="background process failed"):
        compiler.wait()
    assert not (marks / "k").exists()


def test_a_graph_key_is_stable_and_tells_settings_apart():
    assert "0x" not in describe(LBFGS(max_iter=5))
    assert graph_key(LBFGS(max_iter=5), 4) == graph_key(LBFGS(max_iter=5), 4)
    assert graph_key(LBFGS(max_iter=5), 4) != graph_key(LBFGS(max_iter=6), 4)
    assert graph_key(LBFGS(max_iter=5), 4) != graph_key(LBFGS(max_iter=5), 8)


def test_a_child_outlives_its_parent_and_others_wait_for_it(marks, tmp_path):
    """The child runs in a session of its own, so a run may end while it compiles; another
    process (here a second compiler) that finds it at work plans eagerly instead of starting a
    compile beside it, and starts its own once the child is done."""
    first = BackgroundCompile()
    assert not first.ready("k", functools.partial(time.sleep, 3.0))
    child = first.pid
    assert os.getsid(child) == child != os.getsid(0)  # a session of its own
    other = BackgroundCompile()
    assert background.compiling_elsewhere()
    assert not other.ready("j", _never) and not other.compiling
    first.wait()
    assert (marks / "k").exists() and not (marks / "k.compiling").exists()
    assert not background.compiling_elsewhere()
    assert not other.ready("j", functools.partial(time.sleep, 0.0)) and other.compiling
    other.wait()
    assert other.ready("j", _never)


def test_a_lock_left_by_a_dead_child_is_not_a_compile(marks):
    (marks / "k.compiling").write_text("999999999")
    os.utime(marks / "k.compiling", (0, 0))
    assert not background.compiling_elsewhere() and not (marks / "k.compiling").exists()
