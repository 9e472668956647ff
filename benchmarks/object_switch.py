"""What a new object costs a sweep: its setup and first compiled plan, with the environment's
graph kept or dropped (``torch._dynamo.reset()``) between objects.

    python benchmarks/object_switch.py --env trifinger --objects random-401,random-402,random-403

Each object is built as a sweep builds it (``build_trial``) and planned for ``--steps`` steps,
compiled, one thread; ``keep`` runs every object on the graph the process already has,
``reset`` drops the graphs before each object as workers did before 2026-12-02. The first
object's time includes loading (or compiling) the graph. Prints the seconds per object and the
graphs Dynamo compiled, and writes ``results/object_switch/object_switch_ENV.json``. Nothing
else should run on the machine meanwhile.
"""

import os

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op

import argparse  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import torch  # noqa: E402

from torchcontact.results import read_json, write_json  # noqa: E402


def run_mode(env: str, objects: list[str], steps: int, reset: bool) -> list[dict]:
    """Seconds to set up and plan ``steps`` steps of each of ``objects``, in this process."""
    from torch._dynamo.utils import counters

    from torchcontact.environments import environment
    from torchcontact.mpc.trial_config import trial_configs
    from torchcontact.mpc.trials import build_trial, run_trial

    task = environment(env).tasks[0]
    configs = trial_configs(env, [(task, obj) for obj in objects], [0], max_steps=steps)
    rows = []
    for config in configs:
        if reset:
            torch._dynamo.reset()
        start = time.perf_counter()
        built_env, plant, mpc = build_trial(config)
        mpc.wait_for_compile()
        record = run_trial(config, built_env, plant, mpc)
        rows.append(
            {
                "object": config.object,
                "seconds": round(time.perf_counter() - start, 2),
                "eager_steps": len(record.eager_steps or []),
                "graphs": counters["stats"]["unique_graphs"],
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="trifinger")
    parser.add_argument("--objects", default="random-401,random-402,random-403,random-404")
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--mode", choices=("keep", "reset"), default=None, help=argparse.SUPPRESS)
    parser.add_argument("--json", type=Path, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=Path("results/object_switch"))
    args = parser.parse_args()
    objects = args.objects.split(",")
    if args.mode is not None:  # one mode, in a fresh process
        write_json(args.json, run_mode(args.env, objects, args.steps, args.mode == "reset"))
        return
    results = {}
    for mode in ("keep", "reset"):
        path = args.out / f".{mode}.json"
        argv = [sys.executable, __file__, "--env", args.env, "--objects", args.objects,
                "--steps", str(args.steps), "--mode", mode, "--json", str(path)]  # fmt: skip
        subprocess.run(argv, check=True)
        results[mode] = read_json(path)
        path.unlink()
        for row in results[mode]:
            print(f"{mode:5s} {row['object']:14s} {row['seconds']:7.2f} s, graphs {row['graphs']}")
    later = {mode: [row["seconds"] for row in rows[1:]] for mode, rows in results.items()}
    if later["keep"]:
        keep, reset = (sum(later[m]) / len(later[m]) for m in ("keep", "reset"))
        print(f"each later object: {keep:.2f} s kept against {reset:.2f} s reset")
    write_json(args.out / f"object_switch_{args.env}.json", {"env": args.env, **results})


if __name__ == "__main__":
    main()
