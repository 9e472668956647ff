"""Closed-loop trials as an API: a typed configuration in, a typed record out.

``run_trials(configs, workers=2, out="results/trifinger")`` runs each :class:`TrialConfig` in
MuJoCo under the MPC it names, writes each finished :class:`TrialRecord` atomically to
``out/trials/NAME.json`` and reuses a record already there when it was made with the same
configuration and inputs, so an interrupted sweep resumes where it stopped. A trial depends only
on its configuration and inputs, so a parallel run's records equal a serial run's (timings
aside).

A record's identity is its :class:`TrialConfig` plus its ``inputs`` (:func:`trial_inputs`: the
SHA-256 of the object mesh, learned checkpoint and robot MJCF files it names, with every file their
loaders read besides, and the versions of torchcontact, torch and mujoco). On resume, a record at a
trial's path is reused when its identity equals the trial's; set aside (renamed
``NAME.corrupt-<n>.json``, with a warning) and run again when it is not a readable record; set
aside (``NAME.stale-<n>.json``) and run again when it differs only in :data:`RELEASE_FIELDS` (an
older release of our scenes or of a library); and any other difference refuses the whole run before
a trial runs (:class:`RecordMismatch`): a run never overwrites a record made with other settings or
inputs. A record without ``inputs`` (written before them) counts as made with the current inputs
when it names no file, and as one of an older release when it does.

Per control step: detect contacts at the real state (MuJoCo), solve the MPC (torch), and
simulate the applied control (MuJoCo); the three times are recorded separately.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import importlib.metadata
import importlib.util
import json
import math
import os
import re
import time
import typing
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from torchcontact.digests import content_sha256
from torchcontact.environments import environment, import_environments, tasks
from torchcontact.environments.base import BENCHMARK_COLLISION, Environment
from torchcontact.environments.options import CostOptions
from torchcontact.environments.presets import PAPER, MPCSettings
from torchcontact.environments.robot_options import RobotOptions
from torchcontact.model import ContactModel
from torchcontact.mpc.compile_notes import compile_notice, quiet_known_inductor_warnings
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.model_options import ModelOptions
from torchcontact.mpc.models import DEFAULT_MODEL, LEGACY_MODELS
from torchcontact.object_sources import mesh_file_of, object_source, record_stem
from torchcontact.objects import ObjectOptions
from torchcontact.parallel import check_backend, parallel_map
from torchcontact.results import (
    locked_folder,
    read_json,
    writable_directory,
    write_json,
)
from torchcontact.shipped import SHIPPED, resolve_learned
from torchcontact.sim.plant import as_pose

SCENES_VERSION = 11
"""Version of the plants, samplers and MPC models, stored with every trial record so that a
resumed sweep reruns trials from older versions (docs/experiments.md lists what each changed)."""

MAX_TRIALS = 1_000_000
"""The most trials one call of :func:`trial_configs` makes (``torchcontact run`` one run): more
would take months on any machine, and building their configurations alone takes minutes."""

LEGACY_DEFAULTS = {
    "model": "complementarity_free",
    "learned": None,
    "memory": PAPER.memory,
    "horizon": PAPER.horizon,
    "scenes": 1,
    "collision": "parts",
    "gaps": "frozen",
    "planner": "lbfgs",
    "robot": None,
    "tips": None,
    "cost": None,
    "object_size": None,
    "object_scale": None,
    "object_mass": None,
    "object_friction": None,
    "object_pose": "stable",
    "hold_first": 0,
    "hold_approach": 1.0,
    "residual_plan": "fixed",
    "env_module": None,
    **dict.fromkeys(
        ("initial_joints", "control_bound", "placement", "target_x", "target_y", "lift")
    ),
}
"""Values of configuration keys that records written before the key existed lack."""

REMOVED_OPTIONS = {
    "support": None,
    "support_margin": None,
    "contact_spread": None,
    "support_pass": False,
    "balance": 0.0,
    "hold_upright": 0.0,
    "pose_stage": 0.0,
    "pose_stage_radius": None,  # inf, which JSON writes as null
}
"""Configuration keys of options since removed (measured no better than the defaults,
docs/experiments.md), with the value that left them off: a record holding another value was
made by a removed option and matches no trial of this release."""


INPUT_FILES = {
    "object_sha256": "object",
    "learned_sha256": "learned",
    "robot_sha256": "robot",
    "env_module_sha256": "env_module",
}
"""Keys of a record's ``inputs`` holding the SHA-256 of the file a configuration field names
(None where it names none: a built-in object, no learned model, a built-in robot)."""

VERSION_KEYS = ("torchcontact", "torch", "mujoco")
"""Libraries whose versions a record's ``inputs`` holds."""

RESTING_RULE = "stable face from the centre of mass"
"""A record's ``inputs.object_rest`` for a mesh file turned onto its stable face
(:func:`~torchcontact.objects.mesh_rest`); records of meshes written before the rule lack it,
and their trials are rerun."""

RELEASE_FIELDS = (
    "scenes",
    "inputs",
    "inputs.object_rest",
    *(f"inputs.{key}" for key in VERSION_KEYS),
)
"""Identity fields that change with a release of ours or of a library, not with what the user
asked (``inputs``: a record written before inputs were recorded). A record
differing only in these is set aside and run again; any other difference refuses the run."""

FINITE_KEYS = (
    "pos_err_mm",
    "quat_err",
    "angle_err_deg",
    "initial_pose",
    "target_pose",
    "aim_pose",
    "final_pose",
)
"""Record values that must be finite: a record holding a non-finite one is never written and
counts as corrupt on reading."""


ERROR_KEYS = ("pos_err_mm", "quat_err", "angle_err_deg")
"""A record's final errors, which are never negative: a record holding one that is counts as
corrupt, as one with a NaN solve time or more steps than its ``max_steps`` does."""

OBJECT_FACTS = ("object_extent", "object_mass_kg", "object_friction_mu", "object_collision")
"""Record fields describing the object a trial used (its bounding box [m], mass [kg], sliding
friction, collision shape); None in records written before them."""


class RecordMismatch(ValueError):
    """A saved record at a trial's path was made with other settings or inputs than the run's."""


class TrialsInterrupted(KeyboardInterrupt):
    """A run stopped by Ctrl-C; ``kept``: its trials whose records are saved, which a rerun
    into the same folder reuses."""

    def __init__(self, kept: int):
        super().__init__(f"interrupted; {kept} trials kept, rerun to resume")
        self.kept = kept


@functools.cache
def library_versions() -> dict[str, str]:
    """The versions of :data:`VERSION_KEYS` in this process (``"unknown"`` for torchcontact
    when it is not installed as a distribution)."""
    import mujoco

    try:
        ours = importlib.metadata.version("torchcontact")
    except importlib.metadata.PackageNotFoundError:
        ours = "unknown"
    return {"torchcontact": ours, "torch": torch.__version__, "mujoco": mujoco.__version__}


@dataclass(frozen=True)
class TrialConfig:
    """What defines a trial's outcome (stored with its record, checked on resume).

    Attributes:
        env: the environment's registered name (``"custom"`` with ``robot``); env_module:
            the module (or ``.py`` file) that registers it, where it is not built in
            (:func:`~torchcontact.environments.import_environments`, imported by every
            process that runs the trial).
        task, object: the task and the object (a name or a mesh path); seed: the trial's.
        max_steps: control steps at most.
        settings: the solver settings.
        model_options: the contact model the MPC plans through, resolved for the environment
            (:meth:`~torchcontact.mpc.model_options.ModelOptions.resolved`).
        planner: the planner's registered name.
        scenes: :data:`SCENES_VERSION`; collision: how the object collides.
        robot, tips: a user robot's MJCF and fingertip sites (``env="custom"``);
            robot_options: what is set of its environment beyond its file.
        cost: a cost's registered name, None for the environment's; cost_options: the
            environment's cost terms (:func:`trial_configs` gives the environment's unless
            told; none with ``cost``).
        object_options: the user's settings of the object, its defaults for the scene's.

    A record holds these flat, each part's fields under :data:`RECORD_PARTS`' prefix
    (:func:`flat_config`), as records have always held them.
    """

    env: str
    task: str
    object: str
    seed: int
    max_steps: int
    settings: MPCSettings
    model_options: ModelOptions
    scenes: int = SCENES_VERSION
    collision: str = BENCHMARK_COLLISION
    planner: str = "lbfgs"
    robot: str | None = None
    tips: tuple[str, ...] | None = None
    robot_options: RobotOptions = RobotOptions()
    env_module: str | None = None
    cost: str | None = None
    cost_options: CostOptions = CostOptions(hold_first=0, hold_approach=1.0)
    object_options: ObjectOptions = ObjectOptions()

    @property
    def variant(self) -> str:
        """The environment tagged with a non-default model: ``trifinger_relaxed_qp``."""
        model = self.model_options
        if model.learned is not None and model.learned != SHIPPED:
            return f"{self.env}_learned"
        return self.env if model.model == DEFAULT_MODEL else f"{self.env}_{model.model}"

    @property
    def name(self) -> str:
        """File stem of the record: ``trifinger_in-hand_cube_seed3``; an object of a source
        contributes its :func:`~torchcontact.object_sources.record_stem` (a mesh path's
        ``cube-mesh-1a2b3c4d``)."""
        return f"{self.variant}_{self.task}_{record_stem(self.object)}_seed{self.seed}"

    def matches(self, record: dict) -> bool:
        """Whether the saved ``record`` was made with this configuration (inputs aside)."""
        removed = any(record.get(key, off) != off for key, off in REMOVED_OPTIONS.items())
        return not removed and stored_config(record) == flat_config(self)


RECORD_PARTS = {
    "settings": (MPCSettings, ""),
    "model_options": (ModelOptions, ""),
    "robot_options": (RobotOptions, ""),
    "cost_options": (CostOptions, ""),
    "object_options": (ObjectOptions, "object"),
}
"""The typed parts of a :class:`TrialConfig` and the prefix of their fields in a record (and
on the command line): ``object_options.size`` is ``object_size``, ``--object-size``."""


def _key(prefix: str, name: str) -> str:
    return f"{prefix}_{name}" if prefix else name


def flat_config(config: TrialConfig) -> dict:
    """``config`` as a record holds it: its fields, each part's under its prefix."""
    flat = {}
    for f in fields(TrialConfig):
        value = getattr(config, f.name)
        if f.name in RECORD_PARTS:
            prefix = RECORD_PARTS[f.name][1]
            flat.update({_key(prefix, k): v for k, v in asdict(value).items()})
        else:
            flat[f.name] = value
    return flat


def config_from_flat(flat: dict) -> TrialConfig:
    """The :class:`TrialConfig` of :func:`flat_config`'s ``flat``; ``ValueError`` from a part
    that refuses its values."""
    parts = {
        name: cls(**{f.name: flat[_key(prefix, f.name)] for f in fields(cls)})
        for name, (cls, prefix) in RECORD_PARTS.items()
    }
    rest = {f.name: flat[f.name] for f in fields(TrialConfig) if f.name not in RECORD_PARTS}
    return TrialConfig(**rest, **parts)


RECORD_KEYS = tuple(flat_config(TrialConfig("", "", "", 0, 1, PAPER, ModelOptions())))
"""The configuration keys of a record, in :func:`flat_config`'s order."""


def stored_config(record: dict) -> dict:
    """The configuration keys of a saved ``record`` (:data:`RECORD_KEYS`), completed by
    :data:`LEGACY_DEFAULTS` and :data:`LEGACY_MODELS`, its JSON lists as tuples."""
    stored = {key: record.get(key, LEGACY_DEFAULTS.get(key)) for key in RECORD_KEYS}
    if isinstance(stored["model"], str):
        stored["model"] = LEGACY_MODELS.get(stored["model"], stored["model"])
    return {k: tuple(v) if isinstance(v, list) else v for k, v in stored.items()}


@dataclass(frozen=True)
class TrialRecord:
    """The outcome of one trial (errors against the target; times per control step [ms])."""

    config: TrialConfig
    success: bool
    steps: int
    pos_err_mm: float
    quat_err: float
    angle_err_deg: float
    initial_pose: list[float]
    target_pose: list[float]
    aim_pose: list[float]
    final_pose: list[float]
    fell: bool
    detect_ms: list[float]
    solve_ms: list[float]
    sim_ms: list[float]
    iterations: list[int]
    contact_slots: int
    contacts_found_mean: float
    contacts_found_max: int
    steps_with_dropped_contacts: int
    object_extent: list[float] | None = None
    object_mass_kg: float | None = None
    object_friction_mu: float | None = None
    object_collision: str | None = None
    eager_steps: list[int] | None = None
    start_penetration_mm: float | None = None
    inputs: dict | None = None

    def to_dict(self) -> dict:
        """The JSON-able record: the configuration's fields, then the outcome's."""
        outcome = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "config"}
        return {**flat_config(self.config), **outcome}

    @classmethod
    def from_dict(cls, record: dict) -> TrialRecord:
        """The record of :meth:`to_dict` (its configuration completed by legacy defaults; no
        ``inputs`` in records written before them)."""
        names = [f.name for f in fields(cls) if f.name not in ("config", "inputs")]
        optional = (*OBJECT_FACTS, "eager_steps", "start_penetration_mm")
        outcome = {name: record[name] for name in names if name not in optional}
        outcome.update({name: record.get(name) for name in optional})
        config = config_from_flat(stored_config(record))
        return cls(config=config, inputs=record.get("inputs"), **outcome)


def trial_configs(
    env: str,
    pairs: Sequence[tuple[str, str]],
    seeds: Sequence[int],
    settings: MPCSettings | None = None,
    max_steps: int | None = None,
    **options,
) -> list[TrialConfig]:
    """Configurations of ``seeds`` on each (task, object) of ``pairs`` in environment ``env``
    (registered name): solver ``settings`` (default the environment's default preset),
    ``max_steps`` (default its criterion's), the environment's planner and its shipped model
    (or, where it ships none, the paper model at its default K) unless ``options`` (other
    :class:`TrialConfig` fields) say otherwise."""
    _check_parts(options)
    if options.get("env_module") is not None:
        import_environments(options["env_module"])
    robot = options.get("robot")
    description = environment(env, robot, options.get("tips"), options.get("robot_options"))
    settings = _settings(description, settings)
    pairs, seeds = (x if hasattr(x, "__len__") else list(x) for x in (pairs, seeds))
    _check_trial_arguments(description, pairs, seeds, max_steps, options)
    options["model_options"] = (options.get("model_options") or ModelOptions()).resolved(
        description
    )
    options.setdefault("planner", description.planner)
    options["cost_options"] = _cost_options(description, options)
    steps = description.criterion.max_steps if max_steps is None else max_steps
    return [
        TrialConfig(
            env=env,
            task=task,
            object=obj,
            seed=seed,
            max_steps=steps,
            settings=settings,
            **options,
        )
        for task, obj in pairs
        for seed in seeds
    ]


def _check_parts(options: dict) -> None:
    """``TypeError`` naming a typed part of :func:`trial_configs`' ``options`` of another
    type."""
    for name, (cls, _) in RECORD_PARTS.items():
        value = options.get(name)
        if name != "settings" and value is not None and not isinstance(value, cls):
            raise TypeError(f"{name} must be {cls.__name__}, got {type(value).__name__}")
    if "settings" in options:
        raise ValueError("settings is trial_configs' fourth argument, not one of its options")


def _cost_options(description: Environment, options: dict) -> CostOptions:
    """The cost terms of :func:`trial_configs`: those given, else the environment's (none with
    another cost)."""
    given = options.get("cost_options") or CostOptions()
    other_cost = options.get("cost") is not None
    hold = given.hold_first
    if hold is None:
        hold = 0 if other_cost else description.hold_first
    approach = given.hold_approach
    if approach is None:
        approach = description.hold_approach if hold and not other_cost else 1.0
    return CostOptions(hold_first=hold, hold_approach=approach)


def _settings(description: Environment, settings) -> MPCSettings:
    """``settings`` of :func:`trial_configs`: an :class:`MPCSettings`, a preset's name or None
    (the environment's default preset); ``ValueError`` naming the argument otherwise."""
    if settings is None or isinstance(settings, str):
        return description.preset(*([] if settings is None else [settings]))
    if not isinstance(settings, MPCSettings):
        raise ValueError(
            f"settings must be MPCSettings or a preset's name, got {type(settings).__name__}"
        )
    return settings


def _check_trial_arguments(description: Environment, pairs, seeds, max_steps, options) -> None:
    """Refuse what :func:`trial_configs` cannot make a trial of, before any trial runs, with a
    ``ValueError`` naming the argument and what was expected (as ``torchcontact run`` does)."""
    unknown = sorted(set(options) - {f.name for f in fields(TrialConfig)})
    if unknown:
        raise ValueError(f"options must be fields of TrialConfig, got {unknown[0]!r}")
    for name, values in (("pairs", pairs), ("seeds", seeds)):
        if len(values) == 0:
            raise ValueError(f"{name} must hold at least one entry, got none")
    for pair in pairs:
        if not (isinstance(pair, (tuple, list)) and len(pair) == 2):
            raise ValueError(f"pairs must hold (task, object) pairs, got {pair!r}")
        task, obj = pair
        if task not in description.tasks:
            raise ValueError(f"pairs: task must be one of {description.tasks}, got {task!r}")
        user = description.user_meshes and object_source(obj) is not None
        if not user and (task, obj) not in description.pairs:
            also = ", a mesh file or random-SEED" if description.user_meshes else ""
            raise ValueError(
                f"pairs: object of task {task!r} must be one of "
                f"{[o for t, o in description.pairs if t == task]}{also}, got {obj!r}"
            )
    if len(pairs) * len(seeds) > MAX_TRIALS:
        raise ValueError(
            f"pairs × seeds must make at most {MAX_TRIALS} trials, got {len(pairs)} × {len(seeds)}"
        )
    for seed in seeds:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seeds must be non-negative integers, got {seed!r}")
    if max_steps is not None and (
        isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1
    ):
        raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")


def trial_inputs(config: TrialConfig, hashes: dict[str, str] | None = None) -> dict:
    """The identity of ``config``'s inputs, stored as a record's ``inputs``: for each key of
    :data:`INPUT_FILES` the :func:`~torchcontact.digests.content_sha256` of the file its field
    names (its SHA-256, covering too the files its loader reads: an MJCF's includes and
    meshes, a glTF's buffers; None where none), and the versions of :data:`VERSION_KEYS`.
    ``hashes`` (resolved path → file digest) caches the digests across calls and is filled
    here. Raises ``ValueError`` naming the field when its file is
    missing."""
    hashes = {} if hashes is None else hashes
    inputs = {}
    for key, field in INPUT_FILES.items():
        if field == "learned":
            path = resolve_learned(config.model_options.learned, config.env)
        elif field == "object":
            path = mesh_file_of(config.object)
        else:
            path = getattr(config, field)
        if field == "env_module" and path is not None and not path.endswith(".py"):
            path = importlib.util.find_spec(path).origin  # imported already: it registered env
        if path is None:
            inputs[key] = None
            continue
        if not Path(path).is_file():
            raise ValueError(f"{field} must be an existing file, got {path!r} ({config.name})")
        inputs[key] = content_sha256(path, hashes)
    stable = mesh_file_of(config.object) is not None and config.object_options.pose == "stable"
    inputs["object_rest"] = RESTING_RULE if stable else None
    return {**inputs, **library_versions()}


def trial_model(config: TrialConfig, h: float) -> ContactModel:
    """The contact model of ``config`` for a model step ``h`` [s]."""
    return config.model_options.build(config.env, h, config.robot, config.tips)


def build_trial(config: TrialConfig) -> tuple[Environment, object, ContactImplicitMPC]:
    """The environment, the plant and the MPC of ``config``."""
    if config.env_module is not None:
        import_environments(config.env_module)
    env = environment(config.env, config.robot, config.tips, config.robot_options)
    plant = env.make_plant(config.object, config.collision, config.object_options)
    model = trial_model(config, env.h(plant))
    cost = config.cost
    terms = config.cost_options
    if cost is None:
        cost = env.cost(plant, terms)
    elif terms.hold_first or terms.hold_approach != 1:
        term = "hold_first" if terms.hold_first else "hold_approach"
        raise ValueError(f"{term} is a term of the environment's cost, not {cost!r}")
    mpc = ContactImplicitMPC.from_env(
        env,
        plant,
        model,
        config.planner,
        config.settings,
        cost,
        background_compile=True,
        residual_plan=config.model_options.residual_plan,
    )
    return env, plant, mpc


def run_trial(
    config: TrialConfig,
    env: Environment,
    plant,
    mpc: ContactImplicitMPC,
    frames: list | None = None,
    frame_every: int = 5,
    inputs: dict | None = None,
) -> TrialRecord:
    """Run one trial to success or ``config.max_steps``; ``frames`` collects rendered RGB
    frames every ``frame_every`` steps when given; ``inputs``: the record's (default
    :func:`trial_inputs` of ``config``). Raises ``ValueError`` naming the trial when a value of
    :data:`FINITE_KEYS` comes out non-finite (no record of it is made)."""
    inputs = trial_inputs(config) if inputs is None else inputs
    initial, target = env.sample(plant, config.task, config.seed)
    # the poses as the plant takes them (quaternions normalised), recorded and judged so
    initial, target = as_pose("initial", initial), as_pose("target", target)
    plant.reset(initial, target)
    mpc.reset()
    criterion = dataclasses.replace(env.criterion, max_steps=config.max_steps)
    tracker = tasks.SuccessTracker(target, criterion)
    aim = env.aim(plant, target)
    target_p, target_quat = torch.as_tensor(aim[:3]), torch.as_tensor(aim[3:])
    times = {"detect_ms": [], "solve_ms": [], "sim_ms": []}
    iterations, found, eager = [], [], []
    for step in range(criterion.max_steps):
        t0 = time.perf_counter()
        contacts = plant.contacts(mpc.dtype)
        found.append(plant.detector.found)
        t1 = time.perf_counter()
        plan = mpc.plan(torch.as_tensor(plant.state()), contacts, target_p, target_quat)
        t2 = time.perf_counter()
        plant.step(plan.control.numpy())
        t3 = time.perf_counter()
        for key, (a, b) in zip(times, ((t0, t1), (t1, t2), (t2, t3)), strict=True):
            times[key].append(1e3 * (b - a))
        iterations.append(plan.iterations)
        if mpc.compiled and not plan.compiled:
            eager.append(step)
        if frames is not None and step % frame_every == 0:
            frames.append(plant.render())
        if tracker.update(plant.state()[:7]):
            break
    final = plant.state()[:7]
    slots = plant.detector.slots
    record = TrialRecord(
        config=config,
        success=bool(tracker.succeeded),
        steps=step + 1,
        pos_err_mm=1e3 * float(tasks.position_error(final[:3], target[:3])),
        quat_err=float(tasks.quaternion_error(final[3:], target[3:])),
        angle_err_deg=float(tasks.angle_error(final[3:], target[3:])),
        initial_pose=initial.tolist(),
        target_pose=target.tolist(),
        aim_pose=aim.tolist(),
        final_pose=final.tolist(),
        fell=tasks.fell(initial, final),
        iterations=iterations,
        contact_slots=slots,
        contacts_found_mean=float(np.mean(found)),
        contacts_found_max=max(found),
        steps_with_dropped_contacts=sum(n > slots for n in found),
        **object_facts(plant),
        eager_steps=eager,
        start_penetration_mm=start_penetration_mm(plant),
        inputs=inputs,
        **times,
    )
    bad = [key for key in FINITE_KEYS if not np.all(np.isfinite(getattr(record, key)))]
    if bad:
        raise ValueError(
            f"trial {config.name} ended with non-finite {', '.join(bad)}; no record written"
        )
    return record


def start_penetration_mm(plant) -> float | None:
    """[mm] How deep the robot overlapped the object at the start of a hand's trial, after
    :meth:`~torchcontact.sim.hands.HandEnv.reset` moved the fingers out where the hand's
    ``clear_start`` says (a base link may stay inside a large object); None for a plant that
    does not measure it."""
    depth = getattr(plant, "start_penetration", None)
    return None if depth is None else 1e3 * float(depth)


def object_facts(plant) -> dict:
    """The :data:`OBJECT_FACTS` of ``plant``'s object."""
    obj = plant.object
    shape = "hull" if obj.collide_hull or len(obj.parts) == 1 else f"{len(obj.parts)} parts"
    return {
        "object_extent": [float(x) for x in obj.size],
        "object_mass_kg": float(obj.mass),
        "object_friction_mu": float(plant.object_friction),
        "object_collision": shape,
    }


@dataclass(frozen=True)
class _Job:
    """One trial to run, with where its record and (optionally) its GIF go."""

    config: TrialConfig
    path: Path | None
    video: Path | None
    inputs: dict


_CACHE: dict = {}  # per process: the environment, plant and MPC of the last trial's setup


def _setup_key(config: TrialConfig, objects: bool = True) -> tuple:
    """What the plant and MPC of a trial depend on: everything but the task and the seed
    (``objects`` False: and the object, which an environment's compiled graph is not
    specialised to)."""
    apart = {"task", "seed", "max_steps"}
    if not objects:
        prefix = RECORD_PARTS["object_options"][1]
        apart |= {"object", *(f"{prefix}_{f.name}" for f in fields(ObjectOptions))}
    return tuple(v for k, v in flat_config(config).items() if k not in apart)


def _run_job(job: _Job) -> TrialRecord:
    """Run ``job``, reusing this process's plant and MPC when they match (so a worker builds
    and compiles them once for all the trials it runs of one setup)."""
    torch.set_num_threads(1)
    key = _setup_key(job.config)
    if _CACHE.get("key") != key:
        if "mpc" in _CACHE:
            _CACHE["mpc"].wait_for_compile()  # its child must finish before the reset below
        graph = _setup_key(job.config, objects=False)
        if _CACHE.get("graph") != graph:
            # Other settings bring other graphs: drop the previous ones, or dynamo reaches its
            # recompile limit after a few and silently runs eager from then on. Another object
            # of the same settings runs the graph it has (contacts padded to the plant's
            # capacity, the cost's per-object terms as inputs): re-tracing it would take tens
            # of seconds per object.
            torch._dynamo.reset()
        _CACHE.clear()
        _CACHE.update(zip(("env", "plant", "mpc"), build_trial(job.config), strict=True), key=key)
        _CACHE["graph"] = graph
        if job.config.settings.compile:
            quiet_known_inductor_warnings()
    frames = [] if job.video is not None else None
    env, plant, mpc = _CACHE["env"], _CACHE["plant"], _CACHE["mpc"]
    record = run_trial(job.config, env, plant, mpc, frames, inputs=job.inputs)
    if frames:
        from torchcontact.mpc.report import save_gif

        save_gif(frames, job.video)
    return record


def _json_kind(hint) -> str:
    """The :func:`_is` kind of a field annotated ``hint`` (``X | None``: ``"X?"``)."""
    args = typing.get_args(hint)
    optional = type(None) in args and typing.get_origin(hint) is not tuple
    if optional:
        (hint,) = [a for a in args if a is not type(None)]
    if typing.get_origin(hint) is tuple:
        kind = {float: "numbers", int: "ints", str: "strs"}[typing.get_args(hint)[0]]
    else:
        kind = {float: "number", int: "int", str: "str", bool: "bool"}[hint]
    return kind + ("?" if optional else "")


def _config_kinds() -> dict[str, str]:
    """The kind of each of :data:`RECORD_KEYS`, from the annotations of the fields it holds."""
    kinds = {}
    for name, hint in typing.get_type_hints(TrialConfig).items():
        if name not in RECORD_PARTS:
            kinds[name] = _json_kind(hint)
            continue
        cls, prefix = RECORD_PARTS[name]
        for field in fields(cls):  # a field whose record holds a narrower kind says so
            kind = field.metadata.get("record_kind")
            kinds[_key(prefix, field.name)] = kind or _json_kind(
                typing.get_type_hints(cls)[field.name]
            )
    return kinds


_CONFIG_KINDS = _config_kinds()
_OUTCOME_KINDS = {
    **dict.fromkeys(("success", "fell"), "bool"),
    **dict.fromkeys(("steps", "contact_slots", "contacts_found_max"), "int"),
    "steps_with_dropped_contacts": "int",
    **dict.fromkeys(("pos_err_mm", "quat_err", "angle_err_deg", "contacts_found_mean"), "number"),
    **dict.fromkeys(("initial_pose", "target_pose", "aim_pose", "final_pose"), "pose"),
    **dict.fromkeys(("detect_ms", "solve_ms", "sim_ms"), "numbers"),
    "iterations": "ints",
    "eager_steps": "ints?",  # absent from records written before background compiles
    "start_penetration_mm": "number?",  # absent before scenes 10
}
_ITEM_KINDS = {"numbers": "number", "ints": "int", "strs": "str", "pose": "number"}


def _is(value, kind: str) -> bool:
    """Whether the JSON ``value`` is of ``kind`` (a key of the schemas above; ``?``: or None)."""
    if kind.endswith("?"):
        return value is None or _is(value, kind[:-1])
    if kind in _ITEM_KINDS:
        if not isinstance(value, (list, tuple)) or (kind == "pose" and len(value) != 7):
            return False
        return all(_is(item, _ITEM_KINDS[kind]) for item in value)
    if kind == "number":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, {"bool": bool, "str": str}[kind])


def record_problem(record) -> str | None:
    """Why a record read from JSON is not a usable trial record (wrong shape, a missing key, a
    wrong type, a non-finite value of :data:`FINITE_KEYS`, an impossible value: a negative
    error or time, more steps than ``max_steps``; malformed ``inputs``); None if it is
    usable."""
    if not isinstance(record, dict):
        return f"a JSON {type(record).__name__}, not an object"
    stored = stored_config(record)
    for key, kind in (*_CONFIG_KINDS.items(), *_OUTCOME_KINDS.items()):
        value = stored[key] if key in stored else record.get(key)
        if not _is(value, kind):
            found = "missing" if key not in record else f"{value!r:.40}"
            return f"{key} must be {kind.replace('?', ' or null')}, got {found}"
    for key in FINITE_KEYS:
        if not all(math.isfinite(x) for x in np.ravel(record[key])):
            return f"{key} is not finite"
    counts = ("contact_slots", "contacts_found_mean", "contacts_found_max")
    for key in (*ERROR_KEYS, "detect_ms", "solve_ms", "sim_ms", "iterations", *counts):
        if not all(math.isfinite(x) and x >= 0 for x in np.ravel(record[key])):
            return f"{key} must be finite and >= 0"
    if not 1 <= record["steps"] <= stored["max_steps"]:
        return f"steps must lie in [1, max_steps = {stored['max_steps']}], got {record['steps']}"
    try:
        config_from_flat(stored)
    except ValueError as error:  # a part that refuses its values: an edited record
        return f"its configuration is refused: {error}"
    inputs = record.get("inputs")
    if inputs is not None and not (
        isinstance(inputs, dict) and all(_is(v, "str?") for v in inputs.values())
    ):
        return f"inputs must be an object of strings or nulls, got {inputs!r:.60}"
    return None


def read_record(path: Path) -> tuple[dict | None, str | None]:
    """``(record, None)`` for a usable record at ``path`` (see :func:`record_problem`),
    ``(None, why)`` for a corrupt one."""
    try:
        record = read_json(path)
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        return None, f"not valid JSON: {error}"
    problem = record_problem(record)
    return (None, problem) if problem else (record, None)


def record_differences(record: dict, config: TrialConfig, inputs: dict) -> dict[str, tuple]:
    """Identity fields where the usable saved ``record`` differs from ``config`` and
    ``inputs``, as ``{field: (old, new)}`` (``inputs.KEY`` for an input; ``inputs`` when the
    record predates inputs)."""
    new = flat_config(config)
    stored = stored_config(record)
    differences = {key: (stored[key], new[key]) for key in new if stored[key] != new[key]}
    for key, off in REMOVED_OPTIONS.items():
        if record.get(key, off) != off:
            differences[key] = (record[key], "an option since removed")
    old = record.get("inputs")
    if old is None:  # written before inputs were recorded: no versions, no file hashes
        differences["inputs"] = ("not recorded", "versions and file hashes")
        return differences
    for key in dict.fromkeys([*old, *inputs]):
        if old.get(key) != inputs.get(key):
            differences[f"inputs.{key}"] = (old.get(key), inputs.get(key))
    return differences


def record_status(path: Path, config: TrialConfig, inputs: dict) -> tuple[str, object]:
    """What a run does with ``path`` for ``config`` with ``inputs``: ``("run", None)`` when
    absent, ``("reuse", record)``, ``("corrupt", why)``, ``("stale", differences)`` when it
    differs only in :data:`RELEASE_FIELDS`, ``("mismatch", differences)`` otherwise."""
    if not path.exists():
        return "run", None
    record, problem = read_record(path)
    if record is None:
        return "corrupt", problem
    differences = record_differences(record, config, inputs)
    if not differences:
        return "reuse", TrialRecord.from_dict(record)
    shipped = config.model_options.learned == SHIPPED  # the shipped model moves with releases
    release = RELEASE_FIELDS + (("inputs.learned_sha256",) if shipped else ())
    stale = all(key in release for key in differences)
    return ("stale" if stale else "mismatch"), differences


def finished_record(path: Path, config: TrialConfig, inputs: dict | None = None):
    """The saved :class:`TrialRecord` of ``config`` at ``path``; None if absent, corrupt or
    made with other settings or ``inputs`` (default :func:`trial_inputs` of ``config``)."""
    inputs = trial_inputs(config) if inputs is None else inputs
    status, found = record_status(Path(path), config, inputs)
    return found if status == "reuse" else None


SET_ASIDE_STEM = re.compile(r"\.[a-z]+-\d+$")
"""The end of the stem :func:`set_aside` gives a record (``NAME.corrupt-1``, ``NAME.stale-2``;
its labels are lowercase words); a mesh object's stem may hold other dots."""


def set_aside(path: Path, label: str) -> Path:
    """Rename ``path`` (``NAME.json``) to the first free ``NAME.LABEL-<n>.json`` (n ≥ 1,
    never overwriting a file, ``label`` matching :data:`SET_ASIDE_STEM`) and return the new
    path."""
    n = 1
    while (target := path.with_name(f"{path.stem}.{label}-{n}{path.suffix}")).exists():
        n += 1
    return path.rename(target)


def _shown(key: str, value) -> str:
    """A field's value in a message (a SHA-256 shortened to 12 hex digits)."""
    if isinstance(value, str) and key.endswith("sha256"):
        return f"{value[:12]}…"
    return repr(value)


def describe_differences(differences: dict[str, tuple]) -> str:
    """``"max_steps 5 → 6, inputs.object_sha256 '1a2b…' → '3c4d…'"``."""
    return ", ".join(
        f"{key} {_shown(key, old)} → {_shown(key, new)}" for key, (old, new) in differences.items()
    )


def _check_names(configs: Sequence[TrialConfig]) -> None:
    """Raise ``ValueError`` when two different configs would write the same record file."""
    seen: dict[str, TrialConfig] = {}
    for config in configs:
        other = seen.setdefault(config.name, config)
        if other != config:
            mine = flat_config(config)
            differences = {k: (v, mine[k]) for k, v in flat_config(other).items() if v != mine[k]}
            raise ValueError(
                f"configs: two trials would write the same record {config.name}.json but "
                f"differ in {describe_differences(differences)}; run them into separate out "
                "folders"
            )


def _plan(folder: Path | None, configs, inputs: dict) -> dict[TrialConfig, tuple]:
    """``{config: (path, status, found)}`` of :func:`record_status` for each distinct config;
    raises :class:`RecordMismatch` (naming the first such record, its differences and what to
    do) when a saved record was made with other settings or inputs. Reads only."""
    plan = {}
    for config in configs:
        path = None if folder is None else folder / "trials" / f"{config.name}.json"
        status = ("run", None) if path is None else record_status(path, config, inputs[config])
        plan[config] = (path, *status)
    mismatched = [(path, found) for path, status, found in plan.values() if status == "mismatch"]
    if mismatched:
        path, differences = mismatched[0]
        more = f" ({len(mismatched) - 1} more records differ too)" if len(mismatched) > 1 else ""
        raise RecordMismatch(
            f"{path} was made with other settings or inputs than this run: "
            f"{describe_differences(differences)}{more}. Nothing was run, nothing overwritten: "
            f"write to another folder (--out / out=) or move the records of {path.parent} "
            "away to rerun here."
        )
    return plan


def run_trials(
    configs: Sequence[TrialConfig],
    workers: int = 1,
    out: str | Path | None = None,
    videos: Sequence[TrialConfig] = (),
    progress: bool = True,
    on_record: Callable[[TrialRecord, bool], None] | None = None,
    backend: str = "local",
    address: str | None = None,
) -> list[TrialRecord]:
    """Run ``configs`` and return their records in order.

    ``workers``: local processes, or the CPUs of a local Ray instance; ``backend``, ``address``:
    where the trials run (:func:`~torchcontact.parallel.parallel_map`: ``"local"`` or
    ``"ray"``, a cluster's address or None for a local instance). ``out``: a folder whose
    ``trials/`` holds one JSON record per trial, written atomically here as each trial
    finishes and reused when its identity (config and :func:`trial_inputs`) matches; a corrupt
    record or one of an older release is set aside (renamed, with a warning) and its trial run
    again, and a record made with other settings or inputs raises :class:`RecordMismatch`
    before any trial runs (None: nothing written or reused); ``videos``: the configs whose trial
    is also saved as ``out/NAME.gif`` (by the worker); ``on_record(record, reused)`` is called
    as each record becomes available. A trial whose Ray worker dies is run once more, with a
    warning. The files' SHA-256 are computed once per distinct file per call.

    Before any trial, ``out`` must be a writable folder (``ValueError`` otherwise), and the
    run holds it (:func:`~torchcontact.results.locked_folder`): a run into a folder another
    process holds raises :class:`~torchcontact.results.FolderInUse`. Ctrl-C raises
    :class:`TrialsInterrupted`, counting the trials whose records are kept.
    """
    _check_run_arguments(configs, out, progress, on_record)
    check_backend(workers, backend, address)
    folder = None if out is None else Path(out)
    distinct = list(dict.fromkeys(configs))
    for config in distinct:
        if not isinstance(config, TrialConfig):
            raise ValueError(f"configs must be TrialConfig, got {type(config).__name__}")
        steps = config.max_steps
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ValueError(f"max_steps must be a positive integer, got {config.max_steps!r}")
    if folder is not None:
        _check_names(distinct)
        writable_directory("out", folder / "trials")
    hashes: dict[str, str] = {}
    inputs = {config: trial_inputs(config, hashes) for config in distinct}
    where = {"workers": workers, "backend": backend, "address": address}
    with contextlib.nullcontext() if folder is None else locked_folder(folder, "out"):
        plan = _plan(folder, distinct, inputs)
        records = _run_planned(plan, inputs, folder, videos, progress, on_record, where)
    return [records[config] for config in configs]


def _check_run_arguments(configs, out, progress, on_record) -> None:
    """``TypeError`` naming the argument of :func:`run_trials` of the wrong kind."""
    if isinstance(configs, TrialConfig) or not isinstance(configs, Sequence):
        raise TypeError(
            f"configs must be a sequence of TrialConfig (a list), got {type(configs).__name__}"
        )
    if out is not None and not isinstance(out, (str, os.PathLike)):
        raise TypeError(f"out must be a folder path or None, got {type(out).__name__}")
    if not isinstance(progress, bool):
        raise TypeError(f"progress must be True or False, got {progress!r}")
    if on_record is not None and not callable(on_record):
        raise TypeError(f"on_record must be callable or None, got {type(on_record).__name__}")


def _run_planned(plan: dict, inputs: dict, folder, videos, progress, on_record, where: dict):
    """The records of :func:`run_trials`'s ``plan`` (of :func:`_plan`), by config: reused, or
    run (``where``: :func:`_run_jobs`'s arguments) after setting the corrupt and stale records
    aside; :class:`TrialsInterrupted` on Ctrl-C, counting the records saved."""
    records: dict[TrialConfig, TrialRecord] = {}
    jobs = []
    try:
        for config, (path, status, found) in plan.items():
            if status == "reuse":
                records[config] = found
                if on_record is not None:
                    on_record(found, True)
                continue
            if status in ("corrupt", "stale"):
                _set_aside_with_warning(path, status, found)
            video = folder / f"{config.name}.gif" if folder and config in videos else None
            jobs.append(_Job(config, path, video, inputs[config]))
        with tqdm(total=len(jobs), desc="trials", disable=not progress) as bar:
            for index, record, written in _run_jobs(jobs, **where):
                if jobs[index].path is not None and not written:
                    write_json(jobs[index].path, record.to_dict())
                records[record.config] = record
                if on_record is not None:
                    on_record(record, False)
                bar.update()
    except KeyboardInterrupt:
        kept = sum(path is not None and path.exists() for path, _, _ in plan.values())
        raise TrialsInterrupted(kept) from None
    return records


BATCH = 4
"""Trials of one setup (object and settings) a local worker runs in a row, so that it builds
and compiles (or loads) their MPC once instead of every worker doing so for every object."""


def _run_jobs(jobs: list[_Job], workers: int, backend: str, address: str | None):
    """``(index, record, written)`` of each of ``jobs`` as it finishes; ``written``: whether its
    worker already wrote the record to the job's path.

    With several local workers, each takes up to :data:`BATCH` trials of one setup at a time
    (writing each record as it finishes), and with a compiled MPC the first trial runs alone
    first: it compiles the MPC's graph into the machine's on-disk cache, which the workers then
    load instead of each compiling it anew. On Ray every trial is its own task."""
    compiled = [job.config for job in jobs if job.config.settings.compile]
    if compiled:
        tqdm.write(compile_notice(compiled[0].env))
    if workers == 1 or backend != "local" or len(jobs) <= 1:
        finished = parallel_map(_run_job, jobs, workers, backend, address, _warn_retry(jobs))
        for index, record in finished:
            yield index, record, False
        return
    first = 0
    if jobs[0].config.settings.compile:
        record = _run_job(jobs[0])
        _CACHE["mpc"].wait_for_compile()  # the graph in the cache before the workers start
        yield 0, record, False
        first = 1
    batches = _batches(range(first, len(jobs)), jobs)
    finished = parallel_map(_run_batch, [[jobs[i] for i in b] for b in batches], workers)
    for index, records in finished:
        for job_index, record in zip(batches[index], records, strict=True):
            yield job_index, record, True


def finish_compiling() -> None:
    """Wait, saying so, for this process's background compile, if one runs: its graph is then
    cached for the next run (the process would wait for it at exit anyway, silently)."""
    mpc = _CACHE.get("mpc")
    if mpc is not None and mpc.compiling:
        tqdm.write(
            f"the trials are done and kept; finishing the MPC's compile for the next runs "
            f"({mpc.compile_elapsed:.0f} s in so far; Ctrl-C skips it, the next run then "
            "compiles again)"
        )
        try:
            mpc.wait_for_compile()
        except KeyboardInterrupt:
            raise KeyboardInterrupt("compile skipped; the trials' records are kept") from None


def _batches(indices, jobs: list[_Job]) -> list[list[int]]:
    """``indices`` of ``jobs`` in runs of at most :data:`BATCH` consecutive ones of one setup."""
    batches: list[list[int]] = []
    for i in indices:
        last = batches[-1] if batches else None
        same = last and _setup_key(jobs[last[-1]].config) == _setup_key(jobs[i].config)
        if same and len(last) < BATCH:
            last.append(i)
        else:
            batches.append([i])
    return batches


def _run_batch(batch: list[_Job]) -> list[TrialRecord]:
    """Run ``batch`` in a row, each record written as its trial finishes."""
    records = []
    for job in batch:
        record = _run_job(job)
        if job.path is not None:
            write_json(job.path, record.to_dict())
        records.append(record)
    return records


def _set_aside_with_warning(path: Path, status: str, found) -> None:
    """Set the ``corrupt`` or ``stale`` record at ``path`` aside, saying so on one line."""
    why = found if status == "corrupt" else f"an older release: {describe_differences(found)}"
    target = set_aside(path, status)
    tqdm.write(
        f"warning: trial record {path} is {status} ({why}); kept as {target.name}, "
        "running its trial again"
    )


def _warn_retry(jobs: list[_Job]) -> Callable[[int, BaseException], None]:
    def warn(index: int, error: BaseException) -> None:
        name = jobs[index].config.name
        tqdm.write(f"trial {name}: its worker died ({type(error).__name__}); running it again")

    return warn
