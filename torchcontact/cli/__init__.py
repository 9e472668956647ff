"""The ``torchcontact`` command: one subcommand per job, each forwarding its own options.

A mistake of the user's (an option's value, an input file that is not what it should be, an
output that cannot be written) ends the job with one line, ``torchcontact JOB: error: ...``
naming the option and what was expected, and exit code 2; a traceback means a bug.
``torchcontact --debug JOB ...`` (or ``--debug`` among the job's options) shows the traceback
of such a mistake too. Ctrl-C ends a job with one line too (a sweep's says how many trials it
kept for a rerun to resume from) and exit code 130.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys

JOBS = {
    "run": (
        "torchcontact.cli.run",
        "closed-loop MPC trials in MuJoCo (e.g. run fingertips --task in-air --object cube)",
    ),
    "compare": (
        "torchcontact.cli.compare",
        "two runs' trial records side by side: trials won and lost, McNemar p-value",
    ),
    "warm": (
        "torchcontact.cli.warm",
        "compile ahead the MPC graphs a run with these options plans with (run's options)",
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


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose error is one line, the message and where the options are
    listed (not argparse's usage block before it); exit code 2."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # a list of numbers that opens with a negative one ("-0.5,1.6") is a value, not an
        # option
        self._negative_number_matcher = re.compile(r"^-\.?\d[\d.e+-]*(,-?\.?\d[\d.e+-]*)*$")

    def error(self, message: str):
        message = " ".join(message.split())
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``torchcontact [--debug] JOB [options]``; ``torchcontact JOB --help`` lists
    options."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = Parser(
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
    except KeyboardInterrupt as interrupt:
        if debug:
            raise
        print(f"torchcontact {args.job}: {interrupt or 'interrupted'}", file=sys.stderr)
        raise SystemExit(130) from None


if __name__ == "__main__":
    sys.exit(main())
