"""Speed-accuracy trade-off of the contact models against MuJoCo, single thread.

    python benchmarks/tradeoff.py                    # every scene and setting (~7 min)
    python benchmarks/tradeoff.py --quick --out /tmp/tradeoff

Prints a table and the dominance summary; writes tradeoff.csv, tradeoff.json, tradeoff.md and
pareto_one_step.png, pareto_h10.png, pareto_traj.png (default under results/tradeoff/); see
``torchcontact.learn.tradeoff`` for the scenes, settings, errors and timed region.
"""

import os

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op

import torch  # noqa: E402

from torchcontact.learn.tradeoff import main  # noqa: E402

torch.set_num_threads(1)

if __name__ == "__main__":
    raise SystemExit(main())
