"""Full-dynamic settings 1-3 (Jin 2024): complementarity-free vs the Anitescu QP vs MuJoCo.

    python benchmarks/full_dynamic.py [--setting 1|2|3|all] [--out DIR] [--json PATH]

Single-threaded, so the numbers do not depend on the machine's core count. Options: see
``python benchmarks/full_dynamic.py --help`` and ``studies.full_dynamic``.
"""

import os
import sys
from pathlib import Path

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repo root: studies/

from studies.full_dynamic import main  # noqa: E402
from studies.report import run_main  # noqa: E402

if __name__ == "__main__":
    run_main(main)
