"""Full-dynamic settings 1-3 (Jin 2024): complementarity-free vs the Anitescu QP vs MuJoCo.

    python benchmarks/full_dynamic.py [--setting 1|2|3|all] [--out DIR] [--json PATH]

Single-threaded, so the numbers do not depend on the machine's core count. Options: see
``python -m torchcontact.experiments.full_dynamic --help``.
"""

import os

os.environ["OMP_NUM_THREADS"] = "1"

import torch  # noqa: E402

from torchcontact.experiments.full_dynamic import main  # noqa: E402

if __name__ == "__main__":
    torch.set_num_threads(1)
    raise SystemExit(main())
