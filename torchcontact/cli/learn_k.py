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
``w_p‖p − p*‖² + w_q(1 − ⟨q, q*⟩²)``. Every stage reads its settings from one
:class:`~torchcontact.cli.learn_config.LearnConfig`.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import datetime
import functools
import math
import os
import shlex
import subprocess
import sys
from collections.abc import Mapping
from dataclasses import asdict
from pathlib import Path

import torch
from tqdm.auto import tqdm

from torchcontact.checkpoint import build_model, constant_model, save_checkpoint
from torchcontact.cli.learn_config import ABLATIONS, LearnConfig, parse_config
from torchcontact.cli.split_store import load_split, save_split, split_digest, split_path
from torchcontact.digests import content_sha256, file_sha256
from torchcontact.environments.options import CostOptions
from torchcontact.environments.presets import MPCSettings
from torchcontact.learn.data import MANIFEST, collect, load_objects
from torchcontact.learn.evaluate import one_step_error, rollout_error, still_error, sweep_constant
from torchcontact.learn.fit import StepData, fit_steps
from torchcontact.learn.residual_fit import fit_residual
from torchcontact.learn.scenes import Scene, make_scene
from torchcontact.model import paper_model
from torchcontact.mpc.compile_notes import quiet_known_inductor_warnings
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.trials import library_versions
from torchcontact.object_sources import mesh_file_of
from torchcontact.parallel import parallel_map
from torchcontact.results import (
    atomic_write,
    writable_directory,
    writable_file,
    write_csv,
    write_json,
)
from torchcontact.shipped import models_dir
from torchcontact.sim.geometry import scene_geometry

MODELS = ("paper_k", "best_constant_k", "learned")

WITHOUT_RESIDUAL = "learned_without_residual"
"""With ``--residual``: the learned model before its residual, evaluated beside it."""


def dataset_dir(config: LearnConfig, obj: str) -> Path:
    """The dataset folder of object ``obj`` under ``--data``: an object from a mesh file (a
    path, or a registered source's) has 8 hex digits of the file's SHA-256 in it
    (``cube-mesh-1a2b3c4d``), so a changed mesh gets data of its own and a user's ``cube.stl``
    never shares the built-in cube's."""
    path = mesh_file_of(obj)
    name = obj if path is None else f"{path.stem}-mesh-{content_sha256(path)[:8]}"
    folder = f"{config.scene}_{name}_{config.actions}_steps{config.steps}_seed{config.seed}"
    return config.data / folder


def check_outputs(config: LearnConfig) -> None:
    """Check, before anything runs, that every output can be written: ``--out`` (created),
    the results folder, the datasets' folders under ``--data`` and ``--json``."""
    writable_directory("--out", config.out)
    writable_directory("--out", config.results, create=False)
    writable_directory("--data", config.data, create=False)
    for obj in config.objects:
        directory = dataset_dir(config, obj)
        if (directory / MANIFEST).is_dir():
            raise ValueError(
                f"--data must hold dataset folders, {directory / MANIFEST} is a folder"
            )
    if config.json is not None:
        writable_file("--json", config.json)


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


def evaluate_models(models: dict, test, detectors, weights, config: LearnConfig) -> dict:
    """One-step and ``config.horizon``-step rollout errors of each model on the test set."""
    window = (config.horizon, config.stride)
    steps = StepData.from_transitions(test)
    return {
        key: {
            "one_step": one_step_error(model, steps, weights),
            "rollout": rollout_error(model, test, detectors, *window),
            "rollout_robot_recorded": rollout_error(model, test, detectors, *window, "recorded"),
        }
        for key, model in models.items()
    }


def collect_all(config: LearnConfig) -> list[Path]:
    """Each object's dataset (collected where missing); returns their folders."""
    directories = []
    for obj in config.objects:
        directories.append(dataset_dir(config, obj))
        collect(
            directories[-1],
            config.scene,
            obj,
            trajectories=config.trajectories,
            steps=config.steps,
            actions=config.actions,
            seed=config.seed,
            task=config.task,
            noise=config.noise,
            progress=not config.no_progress,
            planner=functools.partial(collection_mpc, compile=not config.no_compile),
            workers=config.workers,
            backend=config.backend,
            address=config.address,
        )
    return directories


def run_split(transitions, detectors, seed: int, config: LearnConfig) -> dict:
    """One split: sweep the constant K on its validation objects, fit on its training
    objects, evaluate on its test objects. Returns its record, with ``"model"`` (the fitted
    model), ``"config"`` and ``"history"``."""
    meta = transitions.meta
    if config.split == "objects":
        parts = transitions.split_objects(seed=seed)
    else:
        parts = transitions.split(seed=seed)
    train, val, test = parts
    weights = tuple(meta["pose_weights"])
    sweep = sweep_constant(config.grid, val, detectors, config.horizon, config.stride)
    best_k = min(sweep, key=lambda row: row["combined"])["stiffness"]
    fit = dataclasses.replace(config.fit, initial_stiffness=best_k, seed=seed)
    data = {
        name: StepData.from_transitions(part, fit.loss_horizon).to(config.device)
        for name, part in (("train", train), ("val", val))
    }
    progress = not config.no_progress
    geometries = None
    if fit.loss_contacts == "geometry":
        geometries = object_geometries(detectors, meta["objects"], data["train"].q.dtype)
    fit_model = functools.partial(fit_steps, progress=progress, geometries=geometries)
    contact_only = dataclasses.replace(fit, residual=0)  # the residual comes second
    result = fit_model(build_model(contact_only, meta), data["train"], data["val"], weights, fit)
    learned, extra, seconds = result.model, {}, result.seconds
    if fit.residual:
        extra[WITHOUT_RESIDUAL] = copy.deepcopy(learned).cpu()
        train, val = data["train"], data["val"]
        seconds += fit_residual(learned, train, val, meta["joints"], fit, progress).seconds
    learned = learned.cpu()
    models = {
        "paper_k": constant_model(meta["paper_stiffness"], meta),
        "best_constant_k": constant_model(best_k, meta),
        "learned": learned,
        **extra,
    }
    for key, change in ABLATIONS.items() if config.ablate else ():
        variant = dataclasses.replace(fit, **change)
        model = build_model(variant, meta)
        models[key] = fit_model(model, data["train"], data["val"], weights, variant).model
        models[key] = models[key].cpu()
    evaluation = evaluate_models(models, test, detectors, weights, config)

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
            **asdict(fit),
            "best_epoch": result.best_epoch,
            "epochs_run": len(result.history),
        },
        "calibration": None if learned.calibration is None else learned.calibration.summary(),
        "sweep": sweep,
        "evaluation": evaluation,
        "still_object": still_error(test, config.horizon, config.stride),
        "model": learned,
        "config": fit,
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


def load_transitions(directories: list[Path], config: LearnConfig):
    """The datasets as one :class:`~torchcontact.learn.data.Transitions`, ``--gamma``'s γ in
    its meta."""
    transitions = load_objects(directories, config.trajectories)
    if config.gamma is not None:  # the data hold MuJoCo's motion, whatever γ the models use
        transitions.meta["gamma"] = config.gamma
    return transitions


def object_detectors(config: LearnConfig) -> dict:
    """Each object's contact detector, by name."""
    return {
        obj: make_scene(config.scene, obj, config.task).plant.detector for obj in config.objects
    }


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
    config: LearnConfig


_loaded: dict[tuple, tuple] = {}
"""A worker process's datasets, read once for all the splits it fits."""


def _fit_split(job: _SplitJob) -> dict:
    config = job.config
    key = (job.directories, config.trajectories, config.gamma, config.scene, config.task)
    if key not in _loaded:
        _loaded.clear()
        _loaded[key] = load_transitions(list(job.directories), config), object_detectors(config)
    torch.set_num_threads(1)
    return run_split(*_loaded[key], job.seed, config)


def deciding_options(config: LearnConfig) -> argparse.Namespace:
    """``config`` as :func:`~torchcontact.cli.split_store.split_digest` reads it: one flat
    namespace of the options by name (the fit's among them, less its per-split seed and K),
    without ``--loss-contacts`` at its default (frozen), so the records saved before the option
    existed, whose fits were frozen, keep their digest and are reused."""
    options = {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}
    fit = asdict(options.pop("fit"))
    options |= {k: v for k, v in fit.items() if k not in ("initial_stiffness", "seed")}
    if options["loss_contacts"] == "frozen":
        del options["loss_contacts"]
    return argparse.Namespace(**options)


def fit_splits(directories: list[Path], config: LearnConfig):
    """The datasets' transitions and every split's :func:`run_split` record, in split order.

    Each record is saved as its split finishes, and a rerun with the same inputs reuses the
    saved ones (:mod:`~torchcontact.cli.split_store`). With ``--workers N`` above 1, N splits
    at a time are fitted in spawned local processes of one thread each, each reading the
    datasets; every split is seeded, so the records match a serial run's."""
    transitions = load_transitions(directories, config)
    digest = split_digest(deciding_options(config), directories)
    paths = [split_path(config.results, config.seed + i, digest) for i in range(config.splits)]
    splits = [load_split(path) for path in paths]
    missing = [index for index, split in enumerate(splits) if split is None]
    if len(missing) < len(splits):
        reused = [split["seed"] for split in splits if split is not None]
        print(f"splits {reused} reused from {paths[0].parent} (same options and data)")

    def finished(index: int, record: dict) -> None:
        save_split(paths[index], record)
        splits[index] = record
        bar.update()

    with tqdm(total=len(missing), desc="splits", disable=config.no_progress, unit="split") as bar:
        if config.workers == 1 or len(missing) <= 1:
            detectors = object_detectors(config) if missing else None
            for index in missing:
                finished(index, run_split(transitions, detectors, config.seed + index, config))
            return transitions, splits
        quiet = dataclasses.replace(config, no_progress=True)  # one bar: this one
        jobs = [_SplitJob(tuple(directories), config.seed + index, quiet) for index in missing]
        for job, record in parallel_map(_fit_split, jobs, config.workers):
            finished(missing[job], record)
    return transitions, splits


def run(config: LearnConfig) -> dict:
    """Collect, then per split sweep, fit and evaluate; returns the record written to
    results.json (the first split's model saved beside it)."""
    transitions, splits = fit_splits(collect_all(config), config)
    first = splits[0]
    config.results.mkdir(parents=True, exist_ok=True)
    save_checkpoint(config.results / "model.pt", first["model"], first["config"], transitions.meta)
    write_csv(config.results / "history.csv", first["history"])
    summary = {}
    ablated = [f"rollout10_err_{key}" for key in ABLATIONS if config.ablate]
    ablated += [f"rollout10_err_{WITHOUT_RESIDUAL}"] if config.fit.residual else []
    for key in (*AVERAGED, *ablated):
        summary[key], summary[f"{key}_sd"] = _mean_sd([split[key] for split in splits])
    meta = transitions.meta
    return {
        **summary,
        "transitions": len(transitions),
        "paper_k": meta["paper_stiffness"],
        "horizon": config.horizon,
        "scene": config.scene,
        "objects": meta["objects"],
        "split": config.split,
        "data": str(config.data),
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
    config = parse_config(argv)
    check_outputs(config)
    record = run(config)
    write_json(config.results / "results.json", record)
    if config.json is not None:
        write_json(config.json, headline(record))
    print_table(record, config.fit.stiffness)
    print(f"wrote {config.results}/results.json, model.pt, history.csv")
    if config.ship:
        command = ["torchcontact", "learn-k", *(sys.argv[1:] if argv is None else argv)]
        path = ship_model(config.results / "model.pt", config.scene, record, command)
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
