"""Closed-loop trials as an API: a typed configuration in, a typed record out.

``run_trials(configs, workers=2, out="results/trifinger")`` runs each :class:`TrialConfig` in
MuJoCo under the MPC it names, writes each finished :class:`TrialRecord` atomically to
``out/trials/NAME.json`` and reuses a record already there when it was made with the same
configuration and inputs (:mod:`torchcontact.mpc.records` says when), so an interrupted sweep
resumes where it stopped. A trial depends only on its configuration and inputs
(:mod:`torchcontact.mpc.trial_config`), so a parallel run's records equal a serial run's (timings
aside).

Per control step: detect contacts at the real state (MuJoCo), solve the MPC (torch), and
simulate the applied control (MuJoCo); the three times are recorded separately.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from torchcontact.environments import environment, import_environments, tasks
from torchcontact.environments.base import Environment
from torchcontact.model import ContactModel
from torchcontact.mpc.compile_notes import compile_notice, quiet_known_inductor_warnings
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.records import (
    FINITE_KEYS,
    RecordMismatch,
    describe_differences,
    record_status,
    set_aside,
)
from torchcontact.mpc.trial_config import (
    RECORD_PARTS,
    TrialConfig,
    TrialRecord,
    flat_config,
    library_versions,
    trial_configs,
    trial_inputs,
)
from torchcontact.objects import ObjectOptions
from torchcontact.parallel import check_backend, parallel_map
from torchcontact.results import locked_folder, writable_directory, write_json
from torchcontact.sim.plant import as_pose

# with the names of torchcontact.mpc.trial_config that users import from here (README.md)
__all__ = [
    "TrialConfig",
    "TrialRecord",
    "build_trial",
    "library_versions",
    "run_trial",
    "run_trials",
    "trial_configs",
    "trial_inputs",
    "TrialsInterrupted",
    "report_compiling",
    "warm_graphs",
    "object_facts",
    "start_penetration_mm",
    "trial_model",
]


class TrialsInterrupted(KeyboardInterrupt):
    """A run stopped by Ctrl-C; ``kept``: its trials whose records are saved, which a rerun
    into the same folder reuses."""

    def __init__(self, kept: int):
        super().__init__(f"interrupted; {kept} trials kept, rerun to resume")
        self.kept = kept


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
    if cost is None:
        cost = env.cost(plant, config.cost_options)
    else:
        config.cost_options.resolved(env, cost)  # refuses a term of the environment's cost
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
    initial, target, aim = _start(config, env, plant)
    mpc.reset()
    criterion = dataclasses.replace(env.criterion, max_steps=config.max_steps)
    tracker = tasks.SuccessTracker(target, criterion)
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
            _notice_compile(mpc, config.env)
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


def _start(config: TrialConfig, env: Environment, plant) -> tuple[np.ndarray, ...]:
    """Reset ``plant`` to ``config``'s trial: its initial and target poses (as the plant takes
    them, quaternions normalised: recorded and judged so) and the pose the MPC aims at."""
    initial, target = env.sample(plant, config.task, config.seed)
    initial, target = as_pose("initial", initial), as_pose("target", target)
    plant.reset(initial, target)
    return initial, target, env.aim(plant, target)


_NOTICED: set[int] = set()
"""The background compiles this process has told its user of, by process id."""


def _notice_compile(mpc: ContactImplicitMPC, env: str) -> None:
    """Say once per background compile that the MPC's graph compiles, while it plans eagerly."""
    pid = mpc.compile_pid
    if pid is not None and pid not in _NOTICED:
        _NOTICED.add(pid)
        tqdm.write(compile_notice(env, pid))


def start_penetration_mm(plant) -> float | None:
    """[mm] How deep the robot overlapped the object at the start of a hand's trial, after
    :meth:`~torchcontact.sim.hands.HandPlant.reset` moved the fingers out where the hand's
    ``clear_start`` says (a base link may stay inside a large object); None for a plant that
    does not measure it."""
    depth = getattr(plant, "start_penetration", None)
    return None if depth is None else 1e3 * float(depth)


def object_facts(plant) -> dict:
    """The :data:`~torchcontact.mpc.trial_config.OBJECT_FACTS` of ``plant``'s object."""
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


def warm_graphs(configs: Sequence[TrialConfig], progress: bool = True) -> list[str]:
    """Compile, in the foreground, the MPC graphs the trials of ``configs`` plan with (one
    per setup: an environment's objects mostly share one), each at its setup's first trial's
    start, into this machine's cache; graphs already there are loaded. Returns the names of
    the trials whose graph was compiled."""
    firsts, compiled = {}, []
    for config in configs:
        firsts.setdefault(_setup_key(config), config)
    for config in tqdm(firsts.values(), desc="graphs", disable=not progress):
        torch.set_num_threads(1)
        env, plant, mpc = build_trial(config)
        aim = torch.as_tensor(_start(config, env, plant)[2])
        state = torch.as_tensor(plant.state())
        if mpc.warm_up(state, plant.contacts(mpc.dtype), aim[:3], aim[3:]):
            compiled.append(config.name)
    return compiled


def report_compiling() -> None:
    """Say so where this process's background compile still runs: it goes on after the run
    (its own session), and the runs that start once it is done plan compiled throughout."""
    mpc = _CACHE.get("mpc")
    if mpc is not None and mpc.compiling:
        tqdm.write(
            f"the MPC's graph goes on compiling in a background process (pid "
            f"{mpc.compile_pid}, {mpc.compile_elapsed:.0f} s in so far; output in "
            f"{mpc.compile_log}): runs that start after it has finished plan compiled from "
            "their first step"
        )


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
