"""The ``torchcontact`` command: one subcommand per job, each forwarding its own options.

A mistake of the user's (an option's value, an input file that is not what it should be, an
output that cannot be written) ends the job with one line, ``torchcontact JOB: error: ...``
naming the option and what was expected, and exit code 2; a traceback means a bug.
``torchcontact --debug JOB ...`` (or ``--debug`` among the job's options) shows the traceback
of such a mistake too.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import tempfile
from pathlib import Path

JOBS = {
    "run": (
        "torchcontact.mpc.evaluate",
        "closed-loop MPC trials in MuJoCo (e.g. run fingertips --task in-air --object cube)",
    ),
    "compare": (
        "torchcontact.mpc.compare",
        "two runs' trial records side by side: trials won and lost, McNemar p-value",
    ),
    "learn-k": (
        "torchcontact.cli.learn_k",
        "learn K(q), D(q) from MuJoCo rollouts; compare with the paper's and the best constant K",
    ),
}

USER_ERRORS = (ValueError,)
"""What the library raises for a bad input: ``ValueError`` with a message saying what was
expected (its subclasses :class:`~torchcontact.learn.data.DataFormatError` and
:class:`~torchcontact.checkpoint.CheckpointError` among them)."""


def _nearest_existing(option: str, path: Path) -> Path:
    """The deepest existing folder on the way to ``path``; ``ValueError`` if it is a file."""
    parent = path.absolute()
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{option} must lie in a directory, but {str(parent)!r} is a file")
    return parent


def writable_directory(option: str, path: Path, create: bool = True) -> Path:
    """Check that files can be written in the folder ``path`` (``create``: create it and write
    a probe file; else, writing nothing, check the permissions of its nearest existing folder):
    ``ValueError`` naming ``option`` otherwise."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{option} must be a directory, got the file {str(path)!r}")
    if not create:
        if not os.access(_nearest_existing(option, path), os.W_OK | os.X_OK):
            raise ValueError(f"{option} must be a writable directory, got {str(path)!r}")
        return path
    _nearest_existing(option, path)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise ValueError(
            f"{option} must be a writable directory, got {str(path)!r} ({reason})"
        ) from None
    return path


def writable_file(option: str, path: Path) -> Path:
    """Check, writing nothing, that the file ``path`` can be written (its missing folders
    created): ``ValueError`` naming ``option`` otherwise."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{option} must be a file path, got the directory {str(path)!r}")
    parent = _nearest_existing(option, path.parent)
    if not os.access(parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise ValueError(f"{option} must be a writable file path, got {str(path)!r}")
    return path


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``torchcontact [--debug] JOB [options]``; ``torchcontact JOB --help`` lists
    options."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(
        prog="torchcontact",
        description="Complementarity-free contact models: experiments and tools.",
        epilog="\n".join(f"  {name:14s} {about}" for name, (_, about) in JOBS.items()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--debug", action="store_true", help="show the traceback of a user error too"
    )
    parser.add_argument("job", choices=sorted(JOBS), help="what to run")
    debug = "--debug" in argv
    argv = [arg for arg in argv if arg != "--debug"]
    args, _ = parser.parse_known_args(argv[:1])
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    module = importlib.import_module(JOBS[args.job][0])
    try:
        return module.main(argv[1:]) or 0
    except USER_ERRORS as error:
        if debug or not str(error):
            raise
        message = " ".join(str(error).split())  # one line
        print(f"torchcontact {args.job}: error: {message}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    sys.exit(main())
