"""What carrying the object's momentum costs the MPC's solve: the shipped model with and
without its momentum factor, replayed on the same recorded states in one process, one thread.

    python benchmarks/momentum_rollout.py                          # TriFinger, cube and stick
    python benchmarks/momentum_rollout.py --object bunny --steps 80 --rounds 5

A closed-loop trial of the environment's default MPC (its shipped model, which carries the
object's momentum) records the states and contacts it planned from; each variant then plans
from every recorded state in order, reset first, so its warm starts and displacements follow
the same sequence. The first round compiles each variant's graphs; the next ``--rounds``
interleave the variants and are timed. Variants, both of the shipped model:

- ``momentum``: the MPC's rollout, the horizon's steps chained through the object's
  displacement;
- ``no momentum``: the momentum factor removed, the horizon's steps batched (the cost of a
  model without it, such as the TriFinger's shipped until commit db6bf55).

Prints each variant's median and p90 solve per step, its ratio to ``no momentum``, and the
median objective evaluations per solve (equal evaluations: the difference is per evaluation);
writes JSON (default results/momentum_rollout/momentum_rollout.json).
"""

import os

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import platform  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from torchcontact.environments import environment  # noqa: E402
from torchcontact.mpc.controller import ContactImplicitMPC  # noqa: E402
from torchcontact.mpc.trial_config import trial_configs  # noqa: E402
from torchcontact.mpc.trials import trial_model  # noqa: E402
from torchcontact.results import write_json  # noqa: E402

torch.set_num_threads(1)


def build(env, plant, variant: str, compile: bool = True) -> ContactImplicitMPC:
    """The environment's default MPC (its shipped model), compiled in the foreground."""
    (config,) = trial_configs(env.name, [(env.pairs[0][0], plant.object.name)], [0])
    model = trial_model(config, env.h(plant))
    settings = dataclasses.replace(env.preset(), compile=compile)
    mpc = ContactImplicitMPC.from_env(env, plant, model, settings=settings)
    if not mpc.carries_momentum:
        raise SystemExit(f"{env.name}'s shipped model carries no momentum: nothing to compare")
    if variant == "no momentum":
        mpc.system.object_momentum = None
    return mpc


def record(env, plant, mpc: ContactImplicitMPC, steps: int, seed: int) -> list:
    """``(state, contacts, aim)`` of each of the first ``steps`` steps of a closed-loop trial."""
    initial, target = env.sample(plant, env.pairs[0][0], seed)
    plant.reset(initial, target)
    mpc.reset()
    aim = env.aim(plant, target)
    aim = (torch.as_tensor(aim[:3]), torch.as_tensor(aim[3:]))
    states = []
    for _ in range(steps):
        state, contacts = torch.as_tensor(plant.state()), plant.contacts(mpc.dtype)
        states.append((state, contacts, aim))
        plant.step(mpc.plan(state, contacts, *aim).control.numpy())
    return states


def replay(mpc: ContactImplicitMPC, states: list) -> tuple[list[float], list[int]]:
    """Solve times [ms] and L-BFGS evaluations of planning from each recorded state in turn."""
    mpc.reset()
    times, evaluations = [], []
    for state, contacts, aim in states:
        plan = mpc.plan(state, contacts, *aim)
        times.append(plan.solve_ms)
        evaluations.append(plan.evaluations)
    return times, evaluations


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="trifinger")
    parser.add_argument("--object", nargs="+", default=["cube", "stick"])
    parser.add_argument("--steps", type=int, default=60, help="recorded steps per object")
    parser.add_argument("--rounds", type=int, default=3, help="timed replays per variant")
    parser.add_argument("--seed", type=int, default=0, help="the recorded trial's seed")
    parser.add_argument("--no-compile", action="store_true", help="eager (for a quick check)")
    parser.add_argument("--out", type=Path, default=Path("results/momentum_rollout"))
    args = parser.parse_args(argv)
    if args.steps < 1 or args.rounds < 1:
        parser.error("--steps and --rounds must be >= 1")
    env = environment(args.env)
    variants = ("momentum", "no momentum")
    times = {name: [] for name in variants}
    evaluations = {name: [] for name in variants}
    for name in args.object:
        plant = env.make_plant(name)
        mpcs = {variant: build(env, plant, variant, not args.no_compile) for variant in variants}
        states = record(env, plant, mpcs["momentum"], args.steps, args.seed)
        for mpc in mpcs.values():
            replay(mpc, states)  # compiles
        for round_ in range(args.rounds):
            for variant, mpc in mpcs.items():
                ms, n = replay(mpc, states)
                times[variant] += ms
                evaluations[variant] += n
            print(f"{name}: round {round_ + 1} of {args.rounds} timed", flush=True)
    base = float(np.median(times["no momentum"]))
    rows = []
    for variant in variants:
        median = float(np.median(times[variant]))
        rows.append({
            "variant": variant,
            "solve_ms_median": median,
            "solve_ms_p90": float(np.percentile(times[variant], 90)),
            "ratio_to_no_momentum": median / base,
            "evaluations_median": float(np.median(evaluations[variant])),
        })  # fmt: skip
    objects = ", ".join(args.object)
    print(f"{args.env}, objects {objects}: {args.steps} steps × {args.rounds} rounds")
    print(f"{'variant':>12} {'median ms':>9} {'p90 ms':>7} {'ratio':>6} {'evals':>6}")
    for row in rows:
        print(
            f"{row['variant']:>12} {row['solve_ms_median']:9.2f} {row['solve_ms_p90']:7.2f}"
            f" {row['ratio_to_no_momentum']:6.2f} {row['evaluations_median']:6.0f}"
        )
    settings = {**vars(args), "out": str(args.out), "python": platform.python_version()}
    settings.update(torch=torch.__version__, threads=1)
    write_json(args.out / "momentum_rollout.json", {"rows": rows, "settings": settings})
    print(f"wrote {args.out / 'momentum_rollout.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
