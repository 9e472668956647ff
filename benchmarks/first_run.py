"""A newcomer's first run: a command's wall time on an empty compile cache, then warm.

    python benchmarks/first_run.py                       # every job below
    python benchmarks/first_run.py --job quick-start     # the README's quick start

Each job runs as a subprocess, one thread, with Inductor's cache pointed at a new empty folder
(``TORCHINDUCTOR_CACHE_DIR``: nothing compiled before, as on a fresh install): first on the
empty cache (timing the wall, and when the background compile it started has marked its
graph ready, which may be after the run has ended), then, once that compile is done, again
on the cache the first run left. Each run writes to its own new ``--out``, so no trial record
is reused. Per job it prints:

- the wall of the run on the empty and on the warm cache, and their ratio;
- when the graph was ready (the first compiled step can come no earlier), counted from the
  first run's start;
- the graphs compiled (the marks in the cache), and the steps planned eagerly in each run;
- the median solve of the compiled steps and of the eager ones, apart.

``first-step`` is one step of the quick start (``--max-steps 1``): its wall is the time to the
first step. ``objects`` is the TriFinger's cube, bunny and stick, one trial each: the graphs
an environment's objects compile. Writes ``results/first_run/first_run.json``. Nothing else
should run on the machine meanwhile.
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

from torchcontact.mpc.background import MARKS, compiling_elsewhere
from torchcontact.results import write_json

QUICK_START = ["run", "fingertips", "--task", "rotation", "--object", "cube", "--trials", "5"]

JOBS = {
    "first-step": [*QUICK_START[:-1], "1", "--max-steps", "1"],
    "quick-start": QUICK_START,
    "trifinger": ["run", "trifinger", "--object", "cube", "--trials", "1"],
    "objects": ["run", "trifinger", "--object", "cube,bunny,stick", "--trials", "1"],
}
"""The timed commands (``torchcontact`` arguments): one step of the README's quick start, the
quick start, one TriFinger trial of its cube, and one of each of three TriFinger objects."""

TORCHCONTACT = [
    sys.executable,
    "-c",
    "import sys; from torchcontact.cli import main; sys.exit(main())",
]
"""The ``torchcontact`` command of this interpreter."""

SUMMARY_KEYS = (
    "trials",
    "success_rate",
    "steps_median",
    "solve_steps",
    "solve_ms_median",
    "eager_steps",
    "eager_solve_ms_median",
)


def timed_run(argv: list[str], cache: Path, out: Path) -> dict:
    """Wall time [s] of ``torchcontact ARGV --out OUT --no-progress`` with Inductor's cache
    in ``cache``, when the graphs it compiles were ready (the cache's marks, none compiling)
    counted from its start, and the summary the run wrote."""
    environment = {**os.environ, "OMP_NUM_THREADS": "1", "TORCHINDUCTOR_CACHE_DIR": str(cache)}
    command = [*TORCHCONTACT, *argv, "--out", str(out), "--no-progress"]
    marks = cache / MARKS
    start = time.perf_counter()
    run = subprocess.Popen(command, env=environment, stdout=subprocess.DEVNULL)
    wall = None
    while True:
        if wall is None and run.poll() is not None:
            wall = time.perf_counter() - start
            if run.returncode:
                raise subprocess.CalledProcessError(run.returncode, command)
        if wall is not None and not compiling_elsewhere(marks):
            break
        time.sleep(0.5)
    ready = time.perf_counter() - start
    summary = json.loads((out / "summary.json").read_text())
    graphs = sorted(p.name for p in marks.iterdir() if not p.suffix) if marks.is_dir() else []
    return {
        "wall_s": round(wall, 1),
        "graphs_ready_s": round(ready, 1) if graphs else None,
        "graphs": len(graphs),
        **{key: summary[key] for key in SUMMARY_KEYS},
    }


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
        print(
            f"{job}: empty cache {cold['wall_s']:.1f} s ({cold['eager_steps']} steps eager, "
            f"median {_ms(cold['eager_solve_ms_median'])}; {cold['solve_steps']} compiled, "
            f"median {_ms(cold['solve_ms_median'])}), {cold['graphs']} graphs compiled, ready "
            f"after {cold['graphs_ready_s']} s; warm {warm['wall_s']:.1f} s "
            f"({warm['eager_steps']} eager; compiled median {_ms(warm['solve_ms_median'])}), "
            f"{cold['wall_s'] / warm['wall_s']:.1f}×"
        )
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "first_run.json"
    machine = {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count()}
    write_json(path, {"machine": machine, "jobs": rows})
    print(f"wrote {path}")


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f} ms"


if __name__ == "__main__":
    main()
