"""The MPC's solve per step for each contact source, on the same closed-loop steps.

For each source of ``--gaps`` (:data:`~torchcontact.environments.presets.GAPS`), the
environment's default trial (its shipped model, cost and preset, that source) is run for
``--steps`` MPC steps from each seed's start; every solve is timed and the first ``--skip`` of
each trial left out (a compiled graph builds or loads there). Prints the median and p90 solve
per source and their ratio to the first, writes JSON (default
``results/sources/speed_ENV.json``). One thread, one process: run nothing else meanwhile.

    python benchmarks/contact_sources.py trifinger --steps 40 --seeds 2
    python benchmarks/contact_sources.py trifinger --sources frozen live --no-compile
"""

import os

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from tqdm.auto import tqdm  # noqa: E402

from torchcontact.environments import environment  # noqa: E402
from torchcontact.environments.presets import GAPS  # noqa: E402
from torchcontact.mpc.trial_config import trial_configs  # noqa: E402
from torchcontact.mpc.trials import build_trial  # noqa: E402
from torchcontact.results import write_json  # noqa: E402


def solve_times(config, steps: int, skip: int) -> list[float]:
    """Solve times [ms] of ``steps`` closed-loop MPC steps of ``config``'s trial after the
    first ``skip``; the MPC compiles in the foreground (its first solve waits for the graph)."""
    env, plant, mpc = build_trial(config)
    mpc._background = mpc._eager_planner = None  # time the graph itself, not a child's compile
    initial, target = env.sample(plant, config.task, config.seed)
    plant.reset(initial, target)
    mpc.reset()
    aim = torch.as_tensor(env.aim(plant, target), dtype=mpc.dtype)
    times = []
    for step in range(skip + steps):
        start = time.perf_counter()
        plan = mpc.plan(torch.as_tensor(plant.state()), plant.contacts(mpc.dtype), aim[:3], aim[3:])
        if step >= skip:
            times.append(1e3 * (time.perf_counter() - start))
        plant.step(plan.control.numpy())
    return times


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("env", choices=("fingertips", "trifinger", "allegro"))
    parser.add_argument("--object", default="cube")
    parser.add_argument("--sources", nargs="+", choices=GAPS, default=list(GAPS))
    parser.add_argument("--steps", type=int, default=40, help="timed steps per seed")
    parser.add_argument("--skip", type=int, default=2, help="untimed first steps per seed")
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--no-compile", action="store_true", help="eager objective")
    parser.add_argument("--out", type=Path, default=Path("results/sources"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    rows = {}
    for source in tqdm(args.sources, desc="sources"):
        description = environment(args.env)
        settings = dataclasses.replace(
            description.preset(), gaps=source, compile=not args.no_compile
        )
        pairs = description.select(description.tasks[0], args.object)
        times = []
        for config in trial_configs(args.env, pairs, range(args.seeds), settings):
            times += solve_times(config, args.steps, args.skip)
        rows[source] = {
            "median_ms": float(np.median(times)),
            "p90_ms": float(np.percentile(times, 90)),
            "steps": len(times),
        }
    first = rows[args.sources[0]]["median_ms"]
    for source, row in rows.items():
        row["median_ratio"] = row["median_ms"] / first
        print(f"{source:>10}  median {row['median_ms']:8.2f} ms  p90 {row['p90_ms']:8.2f} ms  "
              f"×{row['median_ratio']:.2f}")  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"speed_{args.env}{'_eager' if args.no_compile else ''}.json"
    settings = vars(args) | {"out": str(args.out)}
    write_json(path, {"rows": rows, "settings": settings})
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
