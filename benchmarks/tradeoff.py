"""Speed-accuracy trade-off, single thread: the contact models, then the MPC's settings.

    python benchmarks/tradeoff.py                      # both levels, every figure and table
    python benchmarks/tradeoff.py --level model [--quick --out /tmp/tradeoff]
    python benchmarks/tradeoff.py --level mpc [--env trifinger --trials 3 --workers 2]
    python benchmarks/tradeoff.py --level mpc --backend ray [--address ADDR]  # on a cluster

Model level (``studies.model_tradeoff``, ~7 min): one-step and 10-step prediction error
against MuJoCo and time per step of every contact-model setting; writes tradeoff.csv/.json/.md
and pareto_*.png under results/tradeoff/. MPC level (``studies.mpc_tradeoff``, about an
hour on two workers, resumable): closed-loop success, final errors and median solve time of
each solver setting and the presets; writes mpc_tradeoff.csv/.json/.md and mpc_pareto_*.png
under results/tradeoff/mpc/. Arguments after ``--level`` go to that level.
"""

import os
import sys
from pathlib import Path

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repo root: studies/

import torch  # noqa: E402

from studies import model_tradeoff as model_level  # noqa: E402
from studies import mpc_tradeoff as mpc_level  # noqa: E402

LEVELS = {"model": model_level.main, "mpc": mpc_level.main}
USAGE = "python benchmarks/tradeoff.py [--level {model,mpc} [LEVEL OPTIONS, --help]]"


def main(argv: list[str]) -> int:
    torch.set_num_threads(1)
    if argv[:1] in (["-h"], ["--help"]):
        print(f"usage: {USAGE}\n\n{__doc__.strip()}")
        return 0
    if argv[:1] != ["--level"]:
        if argv:
            raise SystemExit(f"usage: {__doc__.strip().splitlines()[2].strip()} (got {argv})")
        return max(run([]) for run in LEVELS.values())
    if len(argv) < 2 or argv[1] not in LEVELS:
        raise SystemExit(f"--level must be one of {list(LEVELS)}, got {argv[1:2]}")
    return LEVELS[argv[1]](argv[2:])


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
