"""Compile the MPC's graph in a background process while the MPC plans eagerly.

On a machine's first run a compiled MPC step takes a minute or more to compile (after that it
loads from Inductor's on-disk cache in seconds). Instead of waiting, the MPC can plan those
steps eagerly, with the same model, cost and planner (tens of times slower per step, about 40×
on the fingertips, and equal up to rounding, not bit for bit), while a child process compiles
the graph into the cache, and load it once that is done. A process rather than a thread:
compiling is mostly Python, and in a thread it would share the interpreter lock with the eager
planning and slow both.

A graph the child finished is marked in the cache directory; a marked graph is loaded in the
foreground, as is every graph where no child can be started (inside a daemonic pool worker),
so a run on a warm cache plans every step with the compiled graph and repeats bit for bit.
"""

from __future__ import annotations

import hashlib
import multiprocessing
import time
from collections.abc import Callable
from pathlib import Path

MARKS = "torchcontact-compiled"
"""Folder of the marks, inside Inductor's cache directory (cleared with it)."""


def describe(value: object) -> str:
    """A description of ``value`` that is the same in every process: its ``repr`` unless that
    is ``object``'s default (which holds an address), else its type and attributes."""
    if type(value).__repr__ is not object.__repr__:
        return repr(value)
    attributes = sorted(vars(value).items()) if hasattr(value, "__dict__") else []
    return f"{type(value).__module__}.{type(value).__qualname__}{attributes}"


def graph_key(*parts: object) -> str:
    """A hex digest naming a compiled graph: torch's version and :func:`describe` of each of
    ``parts``, which should hold everything the graph is specialised to (types, settings,
    shapes, dtypes). Two graphs given one key share a mark: the second then compiles in the
    foreground, as without a background compile."""
    import torch

    text = "\n".join([torch.__version__, *(describe(part) for part in parts)])
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _marks() -> Path:
    from torch._inductor.runtime.cache_dir_utils import cache_dir

    return Path(cache_dir()) / MARKS


def marked(key: str) -> bool:
    """Whether this machine's cache holds the graph ``key`` (a process marked it compiled)."""
    return (_marks() / key).exists()


def mark(key: str) -> None:
    """Mark the graph ``key`` as compiled into this machine's cache."""
    path = _marks() / key
    path.parent.mkdir(parents=True, exist_ok=True)
    path.touch()


class BackgroundCompile:
    """Which compiled graphs may run now, compiling the others one at a time in a child.

    ``ready(key, compile)`` answers True for a graph loaded in this process or marked as
    compiled on this machine (the caller then runs it, loading or compiling it in the
    foreground), and False while a child process runs ``compile()`` (a picklable call that
    runs the graph once); meanwhile the caller plans eagerly. A child that fails makes the next
    :meth:`ready` or :meth:`wait` raise.
    """

    def __init__(self):
        self._ready: set[str] = set()
        self._child: multiprocessing.process.BaseProcess | None = None
        self._child_key = ""
        self._started = 0.0

    def ready(self, key: str, compile: Callable[[], object]) -> bool:
        """Whether the graph ``key`` may run now (see the class docstring)."""
        if key in self._ready:
            return True
        if self._child is not None:
            if self._child.is_alive():
                return False  # one compile at a time: the others wait for it, planning eagerly
            self._finish()
            if key in self._ready:
                return True
        if marked(key) or multiprocessing.current_process().daemon:
            self._ready.add(key)
            return True
        self._child = multiprocessing.get_context("spawn").Process(
            target=_compile_and_mark, args=(compile, key), name=f"compile-{key[:8]}"
        )
        self._child.start()
        self._child_key, self._started = key, time.monotonic()
        return False

    @property
    def compiling(self) -> bool:
        """Whether a child is compiling."""
        return self._child is not None and self._child.is_alive()

    @property
    def elapsed(self) -> float:
        """Seconds since the running child started (0 without one)."""
        return time.monotonic() - self._started if self.compiling else 0.0

    def cancel(self) -> None:
        """Stop the running child, if any, leaving its graph unmarked (compiled again by the
        next run that needs it)."""
        if self._child is not None:
            self._child.terminate()
            self._child.join()
            self._child = None

    def wait(self) -> None:
        """Block until the child, if any, has finished (before other processes load its graph
        from the cache)."""
        if self._child is not None:
            self._child.join()
            self._finish()

    def _finish(self) -> None:
        code, self._child = self._child.exitcode, None
        if code == 0:
            self._ready.add(self._child_key)
        else:
            raise RuntimeError(
                f"compiling the MPC's graph in a background process failed (exit code {code}; "
                "its error is printed above); run with compile off (--no-compile) to go on"
            )


def _compile_and_mark(compile: Callable[[], object], key: str) -> None:
    """The child: run ``compile`` on one thread, then :func:`mark` ``key``."""
    import torch

    from torchcontact.mpc.compile_notes import quiet_known_inductor_warnings

    torch.set_num_threads(1)
    quiet_known_inductor_warnings()
    compile()
    mark(key)
