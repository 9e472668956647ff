"""Closed-loop trials as an API: a typed configuration in, a typed record out.

``run_trials(configs, workers=2, out="results/trifinger")`` runs each :class:`TrialConfig` in
MuJoCo under the MPC it names, writes each finished :class:`TrialRecord` atomically to
``out/trials/NAME.json`` and reuses a record already there when it was made with the same
configuration, so an interrupted sweep resumes where it stopped. A trial depends only on its
configuration, so a parallel run's records equal a serial run's (timings aside).

Per control step: detect contacts at the real state (MuJoCo), solve the MPC (torch), and
simulate the applied control (MuJoCo); the three times are recorded separately.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from torchcontact.environments import environment, tasks
from torchcontact.environments.base import BENCHMARK_COLLISION, Environment
from torchcontact.environments.presets import PAPER, MPCSettings
from torchcontact.model import ContactModel, RelaxedQP, contact_model
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.parallel import parallel_map
from torchcontact.relaxed_qp import PAPER_RELAXATION, paper_relaxation
from torchcontact.results import read_json, write_json
from torchcontact.sim.plant import as_pose

SCENES_VERSION = 7
"""Version of the plants, samplers and MPC models, stored with every trial record so that a
resumed sweep reruns trials from older versions (docs/journal.md lists what each changed)."""

DEFAULT_MODEL = "paper"
"""The contact model the MPC plans through unless told otherwise."""

MPC_MODELS = ("paper", "relaxed_qp")
"""Models a trial may name: the paper's complementarity-free model (constant K) and the QP
with relaxed complementarity (the paper's implicit-MPC baseline). A learned K(q), D(q) comes
with ``learned``."""

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
}
"""Values of configuration keys that records written before the key existed lack."""


LEGACY_MODELS = {"complementarity_free": "paper", "qp": "relaxed_qp"}
"""The models' names in records written before the MPC took ``contact_model`` names."""


@dataclass(frozen=True)
class TrialConfig:
    """What defines a trial's outcome (stored with its record, checked on resume).

    Attributes:
        env: the environment's registered name (``"custom"`` with ``robot``).
        task, object: the task and the object (a name or a mesh path); seed: the trial's.
        max_steps: control steps at most.
        max_iter, memory, horizon, dtype, compile, gaps: the solver settings
            (:class:`~torchcontact.environments.presets.MPCSettings`).
        stiffness: K of the paper's model (None with ``learned`` or the QP).
        model: one of :data:`MPC_MODELS`; relaxation: the paper's κ of the relaxed QP.
        learned: a checkpoint whose K(q), D(q) the MPC plans with.
        planner: the planner's registered name.
        scenes: :data:`SCENES_VERSION`; collision: how the object collides.
        robot, tips: a user robot's MJCF and fingertip sites (``env="custom"``).
        cost: a cost's registered name, None for the environment's.
    """

    env: str
    task: str
    object: str
    seed: int
    max_steps: int
    max_iter: int
    compile: bool
    dtype: str
    stiffness: float | None
    model: str = DEFAULT_MODEL
    relaxation: float | None = None
    learned: str | None = None
    memory: int = PAPER.memory
    horizon: int = PAPER.horizon
    scenes: int = SCENES_VERSION
    collision: str = BENCHMARK_COLLISION
    gaps: str = PAPER.gaps
    planner: str = "lbfgs"
    robot: str | None = None
    tips: tuple[str, ...] | None = None
    cost: str | None = None

    @property
    def settings(self) -> MPCSettings:
        """The solver settings of this trial."""
        names = [f.name for f in fields(MPCSettings)]
        return MPCSettings(**{name: getattr(self, name) for name in names})

    @property
    def variant(self) -> str:
        """The environment tagged with a non-default model: ``trifinger_relaxed_qp``."""
        if self.learned is not None:
            return f"{self.env}_learned"
        return self.env if self.model == DEFAULT_MODEL else f"{self.env}_{self.model}"

    @property
    def name(self) -> str:
        """File stem of the record: ``trifinger_in-hand_cube_seed3`` (a mesh path contributes
        its file stem)."""
        return f"{self.variant}_{self.task}_{Path(self.object).stem}_seed{self.seed}"

    def matches(self, record: dict) -> bool:
        """Whether the saved ``record`` was made with this configuration."""
        stored = {k: record.get(k, LEGACY_DEFAULTS.get(k)) for k in asdict(self)}
        stored["model"] = LEGACY_MODELS.get(stored["model"], stored["model"])
        if isinstance(stored["tips"], list):
            stored["tips"] = tuple(stored["tips"])
        return stored == asdict(self)


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

    def to_dict(self) -> dict:
        """The JSON-able record: the configuration's fields, then the outcome's."""
        outcome = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "config"}
        return {**asdict(self.config), **outcome}

    @classmethod
    def from_dict(cls, record: dict) -> TrialRecord:
        """The record of :meth:`to_dict` (its configuration completed by legacy defaults)."""
        names = [f.name for f in fields(TrialConfig)]
        config = {k: record.get(k, LEGACY_DEFAULTS.get(k)) for k in names}
        config["model"] = LEGACY_MODELS.get(config["model"], config["model"])
        if config["tips"] is not None:
            config["tips"] = tuple(config["tips"])
        outcome = {f.name: record[f.name] for f in fields(cls) if f.name != "config"}
        return cls(config=TrialConfig(**config), **outcome)


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
    ``max_steps`` (default its criterion's), the paper model at the environment's default K
    unless ``options`` (other :class:`TrialConfig` fields) say otherwise."""
    description = environment(env, options.get("robot"), options.get("tips"))
    settings = description.preset() if settings is None else settings
    if options.get("model") == "relaxed_qp":
        options.setdefault("relaxation", PAPER_RELAXATION)
    elif not options.get("learned"):
        options.setdefault("stiffness", description.default_stiffness)
    options.setdefault("stiffness", None)
    steps = description.criterion.max_steps if max_steps is None else max_steps
    return [
        TrialConfig(
            env=env,
            task=task,
            object=obj,
            seed=seed,
            max_steps=steps,
            **asdict(settings),
            **options,
        )
        for task, obj in pairs
        for seed in seeds
    ]


def trial_model(config: TrialConfig, h: float) -> ContactModel:
    """The contact model of ``config`` for a model step ``h`` [s]."""
    if config.learned is not None:
        from torchcontact.checkpoint import load_model

        return load_model(config.learned).requires_grad_(False)
    if config.model == "relaxed_qp":
        kappa = PAPER_RELAXATION if config.relaxation is None else config.relaxation
        return RelaxedQP(paper_relaxation(h, kappa), facets=4)
    if config.model == "paper":
        return contact_model("paper", stiffness=config.stiffness)
    raise ValueError(f"model must be one of {MPC_MODELS}, got {config.model!r}")


def build_trial(config: TrialConfig) -> tuple[Environment, object, ContactImplicitMPC]:
    """The environment, the plant and the MPC of ``config``."""
    env = environment(config.env, config.robot, config.tips)
    plant = env.make_plant(config.object, config.collision)
    model = trial_model(config, env.h(plant))
    mpc = ContactImplicitMPC.from_env(
        env, plant, model, config.planner, config.settings, config.cost
    )
    return env, plant, mpc


def run_trial(
    config: TrialConfig,
    env: Environment,
    plant,
    mpc: ContactImplicitMPC,
    frames: list | None = None,
    frame_every: int = 5,
) -> TrialRecord:
    """Run one trial to success or ``config.max_steps``; ``frames`` collects rendered RGB
    frames every ``frame_every`` steps when given."""
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
    iterations, found = [], []
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
        if frames is not None and step % frame_every == 0:
            frames.append(plant.render())
        if tracker.update(plant.state()[:7]):
            break
    final = plant.state()[:7]
    slots = plant.detector.slots
    return TrialRecord(
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
        **times,
    )


@dataclass(frozen=True)
class _Job:
    """One trial to run, with where its record and (optionally) its GIF go."""

    config: TrialConfig
    path: Path | None
    video: Path | None


_CACHE: dict = {}  # per process: the environment, plant and MPC of the last trial's setup


def _setup_key(config: TrialConfig) -> tuple:
    """What the plant and MPC of a trial depend on: everything but the task and the seed."""
    return tuple(v for k, v in asdict(config).items() if k not in ("task", "seed", "max_steps"))


def _run_job(job: _Job) -> TrialRecord:
    """Run ``job``, reusing this process's plant and MPC when they match (so a worker builds
    and compiles them once for all the trials it runs of one setup)."""
    torch.set_num_threads(1)
    key = _setup_key(job.config)
    if _CACHE.get("key") != key:
        _CACHE.clear()
        # A new object brings new tensor shapes: drop the previous compiled graphs, or dynamo
        # reaches its recompile limit after a few objects and silently runs eager from then on.
        torch._dynamo.reset()
        _CACHE.update(zip(("env", "plant", "mpc"), build_trial(job.config), strict=True), key=key)
    frames = [] if job.video is not None else None
    record = run_trial(job.config, _CACHE["env"], _CACHE["plant"], _CACHE["mpc"], frames)
    if frames:
        from torchcontact.mpc.report import save_gif

        save_gif(frames, job.video)
    return record


def finished_record(path: Path, config: TrialConfig) -> TrialRecord | None:
    """The saved record of ``config`` at ``path``, None if absent or made otherwise."""
    if not path.exists():
        return None
    record = read_json(path)
    return TrialRecord.from_dict(record) if config.matches(record) else None


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
    finishes and reused when it matches its configuration (None: nothing written or reused);
    ``videos``: the configs whose trial is also saved as ``out/NAME.gif`` (by the worker);
    ``on_record(record, reused)`` is called as each record becomes available. A trial whose
    Ray worker dies is run once more, with a warning.
    """
    folder = None if out is None else Path(out)
    records: dict[TrialConfig, TrialRecord] = {}
    jobs = []
    for config in configs:
        path = None if folder is None else folder / "trials" / f"{config.name}.json"
        record = None if path is None else finished_record(path, config)
        if record is not None:
            records[config] = record
            if on_record is not None:
                on_record(record, True)
            continue
        video = folder / f"{config.name}.gif" if folder and config in videos else None
        jobs.append(_Job(config, path, video))
    finished = parallel_map(_run_job, jobs, workers, backend, address, on_retry=_warn_retry(jobs))
    with tqdm(total=len(jobs), desc="trials", disable=not progress) as bar:
        for index, record in finished:
            if jobs[index].path is not None:
                write_json(jobs[index].path, record.to_dict())
            records[record.config] = record
            if on_record is not None:
                on_record(record, False)
            bar.update()
    return [records[config] for config in configs]


def _warn_retry(jobs: list[_Job]) -> Callable[[int, BaseException], None]:
    def warn(index: int, error: BaseException) -> None:
        name = jobs[index].config.name
        tqdm.write(f"trial {name}: its worker died ({type(error).__name__}); running it again")

    return warn
