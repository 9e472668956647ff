"""The ``torchcontact`` command: one subcommand per job, each forwarding its own options."""

from __future__ import annotations

import argparse
import importlib
import os
import sys

JOBS = {
    "run": (
        "torchcontact.mpc.evaluate",
        "closed-loop MPC trials in MuJoCo (e.g. run fingertips --task in-air --object cube)",
    ),
    "learn-k": (
        "torchcontact.cli.learn_k",
        "learn K(q), D(q) from MuJoCo rollouts; compare with the paper's and the best constant K",
    ),
}


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``torchcontact JOB [options]``; ``torchcontact JOB --help`` lists options."""
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(
        prog="torchcontact",
        description="Complementarity-free contact models: experiments and tools.",
        epilog="\n".join(f"  {name:14s} {about}" for name, (_, about) in JOBS.items()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("job", choices=sorted(JOBS), help="what to run")
    args, rest = parser.parse_known_args(argv[:1])
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    module = importlib.import_module(JOBS[args.job][0])
    return module.main(argv[1:]) or 0


if __name__ == "__main__":
    sys.exit(main())
