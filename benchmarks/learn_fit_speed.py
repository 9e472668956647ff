"""Time the K(q), D(q) fit on a large dataset (the target: 100k transitions in <= 2 minutes).

Collects the transitions with :func:`torchcontact.learn.data.collect` (random reach-and-push
actions, resumable; a rerun reuses them), cuts them into the loss's windows and runs the same
:func:`torchcontact.learn.fit.fit_steps` as ``torchcontact learn-k`` with its default model
(contact-network K and D, the system calibration, the robot term), one CPU thread, or on a GPU
with ``--device cuda`` (as ``learn-k --device cuda``). Prints a table and writes
``results/learn/fit_speed.json`` (``fit_speed_cuda.json`` on a GPU)::

    python benchmarks/learn_fit_speed.py                       # 2000 x 50 = 100k transitions
    python benchmarks/learn_fit_speed.py --trajectories 40     # a quick check
    python benchmarks/learn_fit_speed.py --device cuda         # the same fit on a GPU
    python benchmarks/learn_fit_speed.py --residual 64         # and an object residual after it
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
import torch  # noqa: E402

from torchcontact.checkpoint import (  # noqa: E402
    DAMPING_KINDS,
    STIFFNESS_KINDS,
    FitConfig,
    build_model,
    constant_model,
)
from torchcontact.learn.data import collect, load  # noqa: E402
from torchcontact.learn.evaluate import one_step_error  # noqa: E402
from torchcontact.learn.fit import StepData, fit_steps  # noqa: E402
from torchcontact.learn.residual_fit import fit_residual  # noqa: E402
from torchcontact.learn.scenes import SCENES  # noqa: E402
from torchcontact.results import write_json  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=SCENES, default="trifinger")
    parser.add_argument("--object", default="cube")
    parser.add_argument("--trajectories", type=int, default=2000)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--actions", default="random", help="random, mpc or mixed")
    parser.add_argument("--stiffness", choices=STIFFNESS_KINDS, default="contact_network")
    parser.add_argument("--damping", choices=DAMPING_KINDS, default="contact_network")
    parser.add_argument("--hidden", type=int, default=32)
    parser.add_argument("--epochs", type=int, default=30)
    parser.add_argument("--batch-size", type=int, default=1024)
    parser.add_argument("--lr", type=float, default=3e-3)
    parser.add_argument("--loss-horizon", type=int, default=1)
    parser.add_argument("--robot-weight", type=float, default=1.0)
    parser.add_argument("--calibrate", default="command_gain,robot_stiffness,object_metric")
    parser.add_argument("--residual", type=int, default=0, help="object residual's hidden units")
    parser.add_argument("--workers", type=int, default=1, help="collection processes")
    parser.add_argument("--out", type=Path, default=Path("results/learn"))
    parser.add_argument("--device", default="cpu", help="where the fit runs: cpu or cuda")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    data_dir = (
        args.out / "data" / f"{args.scene}_{args.object}_{args.actions}_steps{args.steps}_seed0"
    )
    collect(
        data_dir,
        args.scene,
        args.object,
        trajectories=args.trajectories,
        steps=args.steps,
        actions=args.actions,
        workers=args.workers,
    )
    start = time.perf_counter()
    transitions = load(data_dir, args.trajectories)
    load_s = time.perf_counter() - start
    meta = transitions.meta
    train, val, test = transitions.split(seed=0)
    start = time.perf_counter()
    steps = [StepData.from_transitions(part, args.loss_horizon) for part in (train, val)]
    steps.append(StepData.from_transitions(test))
    steps = [part.to(args.device) for part in steps]
    windows_s = time.perf_counter() - start
    config = FitConfig(
        stiffness=args.stiffness,
        damping=args.damping,
        hidden=args.hidden,
        epochs=args.epochs,
        batch_size=args.batch_size,
        lr=args.lr,
        patience=args.epochs,
        loss_horizon=args.loss_horizon,
        robot_weight=args.robot_weight,
        calibrate=tuple(filter(None, args.calibrate.split(","))),
        residual=args.residual,
    )
    weights = tuple(meta["pose_weights"])
    model = build_model(dataclasses.replace(config, residual=0), meta)
    result = fit_steps(model, steps[0], steps[1], weights, config)
    residual_s = 0.0
    if args.residual:  # the second stage, as learn-k --residual
        residual_s = fit_residual(result.model, *steps[:2], meta["joints"], config).seconds
    paper_model = constant_model(meta["paper_stiffness"], meta).to(args.device)
    paper = one_step_error(paper_model, steps[2], weights)
    learned = one_step_error(result.model, steps[2], weights)
    epochs = len(result.history)
    record = {
        "transitions": len(transitions),
        "train_transitions": len(train),
        "load_seconds": load_s,
        "windows_seconds": windows_s,
        "fit_seconds": result.seconds,
        "residual_seconds": residual_s,
        "epochs": epochs,
        "seconds_per_epoch": result.seconds / epochs,
        "adam_steps": epochs * -(-len(train) // args.batch_size),
        "threads": torch.get_num_threads(),
        "device": torch.cuda.get_device_name() if args.device.startswith("cuda") else "cpu",
        "config": vars(args) | {"out": str(args.out)},
        "one_step_test_paper_k": paper,
        "one_step_test_learned": learned,
    }
    print(
        f"{'transitions':>11s} {'train':>7s} {'load s':>7s} {'windows s':>12s} "
        f"{'fit s':>7s} {'epochs':>6s} {'s/epoch':>7s} {'residual s':>10s}"
    )
    print(
        f"{len(transitions):>11d} {len(train):>7d} {load_s:>7.1f} {windows_s:>12.1f} "
        f"{result.seconds:>7.1f} {epochs:>6d} {result.seconds / epochs:>7.2f} {residual_s:>10.1f}"
    )
    print(
        f"one-step test error: paper K {paper['pos_mm']:.2f} mm {paper['angle_deg']:.2f}°, "
        f"learned {learned['pos_mm']:.2f} mm {learned['angle_deg']:.2f}°"
    )
    suffix = "" if args.device == "cpu" else "_cuda"
    path = write_json(args.out / f"fit_speed{suffix}.json", record)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
