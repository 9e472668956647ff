"""Box pushing: CF vs QP (OSQP) predictions and time per step, single thread.

    python benchmarks/box_pushing.py                          # N = 1, 5, 10, 15, 20, 1000 steps
    python benchmarks/box_pushing.py --cubes 10 --json out.json

Prints a table and writes JSON, CSV and a PNG (default under results/box_pushing/); see
``studies.box_pushing`` for the experiment, the timed region and the options, and
``torchcontact.sim.box_pushing`` for the scene.
"""

import os
import sys
from pathlib import Path

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repo root: studies/

from studies.box_pushing import main  # noqa: E402
from studies.report import run_main  # noqa: E402

if __name__ == "__main__":
    run_main(main)
