"""``torchcontact learn-k``: learn K(q) and D(q) of a scene from MuJoCo rollouts and compare.

The pipeline, one stage per line of :func:`run`::

    collect(data_dir, scene, obj, ...)            # MuJoCo transitions (reused, resumed)
    train, val, test = load(data_dir).split()    # by trajectory
    sweep = sweep_constant(grid, val, detector)   # best constant K by 10-step rollouts
    result = fit(model, train, val, ...)          # learned K(q), D(q) on the one-step loss
    evaluation = ... paper K, best K, learned     # one step and 10-step rollouts on test

Writes ``OUT/SCENE_OBJECT/results.json`` (everything measured), ``model.pt`` (the learned
model's checkpoint, :func:`~torchcontact.checkpoint.load_checkpoint`) and ``history.csv``
(losses per epoch); ``--json PATH`` writes the headline figures. Errors are means over the
test windows; the combined error is the MPC's ``w_p‖p − p*‖² + w_q(1 − ⟨q, q*⟩²)``.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import math
import os
import shlex
import subprocess
import sys
from dataclasses import asdict, fields
from pathlib import Path

import torch

from torchcontact.checkpoint import (
    DAMPING_KINDS,
    STIFFNESS_KINDS,
    FitConfig,
    build_model,
    constant_model,
    save_checkpoint,
)
from torchcontact.cli import writable_directory, writable_file
from torchcontact.environments import environment
from torchcontact.environments.presets import MPCSettings
from torchcontact.learn.data import MANIFEST, collect, load
from torchcontact.learn.evaluate import (
    log_grid,
    one_step_error,
    rollout_error,
    still_error,
    sweep_constant,
)
from torchcontact.learn.fit import StepData, fit
from torchcontact.learn.policies import ACTIONS
from torchcontact.learn.scenes import BOX_PUSHING, SCENES, Scene, make_scene
from torchcontact.model import paper_model
from torchcontact.mpc.compile_notes import quiet_known_inductor_warnings
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.trials import file_sha256, library_versions
from torchcontact.parallel import BACKENDS, RAY_EXTRA, check_backend
from torchcontact.results import atomic_write, write_csv, write_json
from torchcontact.shipped import models_dir

DEFAULT_STEPS = {"fingertips": 120, "trifinger": 50, "allegro": 50, "box_pushing": 100}
"""Steps per trajectory by scene: the fingertips start 0.2 m from the object."""

MODELS = ("paper_k", "best_constant_k", "learned")
LABELS = {"paper_k": "paper K", "best_constant_k": "best constant K", "learned": "learned"}


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="torchcontact learn-k",
        description="Learn the contact stiffness K(q) and damping D(q) from MuJoCo rollouts.",
    )
    add = parser.add_argument
    add("--scene", choices=SCENES, default="trifinger")
    add("--object", default="cube", help="an object of the scene's suite")
    add("--task", default=None, help="the suite task whose sampler starts each trajectory")
    add("--trajectories", type=int, default=400, help="trajectories used (collected if missing)")
    add("--steps", type=int, default=None, help=f"steps per trajectory (default {DEFAULT_STEPS})")
    add(
        "--actions",
        choices=ACTIONS,
        default=None,
        help="action source (default mpc; random for box_pushing, which has no MPC task)",
    )
    add("--noise", type=float, default=None, help="exploration noise, fraction of the bound")
    add("--no-compile", action="store_true", help="eager MPC while collecting")
    add("--workers", type=int, default=1, help="parallel collection processes (or Ray CPUs)")
    add("--backend", choices=BACKENDS, default="local", help=f"local or Ray ({RAY_EXTRA})")
    add("--address", default=None, help="(ray) a running cluster's address")
    add("--data", type=Path, default=None, help="dataset directory (default under --out)")
    add("--stiffness", choices=STIFFNESS_KINDS, default="contact_network", help="K(q)")
    add("--damping", choices=DAMPING_KINDS, default="contact_network", help="D(q)")
    add("--hidden", type=int, default=32, help="hidden units of the networks")
    add("--distance-scale", type=float, default=1e-4, help="φ feature scale [m]")
    add("--epochs", type=int, default=300)
    add("--batch-size", type=int, default=512)
    add("--lr", type=float, default=3e-3)
    add("--patience", type=int, default=40, help="early stopping patience [epochs]")
    add(
        "--sweep",
        type=float,
        nargs=3,
        default=(1e-3, 1e2, 16),
        metavar=("LOW", "HIGH", "N"),
        help="constant-K grid: N log-spaced values",
    )
    add("--horizon", type=int, default=10, help="rollout steps of the evaluation")
    add("--stride", type=int, default=5, help="a rollout starts every STRIDE steps")
    add("--seed", type=int, default=0, help="data, split and fit seed")
    add("--out", type=Path, default=Path("results/learn"))
    add("--json", type=Path, default=None, help="write the headline figures here")
    add(
        "--ship",
        action="store_true",
        help="also install the learned model as the scene's shipped default, with its manifest "
        "(torchcontact/assets/models/SCENE.pt and .json)",
    )
    add("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    positive = ("hidden", "epochs", "batch_size", "patience", "horizon", "stride", "workers")
    for name in positive:
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    try:
        check_backend(args.workers, args.backend, args.address)
    except (ValueError, ImportError) as error:
        parser.error(f"--backend/--address/--workers: {error}")
    if args.trajectories < 3:
        parser.error(f"--trajectories must be >= 3 (train, val, test), got {args.trajectories}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    if not 0 < args.distance_scale < math.inf:
        parser.error(f"--distance-scale must be positive and finite, got {args.distance_scale}")
    if args.noise is not None and not 0 <= args.noise < math.inf:
        parser.error(
            f"--noise must be a non-negative finite fraction of the control bound, got {args.noise}"
        )
    _check_fit_options(parser, args)
    _check_scene(parser, args)
    args.steps = DEFAULT_STEPS[args.scene] if args.steps is None else args.steps
    if args.actions is None:
        args.actions = "random" if args.scene == BOX_PUSHING else "mpc"
    elif args.scene == BOX_PUSHING and args.actions != "random":
        parser.error(f"--actions must be random for box_pushing (no MPC task), got {args.actions}")
    if args.steps <= args.horizon:
        parser.error(f"--steps must exceed --horizon ({args.horizon}), got {args.steps}")
    low, high, count = args.sweep
    if not (0 < low < high < math.inf) or count < 2 or count != int(count):
        parser.error(f"--sweep needs finite 0 < LOW < HIGH and an integer N >= 2, got {args.sweep}")
    args.grid = log_grid(low, high, int(count))
    name = f"{args.scene}_{Path(args.object).stem}"
    args.results = args.out / name
    if args.data is None:
        args.data = args.out / "data" / f"{name}_{args.actions}_steps{args.steps}_seed{args.seed}"
    return args


def _check_fit_options(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """The checks of :class:`FitConfig` on the options that become its fields."""
    names = [f.name for f in fields(FitConfig) if f.name != "initial_stiffness"]
    try:
        FitConfig(**{name: getattr(args, name) for name in names})
    except ValueError as error:
        field, _, rest = str(error).partition(" ")
        parser.error(f"--{field.replace('_', '-')} {rest}")


def _check_scene(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--object`` and ``--task`` against the scene's suite (as :func:`make_scene` does)."""
    if args.scene == BOX_PUSHING:
        if args.object != "cube" or args.task not in (None, "push"):
            parser.error(
                f"--object and --task of box_pushing are cube and push only, got "
                f"{args.object!r}, {args.task!r}"
            )
        return
    env = environment(args.scene)
    tasks = [t for t, o in env.pairs if o == args.object]
    if not tasks:
        parser.error(f"--object must be one of {env.objects} for {args.scene}, got {args.object!r}")
    if args.task is not None and args.task not in tasks:
        parser.error(f"--task must be one of {tasks} for {args.object}, got {args.task!r}")


def check_outputs(args: argparse.Namespace) -> None:
    """Check, before anything runs, that every output can be written: ``--out`` (created),
    the results folder, the dataset folder ``--data`` and ``--json``."""
    writable_directory("--out", args.out)
    writable_directory("--out", args.results, create=False)
    writable_directory("--data", args.data, create=False)
    if (args.data / MANIFEST).is_dir():
        raise ValueError(f"--data must be a dataset directory, {args.data / MANIFEST} is a folder")
    if args.json is not None:
        writable_file("--json", args.json)


def collection_mpc(scene: Scene, compile: bool = True) -> ContactImplicitMPC:
    """The MPC whose actions the data are collected with: the paper's model at the paper's K
    and the paper's solver settings."""
    env = scene.environment
    settings = MPCSettings(compile=compile)
    if compile:
        quiet_known_inductor_warnings()
    return ContactImplicitMPC.from_env(
        env, scene.plant, paper_model(env.stiffness), settings=settings
    )


def evaluate_models(models: dict, steps, test, detector, weights, args) -> dict:
    """One-step and ``args.horizon``-step rollout errors of each model on the test split."""
    window = (args.horizon, args.stride)
    return {
        key: {
            "one_step": one_step_error(model, steps, weights),
            "rollout": rollout_error(model, test, detector, *window),
            "rollout_robot_recorded": rollout_error(model, test, detector, *window, "recorded"),
        }
        for key, model in models.items()
    }


def run(args: argparse.Namespace) -> dict:
    """Collect, split, sweep, fit and evaluate; returns the record written to results.json."""
    progress = not args.no_progress
    collect(
        args.data,
        args.scene,
        args.object,
        trajectories=args.trajectories,
        steps=args.steps,
        actions=args.actions,
        seed=args.seed,
        task=args.task,
        noise=args.noise,
        progress=progress,
        planner=functools.partial(collection_mpc, compile=not args.no_compile),
        workers=args.workers,
        backend=args.backend,
        address=args.address,
    )
    transitions = load(args.data, args.trajectories)
    meta = transitions.meta
    splits = dict(zip(("train", "val", "test"), transitions.split(seed=args.seed), strict=True))
    steps = {name: StepData.from_transitions(part, meta["facets"]) for name, part in splits.items()}
    detector = make_scene(args.scene, args.object, meta["task"]).plant.detector
    weights = tuple(meta["pose_weights"])

    sweep = sweep_constant(args.grid, splits["val"], detector, args.horizon, args.stride)
    best_k = min(sweep, key=lambda row: row["combined"])["stiffness"]
    names = [f.name for f in fields(FitConfig) if f.name != "initial_stiffness"]
    config = FitConfig(initial_stiffness=best_k, **{name: getattr(args, name) for name in names})
    result = fit(build_model(config, meta), steps["train"], steps["val"], weights, config, progress)

    models = {
        "paper_k": constant_model(meta["paper_stiffness"], meta),
        "best_constant_k": constant_model(best_k, meta),
        "learned": result.model,
    }
    evaluation = evaluate_models(models, steps["test"], splits["test"], detector, weights, args)
    args.results.mkdir(parents=True, exist_ok=True)
    save_checkpoint(args.results / "model.pt", result.model, config, meta)
    write_csv(args.results / "history.csv", result.history)

    def improvement(kind: str, statistic: str = "combined") -> float:
        learned, best = (evaluation[key][kind][statistic] for key in ("learned", "best_constant_k"))
        return 1.0 - learned / best

    return {
        **{f"rollout10_err_{key}": evaluation[key]["rollout"]["combined"] for key in MODELS},
        "improvement_vs_best_constant": improvement("rollout"),
        "improvement_vs_best_constant_median": improvement("rollout", "combined_median"),
        **{
            f"rollout10_robot_recorded_err_{key}": evaluation[key]["rollout_robot_recorded"][
                "combined"
            ]
            for key in MODELS
        },
        "improvement_vs_best_constant_robot_recorded": improvement("rollout_robot_recorded"),
        "fit_seconds": result.seconds,
        "transitions": len(transitions),
        "paper_k": meta["paper_stiffness"],
        "best_constant_k": best_k,
        "horizon": args.horizon,
        "scene": args.scene,
        "object": args.object,
        "data": str(args.data),
        "splits": {name: len(part) for name, part in splits.items()},
        "fit": {
            **asdict(config),
            "best_epoch": result.best_epoch,
            "epochs_run": len(result.history),
        },
        "sweep": sweep,
        "evaluation": evaluation,
        "still_object": still_error(splits["test"], args.horizon, args.stride),
    }


HEADLINE = (
    *(f"rollout10_err_{key}" for key in MODELS),
    "improvement_vs_best_constant",
    "improvement_vs_best_constant_median",
    *(f"rollout10_robot_recorded_err_{key}" for key in MODELS),
    "improvement_vs_best_constant_robot_recorded",
    "fit_seconds",
    "transitions",
    "paper_k",
    "best_constant_k",
    "horizon",
)


def print_table(record: dict, stiffness: str) -> None:
    """The comparison table of one run."""
    splits, fit_record, horizon = record["splits"], record["fit"], record["horizon"]
    print(
        f"{record['scene']} {record['object']}: {record['transitions']} transitions (train "
        f"{splits['train']}, val {splits['val']}, test {splits['test']}), fit "
        f"{record['fit_seconds']:.1f} s ({fit_record['epochs_run']} epochs, best "
        f"{fit_record['best_epoch']})"
    )
    header = f"{'pos mm':>8s} {'ang °':>7s} {'combined':>9s}"
    print(
        f"{'':<16s} {'':>15s} {'one step':^26s} {f'{horizon}-step rollout':^26s} "
        f"{'recorded robot':>14s}"
    )
    print(f"{'model':<16s} {'K':>15s} {header} {header} {'combined':>14s}")
    ks = {
        "paper_k": f"{record['paper_k']:g}",
        "best_constant_k": f"{record['best_constant_k']:.3g}",
        "learned": stiffness,
    }
    for key in MODELS:
        parts = record["evaluation"][key]
        cells = [
            f"{part['pos_mm']:>8.2f} {part['angle_deg']:>7.2f} {part['combined']:>9.2e}"
            for part in (parts["one_step"], parts["rollout"])
        ]
        recorded = parts["rollout_robot_recorded"]["combined"]
        print(f"{LABELS[key]:<16s} {ks[key]:>15s} {cells[0]} {cells[1]} {recorded:>14.2e}")
    still = record["still_object"]
    print(
        f"{'objects kept still':<32s} {'':>26s} {still['pos_mm']:>8.2f} "
        f"{still['angle_deg']:>7.2f} {still['combined']:>9.2e}  (how far they really moved)"
    )
    windows = record["evaluation"]["learned"]["rollout"]["windows"]
    print(
        f"{horizon}-step combined error, learned vs best constant K ({windows} test windows): "
        f"{100 * record['improvement_vs_best_constant']:.1f} % lower in the mean, "
        f"{100 * record['improvement_vs_best_constant_median']:.1f} % in the median, "
        f"{100 * record['improvement_vs_best_constant_robot_recorded']:.1f} % with the "
        "recorded robot motion"
    )


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    torch.set_num_threads(1)
    args = parse_args(argv)
    check_outputs(args)
    record = run(args)
    write_json(args.results / "results.json", record)
    if args.json is not None:
        write_json(args.json, {key: record[key] for key in HEADLINE})
    print_table(record, args.stiffness)
    print(f"wrote {args.results}/results.json, model.pt, history.csv")
    if args.ship:
        command = ["torchcontact", "learn-k", *(sys.argv[1:] if argv is None else argv)]
        path = ship_model(args.results / "model.pt", args.scene, record, command)
        print(f"shipped {path} and its manifest {path.with_suffix('.json').name}")
    return 0


def ship_model(checkpoint: Path, scene: str, record: dict, command: list[str]) -> Path:
    """Install ``checkpoint`` as ``scene``'s shipped model (:mod:`torchcontact.shipped`), with
    a manifest: the command, the dataset, the library versions, the file's SHA-256, the date,
    the commit and the validation figures of ``record``. Returns the model's path."""
    target = models_dir() / f"{scene}.pt"
    data = checkpoint.read_bytes()
    atomic_write(target, lambda f: f.write(data), binary=True)
    manifest = {
        "environment": scene,
        "command": shlex.join(command),
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "commit": _commit(),
        "sha256": file_sha256(target),
        "dataset": {
            "object": record["object"],
            "transitions": record["transitions"],
            "splits": record["splits"],
        },
        "fit": record["fit"],
        "versions": library_versions(),
        "validation": {key: record[key] for key in HEADLINE},
    }
    write_json(target.with_suffix(".json"), manifest)
    return target


def _commit() -> str | None:
    """The source checkout's commit, None outside a git checkout."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).parent,
            capture_output=True,
            text=True,
            check=True,
        )
    except (OSError, subprocess.CalledProcessError):
        return None
    return out.stdout.strip()
