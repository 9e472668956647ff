"""``torchcontact learn-k``: learn a scene's model from MuJoCo rollouts and judge it on unseen
objects.

The pipeline::

    collect(data/SCENE_OBJECT_..., scene, obj, ...)   # per object (reused, resumed)
    transitions = load_objects(...)                    # one set, objects indexed
    for each of --splits object splits (seed, seed + 1, ...):
        train, val, test = transitions.split_objects() # no object in two sets
        sweep = sweep_constant(grid, val, detectors)   # best constant K on val objects
        result = fit_steps(model, train, val, ...)     # K(q), D(q) and the system factors
                                                       # (--loss-contacts geometry: each
                                                       # object's torch geometry in the loss)
        evaluation = ... paper K, best K, learned      # 10-step rollouts on test objects

Writes ``OUT/SCENE_OBJECTS/results.json`` (everything measured, per split),
``model.pt`` (the first split's learned model, :func:`~torchcontact.checkpoint.load_checkpoint`),
``history.csv`` (its losses per epoch) and ``splits/`` (each split's record as it finished,
which a rerun with the same inputs reuses); ``--json PATH`` writes the headline figures: the
improvement over the best constant K on held-out objects, mean and standard deviation over the
splits. Errors are means over the test windows; the combined error is the MPC's
``w_p‖p − p*‖² + w_q(1 − ⟨q, q*⟩²)``.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import datetime
import functools
import hashlib
import math
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Mapping
from dataclasses import asdict, fields
from pathlib import Path

import torch
from tqdm.auto import tqdm

from torchcontact.calibration import MOMENTUM, OPTIONAL, PARTS
from torchcontact.checkpoint import (
    DAMPING_KINDS,
    LOSS_CONTACTS,
    STIFFNESS_KINDS,
    FitConfig,
    build_model,
    constant_model,
    save_checkpoint,
)
from torchcontact.cli import Parser
from torchcontact.cli.split_store import load_split, save_split, split_digest, split_path
from torchcontact.digests import content_sha256, file_sha256
from torchcontact.environments import environment
from torchcontact.environments.options import CostOptions
from torchcontact.environments.presets import MPCSettings
from torchcontact.learn.data import MANIFEST, collect, load_objects
from torchcontact.learn.evaluate import (
    log_grid,
    one_step_error,
    rollout_error,
    still_error,
    sweep_constant,
)
from torchcontact.learn.fit import StepData, fit_steps
from torchcontact.learn.policies import ACTIONS
from torchcontact.learn.residual_fit import fit_residual
from torchcontact.learn.scenes import BOX_PUSHING, SCENES, Scene, make_scene
from torchcontact.model import paper_model
from torchcontact.mpc.compile_notes import quiet_known_inductor_warnings
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.trials import library_versions
from torchcontact.object_sources import mesh_file_of
from torchcontact.parallel import BACKENDS, RAY_EXTRA, check_backend, parallel_map
from torchcontact.results import (
    atomic_write,
    writable_directory,
    writable_file,
    write_csv,
    write_json,
)
from torchcontact.shapes import load_object
from torchcontact.shipped import models_dir
from torchcontact.sim.geometry import scene_geometry

DEFAULT_STEPS = {"fingertips": 120, "trifinger": 50, "allegro": 50, "box_pushing": 100}
"""Steps per trajectory by scene: the fingertips start 0.2 m from the object."""

DEFAULT_OBJECTS = {
    "trifinger": "all,random:0-99",
    "allegro": "all,random:0-29",
    "fingertips": "cube,stick,bunny",
}
"""Objects by scene (``cube`` for box pushing): the hands' built-in ones and 30 generated
tuning objects (seeds below 1000, so the reported generated objects stay unseen); the
fingertips' objects whose model shares h = 0.1 s (the foam brick's has 0.05 s)."""

DEFAULT_CALIBRATE = {
    "trifinger": PARTS + (MOMENTUM,),
    "allegro": tuple(part for part in PARTS if part != "friction"),
}
"""The system factors fitted by default, by scene: the four parts (measured best with μ,
docs/experiments.md); on the TriFinger the object's momentum too (measured there: its objects
tip); on the Allegro all but μ (a fitted μ of 2.9 doubled its falls in closed loop, and no
later Allegro fit used it: docs/experiments.md, "why the learned Allegro model drops
objects")."""

MODELS = ("paper_k", "best_constant_k", "learned")
LABELS = {"paper_k": "paper K", "best_constant_k": "best constant K", "learned": "learned"}
ABLATIONS = {
    "calibrated_constant_k": {"stiffness": "constant", "damping": "paper"},
    "uncalibrated_learned": {"calibrate": ()},
}
"""``--ablate``'s extra fits per split: the best constant K with the system factors fitted, and
the learned K(q), D(q) without them (each otherwise as the learned model)."""

WITHOUT_RESIDUAL = "learned_without_residual"
"""With ``--residual``: the learned model before its residual, evaluated beside it."""


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = Parser(
        prog="torchcontact learn-k",
        description="Learn the contact model K(q), D(q) and the system's factors from MuJoCo "
        "rollouts of many objects; judge it on held-out objects.",
    )
    add = parser.add_argument
    add("--scene", choices=SCENES, default="trifinger")
    add(
        "--object",
        default=None,
        help="objects, comma-separated: names, 'all' (the built-in ones), random-SEED, "
        f"random:A-B (tune on seeds < 1000) or mesh files (default {DEFAULT_OBJECTS}, else all)",
    )
    add("--task", default=None, help="the suite task whose sampler starts each trajectory")
    add(
        "--trajectories",
        type=int,
        default=20,
        help="trajectories per object (collected if missing)",
    )
    add("--steps", type=int, default=None, help=f"steps per trajectory (default {DEFAULT_STEPS})")
    add(
        "--actions",
        choices=ACTIONS,
        default=None,
        help="action source (default mpc; random for box_pushing, which has no MPC task)",
    )
    add("--noise", type=float, default=None, help="exploration noise, fraction of the bound")
    add("--no-compile", action="store_true", help="eager MPC while collecting")
    add(
        "--workers",
        type=int,
        default=1,
        help="parallel collection processes (or Ray CPUs), and splits fitted at a time (local "
        "processes)",
    )
    add("--backend", choices=BACKENDS, default="local", help=f"local or Ray ({RAY_EXTRA})")
    add("--address", default=None, help="(ray) a running cluster's address")
    add("--data", type=Path, default=None, help="folder of the datasets (default OUT/data)")
    add(
        "--split",
        choices=("objects", "trajectories"),
        default=None,
        help="hold out whole objects (default, 3+ objects) or trajectories (one object)",
    )
    add("--splits", type=int, default=5, help="random splits, each fitted and judged")
    add("--stiffness", choices=STIFFNESS_KINDS, default="contact_network", help="K(q)")
    add("--damping", choices=DAMPING_KINDS, default="contact_network", help="D(q)")
    add(
        "--calibrate",
        default=None,
        help=f"system factors fitted with K and D, comma-separated from {PARTS + OPTIONAL}, "
        f"or 'none' (default {','.join(PARTS)}, with {MOMENTUM} on the TriFinger and "
        "without friction on the Allegro)",
    )
    add("--loss-horizon", type=int, default=1, help="steps of the training loss's rollouts")
    add(
        "--loss-contacts",
        choices=LOSS_CONTACTS,
        default="frozen",
        help="contacts of the loss's steps after a window's first: frozen (those recorded at "
        "its first state, as the MPC plans; default) or geometry (each object's torch contact "
        "geometry at every predicted state; needs --loss-horizon 2 or more)",
    )
    add(
        "--residual",
        type=int,
        default=0,
        metavar="H",
        help="fit an object residual of H hidden units after K, D and the factors "
        "(torchcontact.residual): better prediction; the MPC plans with it, but on the Allegro "
        "it planned worse (README); 0: none (default)",
    )
    add(
        "--robot-weight",
        type=float,
        default=1.0,
        help="weight of the robot's coordinates' squared error in the loss [1/rad² or 1/m²]",
    )
    add(
        "--gamma",
        type=float,
        default=None,
        help="softplus sharpness γ of the fitted and compared models (default the scene's, "
        "as its MPC plans)",
    )
    add("--hidden", type=int, default=32, help="hidden units of the networks")
    add("--distance-scale", type=float, default=1e-4, help="φ feature scale [m]")
    add("--epochs", type=int, default=300)
    add("--batch-size", type=int, default=512)
    add("--lr", type=float, default=3e-3)
    add("--patience", type=int, default=40, help="early stopping patience [epochs]")
    add("--device", default="cpu", help="where the fit runs: cpu or cuda")
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
    add("--seed", type=int, default=0, help="data seed and the first split's seed")
    add("--out", type=Path, default=Path("results/learn"))
    add("--json", type=Path, default=None, help="write the headline figures here")
    add(
        "--ship",
        action="store_true",
        help="also install the first split's model as the scene's shipped default, with its "
        "manifest (torchcontact/assets/models/SCENE.pt and .json)",
    )
    add(
        "--ablate",
        action="store_true",
        help=f"also fit and evaluate {tuple(ABLATIONS)} on each split (two more fits)",
    )
    add("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    positive = ("hidden", "epochs", "batch_size", "patience", "horizon", "stride", "workers")
    positive += ("trajectories", "steps")
    for name in (*positive, "splits", "loss_horizon"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    try:
        check_backend(args.workers, args.backend, args.address)
    except (ValueError, ImportError) as error:
        parser.error(f"--backend/--address/--workers: {error}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    for name in ("distance_scale", "gamma"):  # gamma None: the scene's
        value = getattr(args, name)
        if value is not None and not 0 < value < math.inf:
            parser.error(f"--{name.replace('_', '-')} must be positive and finite, got {value}")
    if args.noise is not None and not 0 <= args.noise < math.inf:
        parser.error(
            f"--noise must be a non-negative finite fraction of the control bound, got {args.noise}"
        )
    if args.device not in ("cpu", "cuda") and not args.device.startswith("cuda:"):
        parser.error(f"--device must be cpu or cuda, got {args.device!r}")
    if args.device != "cpu" and not torch.cuda.is_available():
        parser.error(f"--device {args.device}: this machine has no CUDA device")
    if args.calibrate is None:
        args.calibrate = DEFAULT_CALIBRATE.get(args.scene, PARTS)
    else:
        args.calibrate = () if args.calibrate == "none" else tuple(args.calibrate.split(","))
    if args.loss_contacts == "geometry" and args.loss_horizon == 1:
        parser.error(
            "--loss-contacts geometry needs --loss-horizon 2 or more: one step sees no new state"
        )
    _check_fit_options(parser, args)
    _check_scene(parser, args)
    args.steps = DEFAULT_STEPS[args.scene] if args.steps is None else args.steps
    if args.actions is None:
        args.actions = "random" if args.scene == BOX_PUSHING else "mpc"
    elif args.scene == BOX_PUSHING and args.actions != "random":
        parser.error(f"--actions must be random for box_pushing (no MPC task), got {args.actions}")
    if args.steps <= max(args.horizon, args.loss_horizon):
        parser.error(
            f"--steps must exceed --horizon and --loss-horizon "
            f"({max(args.horizon, args.loss_horizon)}), got {args.steps}"
        )
    _check_split(parser, args)
    low, high, count = args.sweep
    if not (0 < low < high < math.inf) or count < 2 or count != int(count):
        parser.error(f"--sweep needs finite 0 < LOW < HIGH and an integer N >= 2, got {args.sweep}")
    args.grid = log_grid(low, high, int(count))
    args.results = args.out / f"{args.scene}_{results_label(args.object, args.objects)}"
    if args.data is None:
        args.data = args.out / "data"
    return args


RESULTS_LABEL_LIMIT = 80
"""The longest ``--object`` label a results folder's name takes whole (a file name holds 255
bytes); a longer one is cut and given a digest of the whole spec, so it stays unique."""


def results_label(spec: str, objects: list[str]) -> str:
    """The results folder's label for ``--object spec`` (expanded to ``objects``): a lone
    object's file stem, or the spec with its separators as ``_``, cut to
    :data:`RESULTS_LABEL_LIMIT` characters plus a digest of ``spec`` when longer."""
    label = Path(spec).stem if len(objects) == 1 else re.sub(r"[,:/]", "_", spec)
    if len(label) <= RESULTS_LABEL_LIMIT:
        return label
    digest = hashlib.sha256(spec.encode()).hexdigest()[:12]
    return f"{label[: RESULTS_LABEL_LIMIT - len(digest) - 1]}_{digest}"


def _check_fit_options(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """The checks of :class:`FitConfig` on the options that become its fields."""
    try:
        FitConfig(**_fit_fields(args))
    except ValueError as error:
        field, _, rest = str(error).partition(" ")
        parser.error(f"--{field.replace('_', '-')} {rest}")


def _fit_fields(args: argparse.Namespace) -> dict:
    """The options that are :class:`FitConfig` fields, by name."""
    return {
        f.name: getattr(args, f.name) for f in fields(FitConfig) if f.name != "initial_stiffness"
    }


def _check_scene(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--object`` and ``--task`` against the scene (as :func:`make_scene` does); sets
    ``args.objects``, the object names in order."""
    if args.scene == BOX_PUSHING:
        args.object = args.object or "cube"
        if args.object != "cube" or args.task not in (None, "push"):
            parser.error(
                f"--object and --task of box_pushing are cube and push only, got "
                f"{args.object!r}, {args.task!r}"
            )
        args.objects = ["cube"]
        return
    env = environment(args.scene)
    if args.object is None:
        args.object = DEFAULT_OBJECTS.get(args.scene, "all")
    objects = []
    for piece in args.object.split(","):
        try:
            pairs = env.select(args.task or "all", piece)
        except ValueError as error:
            parser.error(str(error))
        objects += [obj for _, obj in pairs]
    args.objects = list(dict.fromkeys(objects))
    for obj in args.objects:  # read each mesh file once, before anything is collected
        path = mesh_file_of(obj)
        if path is not None:
            try:
                load_object(path, decomposition="hull")
            except ValueError as error:
                parser.error(f"--object {obj!r} must be a usable mesh file: {error}")


def _check_split(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--split`` (defaulted by the object count) against the objects and trajectories."""
    if args.split is None:
        args.split = "objects" if len(args.objects) >= 3 else "trajectories"
    if args.split == "objects" and len(args.objects) < 3:
        parser.error(
            f"--split objects needs 3 or more objects (train, val, test), got {args.objects}; "
            "use --split trajectories"
        )
    if args.split == "trajectories" and args.trajectories * len(args.objects) < 3:
        parser.error(
            f"--trajectories must give 3 or more trajectories (train, val, test), got "
            f"{args.trajectories}"
        )


def dataset_dir(args: argparse.Namespace, obj: str) -> Path:
    """The dataset folder of object ``obj`` under ``--data``: an object from a mesh file (a
    path, or a registered source's) has 8 hex digits of the file's SHA-256 in it
    (``cube-mesh-1a2b3c4d``), so a changed mesh gets data of its own and a user's ``cube.stl``
    never shares the built-in cube's."""
    path = mesh_file_of(obj)
    name = obj if path is None else f"{path.stem}-mesh-{content_sha256(path)[:8]}"
    return args.data / f"{args.scene}_{name}_{args.actions}_steps{args.steps}_seed{args.seed}"


def check_outputs(args: argparse.Namespace) -> None:
    """Check, before anything runs, that every output can be written: ``--out`` (created),
    the results folder, the datasets' folders under ``--data`` and ``--json``."""
    writable_directory("--out", args.out)
    writable_directory("--out", args.results, create=False)
    writable_directory("--data", args.data, create=False)
    for obj in args.objects:
        directory = dataset_dir(args, obj)
        if (directory / MANIFEST).is_dir():
            raise ValueError(
                f"--data must hold dataset folders, {directory / MANIFEST} is a folder"
            )
    if args.json is not None:
        writable_file("--json", args.json)


def collection_mpc(scene: Scene, compile: bool = True) -> ContactImplicitMPC:
    """The MPC whose actions the data are collected with: the paper's model at the paper's K,
    the paper's solver settings and the environment's cost without its hold-first
    term (the data the shipped models were fitted on were collected so)."""
    env = scene.environment
    settings = MPCSettings(compile=compile)
    if compile:
        quiet_known_inductor_warnings()
    cost = env.cost(scene.plant, CostOptions(hold_first=0))
    return ContactImplicitMPC.from_env(
        env, scene.plant, paper_model(env.stiffness), settings=settings, cost=cost
    )


def evaluate_models(models: dict, test, detectors, weights, args) -> dict:
    """One-step and ``args.horizon``-step rollout errors of each model on the test set."""
    window = (args.horizon, args.stride)
    steps = StepData.from_transitions(test)
    return {
        key: {
            "one_step": one_step_error(model, steps, weights),
            "rollout": rollout_error(model, test, detectors, *window),
            "rollout_robot_recorded": rollout_error(model, test, detectors, *window, "recorded"),
        }
        for key, model in models.items()
    }


def collect_all(args: argparse.Namespace) -> list[Path]:
    """Each object's dataset (collected where missing); returns their folders."""
    directories = []
    for obj in args.objects:
        directories.append(dataset_dir(args, obj))
        collect(
            directories[-1],
            args.scene,
            obj,
            trajectories=args.trajectories,
            steps=args.steps,
            actions=args.actions,
            seed=args.seed,
            task=args.task,
            noise=args.noise,
            progress=not args.no_progress,
            planner=functools.partial(collection_mpc, compile=not args.no_compile),
            workers=args.workers,
            backend=args.backend,
            address=args.address,
        )
    return directories


def run_split(transitions, detectors, seed: int, args: argparse.Namespace) -> dict:
    """One split: sweep the constant K on its validation objects, fit on its training
    objects, evaluate on its test objects. Returns its record, with ``"model"`` (the fitted
    model), ``"config"`` and ``"history"``."""
    meta = transitions.meta
    if args.split == "objects":
        parts = transitions.split_objects(seed=seed)
    else:
        parts = transitions.split(seed=seed)
    train, val, test = parts
    weights = tuple(meta["pose_weights"])
    sweep = sweep_constant(args.grid, val, detectors, args.horizon, args.stride)
    best_k = min(sweep, key=lambda row: row["combined"])["stiffness"]
    config = FitConfig(initial_stiffness=best_k, **{**_fit_fields(args), "seed": seed})
    data = {
        name: StepData.from_transitions(part, args.loss_horizon).to(args.device)
        for name, part in (("train", train), ("val", val))
    }
    progress = not args.no_progress
    geometries = None
    if config.loss_contacts == "geometry":
        geometries = object_geometries(detectors, meta["objects"], data["train"].q.dtype)
    fit_model = functools.partial(fit_steps, progress=progress, geometries=geometries)
    contact_only = dataclasses.replace(config, residual=0)  # the residual comes second
    result = fit_model(build_model(contact_only, meta), data["train"], data["val"], weights, config)
    learned, extra, seconds = result.model, {}, result.seconds
    if config.residual:
        extra[WITHOUT_RESIDUAL] = copy.deepcopy(learned).cpu()
        train, val = data["train"], data["val"]
        seconds += fit_residual(learned, train, val, meta["joints"], config, progress).seconds
    learned = learned.cpu()
    models = {
        "paper_k": constant_model(meta["paper_stiffness"], meta),
        "best_constant_k": constant_model(best_k, meta),
        "learned": learned,
        **extra,
    }
    for key, change in ABLATIONS.items() if args.ablate else ():
        variant = dataclasses.replace(config, **change)
        model = build_model(variant, meta)
        models[key] = fit_model(model, data["train"], data["val"], weights, variant).model
        models[key] = models[key].cpu()
    evaluation = evaluate_models(models, test, detectors, weights, args)

    def improvement(kind: str, statistic: str = "combined") -> float:
        mine, best = (evaluation[key][kind][statistic] for key in ("learned", "best_constant_k"))
        return 1.0 - mine / best

    names = meta["objects"]
    return {
        "seed": seed,
        **{
            f"{name}_objects": [names[i] for i in part.object_ids()]
            for name, part in zip(("train", "val", "test"), parts, strict=True)
        },
        "transitions": {
            name: len(part) for name, part in zip(("train", "val", "test"), parts, strict=True)
        },
        **{f"rollout10_err_{key}": evaluation[key]["rollout"]["combined"] for key in models},
        "improvement_vs_best_constant": improvement("rollout"),
        "improvement_vs_best_constant_median": improvement("rollout", "combined_median"),
        **{
            f"rollout10_robot_recorded_err_{key}": evaluation[key]["rollout_robot_recorded"][
                "combined"
            ]
            for key in MODELS
        },
        "improvement_vs_best_constant_robot_recorded": improvement("rollout_robot_recorded"),
        "best_constant_k": best_k,
        "fit_seconds": seconds,
        "fit": {
            **asdict(config),
            "best_epoch": result.best_epoch,
            "epochs_run": len(result.history),
        },
        "calibration": None if learned.calibration is None else learned.calibration.summary(),
        "sweep": sweep,
        "evaluation": evaluation,
        "still_object": still_error(test, args.horizon, args.stride),
        "model": learned,
        "config": config,
        "history": result.history,
    }


def _mean_sd(values: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value)."""
    mean = sum(values) / len(values)
    if len(values) < 2:
        return mean, 0.0
    return mean, math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))


AVERAGED = (
    *(f"rollout10_err_{key}" for key in MODELS),
    "improvement_vs_best_constant",
    "improvement_vs_best_constant_median",
    *(f"rollout10_robot_recorded_err_{key}" for key in MODELS),
    "improvement_vs_best_constant_robot_recorded",
    "fit_seconds",
)
"""Per-split figures the record gives as the mean over splits (and ``…_sd``)."""


def load_transitions(directories: list[Path], args: argparse.Namespace):
    """The datasets as one :class:`~torchcontact.learn.data.Transitions`, ``--gamma``'s γ in
    its meta."""
    transitions = load_objects(directories, args.trajectories)
    if args.gamma is not None:  # the data hold MuJoCo's motion, whatever γ the models use
        transitions.meta["gamma"] = args.gamma
    return transitions


def object_detectors(args: argparse.Namespace) -> dict:
    """Each object's contact detector, by name."""
    return {obj: make_scene(args.scene, obj, args.task).plant.detector for obj in args.objects}


def object_geometries(detectors, names: list[str], dtype: torch.dtype) -> list:
    """Each object's torch contact geometry (:func:`~torchcontact.sim.geometry.scene_geometry`
    of its detector, in ``dtype``), in the order of ``names`` (``meta["objects"]``: the
    windows' object indices); ``detectors``: by name, or one for all."""
    found = []
    for name in names:
        detector = detectors[name] if isinstance(detectors, Mapping) else detectors
        found.append(scene_geometry(detector, dtype=dtype))
    return found


@dataclasses.dataclass(frozen=True)
class _SplitJob:
    """One split fitted in a worker process, which reads the datasets itself."""

    directories: tuple[Path, ...]
    seed: int
    args: argparse.Namespace


_loaded: dict[tuple, tuple] = {}
"""A worker process's datasets, read once for all the splits it fits."""


def _fit_split(job: _SplitJob) -> dict:
    args = job.args
    key = (job.directories, args.trajectories, args.gamma, args.scene, args.task)
    if key not in _loaded:
        _loaded.clear()
        _loaded[key] = load_transitions(list(job.directories), args), object_detectors(args)
    torch.set_num_threads(1)
    return run_split(*_loaded[key], job.seed, args)


def deciding_options(args: argparse.Namespace) -> argparse.Namespace:
    """``args`` as :func:`~torchcontact.cli.split_store.split_digest` reads them: without
    ``--loss-contacts`` at its default (frozen), so the records saved before the option
    existed, whose fits were frozen, keep their digest and are reused."""
    if args.loss_contacts != "frozen":
        return args
    return argparse.Namespace(**{k: v for k, v in vars(args).items() if k != "loss_contacts"})


def fit_splits(directories: list[Path], args: argparse.Namespace):
    """The datasets' transitions and every split's :func:`run_split` record, in split order.

    Each record is saved as its split finishes, and a rerun with the same inputs reuses the
    saved ones (:mod:`~torchcontact.cli.split_store`). With ``--workers N`` above 1, N splits
    at a time are fitted in spawned local processes of one thread each, each reading the
    datasets; every split is seeded, so the records match a serial run's."""
    transitions = load_transitions(directories, args)
    digest = split_digest(deciding_options(args), directories)
    paths = [split_path(args.results, args.seed + i, digest) for i in range(args.splits)]
    splits = [load_split(path) for path in paths]
    missing = [index for index, split in enumerate(splits) if split is None]
    if len(missing) < len(splits):
        reused = [split["seed"] for split in splits if split is not None]
        print(f"splits {reused} reused from {paths[0].parent} (same options and data)")

    def finished(index: int, record: dict) -> None:
        save_split(paths[index], record)
        splits[index] = record
        bar.update()

    with tqdm(total=len(missing), desc="splits", disable=args.no_progress, unit="split") as bar:
        if args.workers == 1 or len(missing) <= 1:
            detectors = object_detectors(args) if missing else None
            for index in missing:
                finished(index, run_split(transitions, detectors, args.seed + index, args))
            return transitions, splits
        quiet = argparse.Namespace(**{**vars(args), "no_progress": True})  # one bar: this one
        jobs = [_SplitJob(tuple(directories), args.seed + index, quiet) for index in missing]
        for job, record in parallel_map(_fit_split, jobs, args.workers):
            finished(missing[job], record)
    return transitions, splits


def run(args: argparse.Namespace) -> dict:
    """Collect, then per split sweep, fit and evaluate; returns the record written to
    results.json (the first split's model saved beside it)."""
    transitions, splits = fit_splits(collect_all(args), args)
    first = splits[0]
    args.results.mkdir(parents=True, exist_ok=True)
    save_checkpoint(args.results / "model.pt", first["model"], first["config"], transitions.meta)
    write_csv(args.results / "history.csv", first["history"])
    summary = {}
    ablated = [f"rollout10_err_{key}" for key in ABLATIONS if args.ablate]
    ablated += [f"rollout10_err_{WITHOUT_RESIDUAL}"] if args.residual else []
    for key in (*AVERAGED, *ablated):
        summary[key], summary[f"{key}_sd"] = _mean_sd([split[key] for split in splits])
    meta = transitions.meta
    return {
        **summary,
        "transitions": len(transitions),
        "paper_k": meta["paper_stiffness"],
        "horizon": args.horizon,
        "scene": args.scene,
        "objects": meta["objects"],
        "split": args.split,
        "data": str(args.data),
        "splits": [
            {k: v for k, v in split.items() if k not in ("model", "config", "history")}
            for split in splits
        ],
    }


HEADLINE = (
    *AVERAGED,
    "improvement_vs_best_constant_sd",
    "transitions",
    "paper_k",
    "horizon",
    "split",
)


def headline(record: dict) -> dict:
    """The ``--json`` figures: means and ``improvement_vs_best_constant_sd`` over the splits,
    and each split's objects, best constant K and figures (``splits``)."""
    keep = ("seed", "train_objects", "val_objects", "test_objects", "best_constant_k")
    keep += AVERAGED + ("calibration",)
    return {
        **{key: record[key] for key in HEADLINE},
        "splits": [{k: split[k] for k in keep} for split in record["splits"]],
    }


def print_table(record: dict, stiffness: str) -> None:
    """The comparison table: per split, then the mean ± sd."""
    splits, horizon = record["splits"], record["horizon"]
    held = "objects" if record["split"] == "objects" else "trajectories"
    print(
        f"{record['scene']}: {record['transitions']} transitions of {len(record['objects'])} "
        f"objects, {len(splits)} splits by {held}; {horizon}-step rollout combined error on "
        f"held-out {held}"
    )
    print(
        f"{'split':>5s} {'test objects':<28s} {'paper K':>9s} {'best K':>14s} "
        f"{'learned':>9s} {'gain':>7s}"
    )
    for split in splits:
        test = ",".join(split["test_objects"])
        test = test if len(test) <= 28 else test[:25] + "..."
        best = f"{split['rollout10_err_best_constant_k']:.3g} (K={split['best_constant_k']:.3g})"
        print(
            f"{split['seed']:>5d} {test:<28s} {split['rollout10_err_paper_k']:>9.3g} "
            f"{best:>14s} {split['rollout10_err_learned']:>9.3g} "
            f"{100 * split['improvement_vs_best_constant']:>6.1f}%"
        )
    print(
        f"learned ({stiffness}) vs best constant K: "
        f"{100 * record['improvement_vs_best_constant']:.1f} ± "
        f"{100 * record['improvement_vs_best_constant_sd']:.1f} % lower in the mean over "
        f"splits; median-window {100 * record['improvement_vs_best_constant_median']:.1f} %; "
        f"with the recorded robot motion "
        f"{100 * record['improvement_vs_best_constant_robot_recorded']:.1f} %"
    )
    ablations = [key for key in (*ABLATIONS, WITHOUT_RESIDUAL) if f"rollout10_err_{key}" in record]
    if ablations:
        cells = ", ".join(
            f"{key.replace('_', ' ')} {record[f'rollout10_err_{key}']:.3g}" for key in ablations
        )
        print(
            f"ablations, mean {horizon}-step combined error over splits: {cells} (learned "
            f"{record['rollout10_err_learned']:.3g}, best constant K "
            f"{record['rollout10_err_best_constant_k']:.3g})"
        )
    calibration = splits[0].get("calibration")
    if calibration:
        factors = ", ".join(f"{name} {_fmt(values)}" for name, values in calibration.items())
        print(f"first split's system factors: {factors}")


def _fmt(values: list[float]) -> str:
    return (
        f"{values[0]:.3g}" if len(values) == 1 else "[" + " ".join(f"{v:.2f}" for v in values) + "]"
    )


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    torch.set_num_threads(1)
    args = parse_args(argv)
    check_outputs(args)
    record = run(args)
    write_json(args.results / "results.json", record)
    if args.json is not None:
        write_json(args.json, headline(record))
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
            "objects": record["objects"],
            "transitions": record["transitions"],
            "split": record["split"],
            "model_split": {
                k: record["splits"][0][k]
                for k in ("seed", "train_objects", "val_objects", "test_objects")
            },
        },
        "fit": record["splits"][0]["fit"],
        "versions": library_versions(),
        "validation": headline(record),
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
