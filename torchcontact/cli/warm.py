"""``torchcontact warm ENV [options]``: compile ahead the MPC graphs a run plans with.

Takes the options of ``torchcontact run`` and compiles, in the foreground, the graphs that
run with the same options would plan with, into this machine's compile cache, then exits:
minutes per graph the first time (an environment's objects mostly share one graph), nothing
for graphs the cache holds. A run afterwards plans compiled from its first step instead of
eagerly while a background process compiles. ``scripts/setup.sh`` warms the quick start's.

    torchcontact warm fingertips --task rotation --object cube
    torchcontact warm trifinger --object all
"""

from __future__ import annotations

import time

from torchcontact.cli import run
from torchcontact.mpc.compile_notes import quiet_known_inductor_warnings
from torchcontact.mpc.trials import warm_graphs


def main(argv: list[str] | None = None) -> int:
    args = run.parse_args(argv, prog="torchcontact warm", description=__doc__.split("\n\n")[1])
    if not args.settings.compile:
        raise ValueError("--no-compile: a run that does not compile has no graph to warm")
    configs = run.configs_of(args)
    quiet_known_inductor_warnings()
    start = time.perf_counter()
    print(f"compiling the MPC's graphs for torchcontact run {' '.join(argv or [])} ...")
    compiled = warm_graphs(configs, progress=not args.no_progress)
    print(
        f"{len(compiled)} graph(s) compiled in {time.perf_counter() - start:.0f} s"
        if compiled
        else "every graph was in the cache already"
    )
    return 0
