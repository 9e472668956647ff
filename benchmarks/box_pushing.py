"""Box pushing: CF vs QP (OSQP) predictions and time per step, single thread.

    python benchmarks/box_pushing.py                          # N = 1, 5, 10, 15, 20, 1000 steps
    python benchmarks/box_pushing.py --cubes 10 --json out.json

Prints a table and writes JSON, CSV and a PNG (default under results/box_pushing/); see
``torchcontact.experiments.box_pushing`` for the scene, the timed region and the options.
"""

import os

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op

import torch  # noqa: E402

from torchcontact.experiments.box_pushing import main  # noqa: E402

torch.set_num_threads(1)

if __name__ == "__main__":
    main()
