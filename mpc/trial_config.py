"""A trial's configuration and identity: :class:`TrialConfig`, as a record holds it flat, the
:class:`TrialRecord` of its outcome, :func:`trial_configs` that makes checked configurations, and
:func:`trial_inputs`, the files and library versions a record's identity holds besides.

A record's identity is its :class:`TrialConfig` plus its ``inputs`` (:func:`trial_inputs`: the
SHA-256 of the object mesh, learned checkpoint and robot MJCF files it names, with every file their
loaders read besides, and the versions of torchcontact, torch and mujoco).
"""

from __future__ import annotations

import functools
import importlib.metadata
import importlib.util
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch

from torchcontact.digests import content_sha256
from torchcontact.environments import environment, import_environments
from torchcontact.environments.base import BENCHMARK_COLLISION, Environment
from torchcontact.environments.options import CostOptions
from torchcontact.environments.presets import PAPER, MPCSettings
from torchcontact.environments.robot_options import RobotOptions
from torchcontact.mpc.model_options import ModelOptions
from torchcontact.mpc.models import DEFAULT_MODEL, LEGACY_MODELS
from torchcontact.object_sources import mesh_file_of, object_source, record_stem
from torchcontact.objects import ObjectOptions
from torchcontact.shipped import SHIPPED, resolve_learned

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
    # a record written before a cost term existed ran without it
    **asdict(CostOptions.off()),
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

OBJECT_FACTS = ("object_extent", "object_mass_kg", "object_friction_mu", "object_collision")
"""Record fields describing the object a trial used (its bounding box [m], mass [kg], sliding
friction, collision shape); None in records written before them."""


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
    cost_options: CostOptions = CostOptions.off()
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


def record_key(prefix: str, name: str) -> str:
    """The record key of a part's field ``name`` under :data:`RECORD_PARTS`' ``prefix``."""
    return f"{prefix}_{name}" if prefix else name


def flat_config(config: TrialConfig) -> dict:
    """``config`` as a record holds it: its fields, each part's under its prefix."""
    flat = {}
    for f in fields(TrialConfig):
        value = getattr(config, f.name)
        if f.name in RECORD_PARTS:
            prefix = RECORD_PARTS[f.name][1]
            flat.update({record_key(prefix, k): v for k, v in asdict(value).items()})
        else:
            flat[f.name] = value
    return flat


def config_from_flat(flat: dict) -> TrialConfig:
    """The :class:`TrialConfig` of :func:`flat_config`'s ``flat``; ``ValueError`` from a part
    that refuses its values."""
    parts = {
        name: cls(**{f.name: flat[record_key(prefix, f.name)] for f in fields(cls)})
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
    """The cost terms of :func:`trial_configs`, resolved (:meth:`CostOptions.resolved`)."""
    given = options.get("cost_options") or CostOptions()
    return given.resolved(description, options.get("cost"))


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
