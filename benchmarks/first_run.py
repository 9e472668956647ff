"""A newcomer's first run: a command's wall time on an empty compile cache, then warm.

    python benchmarks/first_run.py                       # the README's quick start
    python benchmarks/first_run.py --job trifinger       # the first TriFinger trial

Each job runs twice as a subprocess, one thread: first with Inductor's cache pointed at a new
empty folder (``TORCHINDUCTOR_CACHE_DIR``: nothing compiled before, as on a fresh install),
then again with that cache as the first run left it. Each run writes to its own new ``--out``,
so no trial record is reused. Prints wall times, their ratio and the runs' summaries (steps
planned eagerly while the MPC compiled, median solve of the compiled steps) and writes them to
``results/first_run/first_run.json``. Nothing else should run on the machine meanwhile.
"""

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from torchcontact.results import write_json

JOBS = {
    "quick-start": ["run", "fingertips", "--task", "rotation", "--object", "cube", "--trials", "5"],
    "trifinger": ["run", "trifinger", "--object", "cube", "--trials", "1"],
}
"""The timed commands (``torchcontact`` arguments): the README's quick start, and one
TriFinger trial of its cube."""


TORCHCONTACT = [
    sys.executable,
    "-c",
    "import sys; from torchcontact.cli import main; sys.exit(main())",
]
"""The ``torchcontact`` command of this interpreter."""


def timed_run(argv: list[str], cache: Path, out: Path) -> dict:
    """Wall time [s] of ``torchcontact ARGV --out OUT --no-progress`` with Inductor's cache
    in ``cache``, and the summary the run wrote."""
    environment = {**os.environ, "OMP_NUM_THREADS": "1", "TORCHINDUCTOR_CACHE_DIR": str(cache)}
    command = [*TORCHCONTACT, *argv, "--out", str(out), "--no-progress"]
    start = time.perf_counter()
    subprocess.run(command, env=environment, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    summary = json.loads((out / "summary.json").read_text())
    keep = ("trials", "success_rate", "steps_median", "eager_steps", "solve_ms_median")
    return {"wall_s": round(wall, 1), **{key: summary[key] for key in keep}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--job", choices=sorted(JOBS), action="append", help="default: all")
    parser.add_argument("--out", type=Path, default=Path("results/first_run"))
    args = parser.parse_args()
    rows = {}
    for job in args.job or list(JOBS):
        with tempfile.TemporaryDirectory() as scratch:
            scratch = Path(scratch)
            cold = timed_run(JOBS[job], scratch / "cache", scratch / "cold")
            warm = timed_run(JOBS[job], scratch / "cache", scratch / "warm")
        rows[job] = {"command": "torchcontact " + " ".join(JOBS[job]), "cold": cold, "warm": warm}
        ratio = cold["wall_s"] / warm["wall_s"]
        print(
            f"{job}: empty cache {cold['wall_s']:.1f} s ({cold['eager_steps']} steps eager), "
            f"warm {warm['wall_s']:.1f} s ({warm['eager_steps']} eager), {ratio:.1f}×; median "
            f"solve {cold['solve_ms_median']:.1f} / {warm['solve_ms_median']:.1f} ms (of the "
            "compiled steps, or of all where none was compiled)"
        )
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "first_run.json"
    machine = {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count()}
    write_json(path, {"machine": machine, "jobs": rows})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
