"""MPC solve time per step: our projected L-BFGS against the paper's CasADi/IPOPT, same states.

    python benchmarks/ipopt_speed.py                       # nine fingertip pairs, seeds 0-1
    python benchmarks/ipopt_speed.py --pairs flip:foam_brick --seeds 5 --steps 300

The issue's speed target is relative to the paper's implementation on the same machine. This
runs both in one process on one thread: each trial is driven closed-loop by our MPC (the
``balanced`` preset, as ``torchcontact run fingertips``), and at every one of its first
``--steps`` states :class:`~torchcontact.mpc.ipopt_baseline.IpoptMPC` solves the paper's MPC
problem too (frozen gaps, float64, the tips' heights bounded as the reference bounds them,
IPOPT at most 100 iterations, warm-started from its own previous solution). Both times
include the frozen rows' extraction; detection and simulation are not timed. The first 5
steps of each trial are left out (compilation, IPOPT's cold start).

Prints per-pair and overall medians and their ratio, and writes JSON and CSV (default under
``results/ipopt_speed/``); each finished trial is written at once, and a rerun with the same
``--out`` skips it.
"""

import os

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op

import argparse  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from tqdm.auto import tqdm  # noqa: E402

from torchcontact.mpc import tasks  # noqa: E402
from torchcontact.mpc.fingertips import fingertips_mpc  # noqa: E402
from torchcontact.mpc.ipopt_baseline import IpoptMPC  # noqa: E402
from torchcontact.mpc.presets import preset_options  # noqa: E402
from torchcontact.mpc.suites import SUITES  # noqa: E402
from torchcontact.results import read_json, write_csv, write_json  # noqa: E402

torch.set_num_threads(1)
WARMUP_STEPS = 5
FINGERTIPS_MAX_ITER = 100
"""IPOPT's cap here: the reference's fingertip MPCs use 100 (foam brick) and 500 (cube)."""


def run_trial(task: str, obj: str, seed: int, steps: int, compile: bool = True) -> dict:
    """Drive one trial with our MPC for ``steps`` steps, timing both solvers at each state."""
    suite = SUITES["fingertips"]
    env = suite.make_env(obj)
    ours = fingertips_mpc(obj, **{**preset_options("fingertips"), "compile": compile})
    high = tasks.OBJECT_SETTINGS[obj].tip_height_max
    baseline = IpoptMPC(
        fingertips_mpc(obj, compile=False),
        n_rows=env.detector.slots * 4,
        max_iter=FINGERTIPS_MAX_ITER,
        tip_height=(0.0, math.inf if high is None else high),
    )
    initial, target = suite.sample(env, task, obj, seed)
    env.reset(initial, target)
    aim = suite.aim(env, target)
    aim_p, aim_quat = torch.as_tensor(aim[:3]), torch.as_tensor(aim[3:])
    ours_ms, ipopt_ms, iterations, statuses = [], [], [], {}
    for step in range(steps):
        contacts = env.contacts(torch.float64)
        q = torch.as_tensor(env.state())
        plan = ours.plan(q, contacts, aim_p, aim_quat)
        reference = baseline.plan(q, contacts, aim_p, aim_quat)
        env.step(plan.control.numpy())
        if step >= WARMUP_STEPS:
            ours_ms.append(plan.solve_ms)
            ipopt_ms.append(reference.solve_ms)
            iterations.append(reference.iterations)
            statuses[reference.status] = statuses.get(reference.status, 0) + 1
    return {
        "task": task,
        "object": obj,
        "seed": seed,
        "steps": steps,
        "ours_ms": ours_ms,
        "ipopt_ms": ipopt_ms,
        "ipopt_iterations": iterations,
        "ipopt_status": statuses,
    }


def summarize(records: list[dict]) -> dict:
    """Medians of both solvers' times over ``records``' steps and their ratios."""
    ours = [t for r in records for t in r["ours_ms"]]
    ipopt = [t for r in records for t in r["ipopt_ms"]]
    ratios = [b / a for r in records for a, b in zip(r["ours_ms"], r["ipopt_ms"], strict=True)]
    return {
        "steps": len(ours),
        "ours_ms_median": statistics.median(ours),
        "ipopt_ms_median": statistics.median(ipopt),
        "ratio_of_medians": statistics.median(ipopt) / statistics.median(ours),
        "median_ratio_per_step": statistics.median(ratios),
        "ipopt_iterations_median": statistics.median(
            [i for r in records for i in r["ipopt_iterations"]]
        ),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--pairs", default="all", help="'all' or comma-separated task:object, e.g. flip:cube"
    )
    parser.add_argument("--seeds", type=int, default=2, help="trials 0…seeds−1 per pair")
    parser.add_argument("--steps", type=int, default=200, help="steps timed per trial")
    parser.add_argument("--out", type=Path, default=Path("results/ipopt_speed"))
    parser.add_argument("--no-compile", action="store_true", help="our objective eager")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.seeds < 1 or args.steps <= WARMUP_STEPS:
        parser.error(f"--seeds must be ≥ 1 and --steps > {WARMUP_STEPS}")
    pairs = list(tasks.PAPER_PAIRS)
    if args.pairs != "all":
        pairs = [tuple(pair.split(":")) for pair in args.pairs.split(",")]
        unknown = [pair for pair in pairs if pair not in tasks.PAPER_PAIRS]
        if unknown:
            parser.error(f"--pairs must be task:object pairs of {tasks.PAPER_PAIRS}: {unknown}")

    jobs = [(task, obj, seed) for task, obj in pairs for seed in range(args.seeds)]
    records = []
    for task, obj, seed in tqdm(jobs, desc="trials", disable=args.no_progress):
        path = args.out / "trials" / f"{task}_{obj}_seed{seed}_steps{args.steps}.json"
        if not path.exists():
            write_json(path, run_trial(task, obj, seed, args.steps, not args.no_compile))
        records.append(read_json(path))

    rows = []
    print(f"{'pair':>22} {'steps':>6} {'ours ms':>8} {'IPOPT ms':>9} {'ratio':>6} {'IPOPT it':>9}")
    for task, obj in [*pairs, ("all", "")]:
        chosen = [r for r in records if task == "all" or (r["task"], r["object"]) == (task, obj)]
        row = {"task": task, "object": obj, **summarize(chosen)}
        rows.append(row)
        print(
            f"{task + ' ' + obj:>22} {row['steps']:>6} {row['ours_ms_median']:>8.1f} "
            f"{row['ipopt_ms_median']:>9.1f} {row['ratio_of_medians']:>6.2f} "
            f"{row['ipopt_iterations_median']:>9.0f}"
        )
    statuses: dict[str, int] = {}
    for record in records:
        for status, count in record["ipopt_status"].items():
            statuses[status] = statuses.get(status, 0) + count
    print("IPOPT return status:", ", ".join(f"{k} {v}" for k, v in sorted(statuses.items())))
    overall = rows[-1]
    print(
        f"ours {overall['ours_ms_median']:.1f} ms, IPOPT {overall['ipopt_ms_median']:.1f} ms "
        f"median per step: {overall['ratio_of_medians']:.2f}x (per-step ratio median "
        f"{overall['median_ratio_per_step']:.2f}x)"
    )
    import casadi

    settings = {
        "torch": torch.__version__,
        "numpy": np.__version__,
        "casadi": casadi.__version__,
        "threads": 1,
    }
    write_json(args.out / "ipopt_speed.json", {"rows": rows, "status": statuses, **settings})
    write_csv(args.out / "ipopt_speed.csv", rows)
    print(f"wrote {args.out / 'ipopt_speed.json'}, ipopt_speed.csv")
    return 0


if __name__ == "__main__":
    sys.exit(main())
