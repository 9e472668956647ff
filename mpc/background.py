"""Compile the MPC's graph in a background process while the MPC plans eagerly.

On a machine's first run a compiled MPC step takes minutes to compile (after that it loads
from Inductor's on-disk cache in seconds). Instead of waiting, the MPC can plan those steps
eagerly, with the same model, cost and planner (tens of times slower per step, and equal up to
rounding, not bit for bit), while a child process compiles the graph into the cache, and load
it once that is done. A process rather than a thread: compiling is mostly Python, and in a
thread it would share the interpreter lock with the eager planning and slow both.

The child runs in a session of its own and outlives the run that started it: a short first
run ends when its trials do, and the runs after the child has finished plan compiled from
their first step. One child compiles at a time on a machine (a lock file per child, naming
its process): a process that finds another's child at work plans eagerly meanwhile rather than
compiling beside it. A graph a child finished is marked in the cache directory; a marked graph
is loaded in the foreground, as is every graph where no child can be started (inside a
daemonic pool worker), so a run on a warm cache plans every step with the compiled graph and
repeats bit for bit.
"""

from __future__ import annotations

import hashlib
import multiprocessing
import os
import pickle
import signal
import subprocess
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from torchcontact.results import atomic_write

MARKS = "torchcontact-compiled"
"""Folder of the marks, inside Inductor's cache directory (cleared with it), with each running
child's lock, job and output."""


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


def mark(key: str, folder: Path | None = None) -> None:
    """Mark the graph ``key`` as compiled into this machine's cache (the marks' ``folder``,
    default this process's)."""
    folder = _marks() if folder is None else folder
    folder.mkdir(parents=True, exist_ok=True)
    (folder / key).touch()


class BackgroundCompile:
    """Which compiled graphs may run now, compiling the others one at a time in a child.

    ``ready(key, compile)`` answers True for a graph loaded in this process or marked as
    compiled on this machine (the caller then runs it, loading or compiling it in the
    foreground), and False while a child process runs ``compile()`` (a picklable call that
    runs the graph once) or another process's child compiles; meanwhile the caller plans
    eagerly. A child of this process that fails makes the next :meth:`ready` or :meth:`wait`
    raise, naming its log.
    """

    def __init__(self):
        self._ready: set[str] = set()
        self._child: subprocess.Popen | None = None
        self._child_key = ""
        self._started = 0.0

    def ready(self, key: str, compile: Callable[[], object]) -> bool:
        """Whether the graph ``key`` may run now (see the class docstring)."""
        if key in self._ready:
            return True
        if self._child is not None:
            if self._child.poll() is None:
                return False  # one compile at a time: the others wait for it, planning eagerly
            self._finish()
            if key in self._ready:
                return True
        if marked(key) or multiprocessing.current_process().daemon:
            self._ready.add(key)
            return True
        if compiling_elsewhere():
            return False
        self._start(key, compile)
        return False

    @property
    def compiling(self) -> bool:
        """Whether a child of this process is compiling."""
        return self._child is not None and self._child.poll() is None

    @property
    def pid(self) -> int | None:
        """The compiling child's process id, or None."""
        return self._child.pid if self.compiling else None

    @property
    def elapsed(self) -> float:
        """Seconds since the running child started (0 without one)."""
        return time.monotonic() - self._started if self.compiling else 0.0

    @property
    def log(self) -> Path:
        """The file the last child started writes its output to."""
        return _marks() / f"{self._child_key}.log"

    def cancel(self) -> None:
        """Stop the running child, if any, leaving its graph unmarked (compiled again by the
        next run that needs it)."""
        if self._child is not None:
            self._child.terminate()
            self._child.wait()
            _lock(self._child_key).unlink(missing_ok=True)
            self._child = None

    def wait(self) -> None:
        """Block until the child, if any, has finished (before other processes load its graph
        from the cache)."""
        if self._child is not None:
            self._child.wait()
            self._finish()

    def _start(self, key: str, compile: Callable[[], object]) -> None:
        """Start the child compiling ``key`` by ``compile()``, in a session of its own."""
        folder = _marks()
        folder.mkdir(parents=True, exist_ok=True)
        job = folder / f"{key}.job"
        atomic_write(job, lambda f: pickle.dump(compile, f), binary=True)
        with open(folder / f"{key}.log", "w") as log:
            self._child = subprocess.Popen(
                [sys.executable, "-m", __name__, str(folder), key],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                env={**os.environ, "OMP_NUM_THREADS": "1"}, start_new_session=True,
            )  # fmt: skip
        _lock(key).write_text(str(self._child.pid))
        self._child_key, self._started = key, time.monotonic()

    def _finish(self) -> None:
        code, self._child = self._child.returncode, None
        if code == 0:
            self._ready.add(self._child_key)
        else:
            raise RuntimeError(
                f"compiling the MPC's graph in a background process failed (exit code {code}; "
                f"its output: {self.log}); run with compile off (--no-compile) to go on"
            )


def _lock(key: str, folder: Path | None = None) -> Path:
    """The file that names the process compiling ``key`` while it runs (in the marks'
    ``folder``, default this process's)."""
    return (_marks() if folder is None else folder) / f"{key}.compiling"


def compiling_elsewhere(folder: Path | None = None) -> bool:
    """Whether a child (of any process on this machine) is compiling a graph into this
    cache now (the marks' ``folder``, default this process's); locks left by a child that
    died are removed."""
    folder = _marks() if folder is None else folder
    for lock in folder.glob("*.compiling") if folder.is_dir() else ():
        try:
            pid = int(lock.read_text())
            os.kill(pid, 0)
        except (OSError, ValueError):  # gone (or a half-written lock): not compiling
            if lock.exists() and time.time() - lock.stat().st_mtime > 5:
                lock.unlink(missing_ok=True)
            continue
        return True
    return False


def _compile_and_mark(folder: Path, key: str) -> None:
    """The child: run the pickled ``compile`` of ``key`` (its job in the marks' ``folder``) on
    one thread, then mark ``key`` there; its lock and job are removed either way."""
    import torch

    from torchcontact.mpc.compile_notes import quiet_known_inductor_warnings

    job = folder / f"{key}.job"
    try:
        torch.set_num_threads(1)
        quiet_known_inductor_warnings()
        with open(job, "rb") as f:
            compile = pickle.load(f)
        compile()
        mark(key, folder)
    finally:
        job.unlink(missing_ok=True)
        _lock(key, folder).unlink(missing_ok=True)


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # stopped: clean up as on exit
    try:
        _compile_and_mark(Path(sys.argv[1]), sys.argv[2])
    except BaseException:
        traceback.print_exc()
        sys.exit(1)
