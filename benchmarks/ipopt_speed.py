"""MPC solve time per step: our projected L-BFGS against the paper's CasADi/IPOPT, same states.

    python benchmarks/ipopt_speed.py                       # nine fingertip pairs, seeds 0-1
    python benchmarks/ipopt_speed.py --pairs flip:foam_brick --seeds 5 --steps 300
    python benchmarks/ipopt_speed.py --env allegro --seeds 1 --steps 100   # 17 objects

The issue's speed target is relative to the paper's implementation on the same machine. This
runs both in one process on one thread. Each trial is first driven closed-loop by our MPC
(``ContactImplicitMPC.from_env`` with the environment's ``balanced`` preset, as ``torchcontact
run ENV``) for ``--steps`` steps, timing its solves and keeping the states and contacts it
visits. Then :class:`~studies.ipopt_baseline.IpoptMPC` solves the paper's MPC problem (the
environment's MPC with the paper's settings: frozen gaps, float64, T = 4) at the same states
in order, once per way of stating it, each in its own pass: our lean NLP and the reference
code's own formulation (``FORMULATIONS``). Each is warm-started from its own previous solution
(point fingertips' IPOPT at most 100 iterations with the tips' heights bounded as the
reference bounds them, the hands' at most 50, the reference's cap, with their fingertips from
CasADi forward kinematics of the same MJCF).
Separate passes keep one solver from evicting another's code and data from the caches
between its solves; our solves still alternate with MuJoCo's detection and simulation, as
in a sweep, while IPOPT's replays do not. All times include the frozen rows' extraction;
detection and simulation are not timed. The first 5 steps of each trial are left out
(compilation, IPOPT's cold start).

Prints per-pair and overall medians and their ratios, and writes JSON and CSV (default under
``results/ipopt_speed/``, ``results/ipopt_speed_ENV/`` for a hand); each finished trial is
written at once, and a rerun with the same ``--out`` skips it.
"""

import argparse
import dataclasses
import math
import os
import statistics
import sys
from pathlib import Path

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repo root: studies/

import numpy as np  # noqa: E402
import torch  # noqa: E402
from tqdm.auto import tqdm  # noqa: E402

from studies.ipopt_baseline import (  # noqa: E402
    FORMULATIONS,
    REFERENCE_MAX_ITER,
    IpoptMPC,
    is_chain,
)
from torchcontact.environments import ENVIRONMENTS, environment, tasks  # noqa: E402
from torchcontact.environments.options import CostOptions
from torchcontact.environments.presets import PAPER  # noqa: E402
from torchcontact.model import paper_model  # noqa: E402
from torchcontact.mpc.controller import ContactImplicitMPC  # noqa: E402
from torchcontact.results import read_json, write_csv, write_json  # noqa: E402

torch.set_num_threads(1)
WARMUP_STEPS = 5
FINGERTIPS_MAX_ITER = 100
"""IPOPT's cap here: the reference's fingertip MPCs use 100 (foam brick) and 500 (cube)."""


def run_trial(
    task: str, obj: str, seed: int, steps: int, compile: bool = True, env_name: str = "fingertips"
) -> dict:
    """Drive one trial of ``env_name`` with our MPC for ``steps`` steps, timing it, then time
    IPOPT on each NLP formulation (:data:`~studies.ipopt_baseline.FORMULATIONS`) in
    its own pass over the states it visited."""
    env = environment(env_name)
    plant = env.make_plant(obj)
    preset = dataclasses.replace(env.preset(), compile=compile)
    # the paper's problem on both sides: the hold term is ours, not in its NLP
    cost = env.cost(plant, CostOptions(hold_first=0))

    # the paper model at the environment's K on both sides, as the paper's NLP states it
    def model():  # one each: an MPC casts its model to its own dtype
        return paper_model(env.default_stiffness)

    ours = ContactImplicitMPC.from_env(env, plant, model(), settings=preset, cost=cost)
    problem = ContactImplicitMPC.from_env(
        env, plant, model(), settings=dataclasses.replace(PAPER, compile=False), cost=cost
    )
    settings = {"max_iter": REFERENCE_MAX_ITER}
    if not is_chain(problem):  # point fingertips: the reference's cap and tip bounds for them
        known = tasks.OBJECT_SETTINGS.get(obj)
        high = None if known is None else known.tip_height_max
        settings = {
            "max_iter": FINGERTIPS_MAX_ITER,
            "tip_height": (0.0, math.inf if high is None else high),
        }
    baselines = {
        name: IpoptMPC(problem, plant.detector.slots * 4, formulation=name, **settings)
        for name in FORMULATIONS
    }
    initial, target = env.sample(plant, task, seed)
    plant.reset(initial, target)
    aim = env.aim(plant, target)
    aim_p, aim_quat = torch.as_tensor(aim[:3]), torch.as_tensor(aim[3:])
    # Pass 1: our MPC drives the trial; its states and contacts are kept for the replays.
    ours_ms, visited = [], []
    for step in range(steps):
        contacts = plant.contacts(torch.float64)
        q = torch.as_tensor(plant.state())
        plan = ours.plan(q, contacts, aim_p, aim_quat)
        plant.step(plan.control.numpy())
        visited.append((q, contacts))
        if step >= WARMUP_STEPS:
            ours_ms.append(plan.solve_ms)
    # Then each IPOPT formulation in its own pass over the same states, warm-started along
    # them: no solver runs between another's solves, evicting its code and data from the
    # caches (interleaved, our TriFinger solve took 5.1 ms against 2.3 ms in its own pass).
    ipopt = {}
    for name, baseline in baselines.items():
        record = ipopt[name] = {"ms": [], "iterations": [], "status": {}}
        for step, (q, contacts) in enumerate(visited):
            solve = baseline.plan(q, contacts, aim_p, aim_quat)
            if step < WARMUP_STEPS:
                continue
            record["ms"].append(solve.solve_ms)
            record["iterations"].append(solve.iterations)
            record["status"][solve.status] = record["status"].get(solve.status, 0) + 1
    return {
        "env": env_name,
        "task": task,
        "object": obj,
        "seed": seed,
        "steps": steps,
        "ours_ms": ours_ms,
        "ipopt": ipopt,
    }


def summarize(records: list[dict]) -> dict:
    """Medians of our and each IPOPT formulation's times over ``records``' steps, their
    ratios, and IPOPT's median iterations."""
    ours = [t for r in records for t in r["ours_ms"]]
    row = {"steps": len(ours), "ours_ms_median": statistics.median(ours)}
    for name in FORMULATIONS:
        times = [t for r in records for t in r["ipopt"][name]["ms"]]
        ratios = [
            b / a
            for r in records
            for a, b in zip(r["ours_ms"], r["ipopt"][name]["ms"], strict=True)
        ]
        row[f"ipopt_{name}_ms_median"] = statistics.median(times)
        row[f"{name}_ratio_of_medians"] = statistics.median(times) / statistics.median(ours)
        row[f"{name}_median_ratio_per_step"] = statistics.median(ratios)
        row[f"ipopt_{name}_iterations_median"] = statistics.median(
            [i for r in records for i in r["ipopt"][name]["iterations"]]
        )
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", choices=tuple(ENVIRONMENTS), default="fingertips")
    parser.add_argument(
        "--pairs", default="all", help="'all' or comma-separated task:object, e.g. flip:cube"
    )
    parser.add_argument("--seeds", type=int, default=2, help="trials 0…seeds−1 per pair")
    parser.add_argument("--steps", type=int, default=200, help="steps timed per trial")
    parser.add_argument("--out", type=Path, help="default results/ipopt_speed[_ENV]")
    parser.add_argument("--no-compile", action="store_true", help="our objective eager")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.seeds < 1 or args.steps <= WARMUP_STEPS:
        parser.error(f"--seeds must be ≥ 1 and --steps > {WARMUP_STEPS}")
    known = environment(args.env).pairs
    pairs = list(known)
    if args.pairs != "all":
        pairs = [tuple(pair.split(":")) for pair in args.pairs.split(",")]
        unknown = [pair for pair in pairs if pair not in known]
        if unknown:
            parser.error(f"--pairs must be task:object pairs of {known}: {unknown}")
    if args.out is None:
        suffix = "" if args.env == "fingertips" else f"_{args.env}"
        args.out = Path(f"results/ipopt_speed{suffix}")

    jobs = [(task, obj, seed) for task, obj in pairs for seed in range(args.seeds)]
    records = []
    for task, obj, seed in tqdm(jobs, desc="trials", disable=args.no_progress):
        path = args.out / "trials" / f"{task}_{obj}_seed{seed}_steps{args.steps}.json"
        if not path.exists():
            record = run_trial(task, obj, seed, args.steps, not args.no_compile, args.env)
            write_json(path, record)
        records.append(read_json(path))

    rows = []
    print(
        f"{'pair':>24} {'steps':>6} {'ours ms':>8} {'lean ms':>8} {'ratio':>6} {'it':>3}"
        f" {'ref ms':>8} {'ratio':>6} {'it':>3}"
    )
    for task, obj in [*pairs, ("all", "")]:
        chosen = [r for r in records if task == "all" or (r["task"], r["object"]) == (task, obj)]
        row = {"task": task, "object": obj, **summarize(chosen)}
        rows.append(row)
        columns = "".join(
            f" {row[f'ipopt_{name}_ms_median']:>8.1f} {row[f'{name}_ratio_of_medians']:>6.2f}"
            f" {row[f'ipopt_{name}_iterations_median']:>3.0f}"
            for name in FORMULATIONS
        )
        print(f"{task + ' ' + obj:>24} {row['steps']:>6} {row['ours_ms_median']:>8.1f}{columns}")
    statuses: dict[str, dict[str, int]] = {name: {} for name in FORMULATIONS}
    for record in records:
        for name in FORMULATIONS:
            for status, count in record["ipopt"][name]["status"].items():
                statuses[name][status] = statuses[name].get(status, 0) + count
    overall = rows[-1]
    for name in FORMULATIONS:
        listed = ", ".join(f"{k} {v}" for k, v in sorted(statuses[name].items()))
        print(f"IPOPT ({name}) return status: {listed}")
        print(
            f"ours {overall['ours_ms_median']:.1f} ms, IPOPT ({name}) "
            f"{overall[f'ipopt_{name}_ms_median']:.1f} ms median per step: "
            f"{overall[f'{name}_ratio_of_medians']:.2f}x (per-step ratio median "
            f"{overall[f'{name}_median_ratio_per_step']:.2f}x)"
        )
    import casadi

    settings = {
        "env": args.env,
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
