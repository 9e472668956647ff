"""Closed-loop evaluation: run MPC trials in MuJoCo, summarize, plot, record.

``torchcontact run fingertips --task in-air --object cube --trials 20`` (or ``run trifinger``,
``run allegro``) runs trial seeds 0…19 of each selected (task, object) pair, writes one JSON
per finished trial (atomically, so an interrupted sweep resumes where it stopped), then a
summary (JSON + CSV), the paper-style figure and, on request, a GIF. ``--workers N`` runs
trials in N processes; a trial depends only on its configuration, so the records are the
same as a serial run's (timings aside).

``--model qp`` plans through the complementarity-based baseline instead, the Anitescu QP with
complementarity relaxed to κ (``--relaxation``, the paper's 5e-4 in its code's scaling
λ∘g = κ, see :func:`torchcontact.relaxed_qp.paper_relaxation`) and differentiated through
its KKT conditions: the paper's "implicit MPC". Its results go to ``results/ENV_qp`` and its
trial records are named ``ENV_qp_...``, so the two models never share a record.

Per control step: detect contacts at the real state (MuJoCo), solve the MPC (torch), and
simulate the applied control (MuJoCo); the three times are recorded separately.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import multiprocessing
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from torchcontact.environments import tasks
from torchcontact.environments.presets import (
    DEFAULT_PRESET,
    GAPS,
    NAMES,
    PAPER,
    MPCSettings,
    preset,
)
from torchcontact.mpc.controller import MPC_MODELS
from torchcontact.mpc.suites import BENCHMARK_COLLISION, SCENES_VERSION, SUITES
from torchcontact.relaxed_qp import PAPER_RELAXATION
from torchcontact.results import atomic_write, read_json, save_figure, write_csv, write_json
from torchcontact.sim.objects import COLLISIONS

SUMMARY_KEYS = (
    "success_rate",
    "pos_err_mm_mean",
    "angle_err_deg_mean",
    "solve_ms_median",
    "solve_ms_p90",
    "trials",
)


DEFAULT_MODEL = "complementarity_free"

LEGACY_DEFAULTS = {
    "model": DEFAULT_MODEL,
    "learned": None,
    "memory": PAPER.memory,
    "horizon": PAPER.horizon,
    "scenes": 1,
    "collision": "parts",
    "gaps": "frozen",
}
"""Values of configuration keys that records written before the key existed lack."""


def variant_name(env: str, model: str, learned: str | None) -> str:
    """The environment tagged with a non-default contact model: ``trifinger_qp``."""
    if learned is not None:
        return f"{env}_learned"
    return env if model == DEFAULT_MODEL else f"{env}_{model}"


def trial_name(variant: str, task: str, obj: str, seed: int) -> str:
    """File stem of a trial record: ``trifinger_in-hand_cube_seed3`` (a mesh path contributes
    its file stem; ``variant`` from :func:`variant_name`)."""
    return f"{variant}_{task}_{Path(obj).stem}_seed{seed}"


@dataclass(frozen=True)
class TrialConfig:
    """What defines a trial's outcome (stored with it, checked on resume)."""

    env: str
    task: str
    object: str
    seed: int
    max_steps: int
    max_iter: int
    compile: bool
    dtype: str
    stiffness: float | None  # K of the complementarity-free model; None for the QP
    model: str = DEFAULT_MODEL
    relaxation: float | None = None  # κ of the QP; None for the complementarity-free model
    learned: str | None = None  # a learn-k checkpoint whose K(q), D(q) the MPC plans with
    memory: int = PAPER.memory  # L-BFGS memory
    horizon: int = PAPER.horizon  # T
    scenes: int = SCENES_VERSION  # plants and samplers, see SCENES_VERSION
    collision: str = BENCHMARK_COLLISION  # how the object collides, see make_object
    gaps: str = PAPER.gaps  # contact distances over the horizon, see controller.GAPS

    @property
    def name(self) -> str:
        """File stem of the trial's record, see :func:`trial_name`."""
        variant = variant_name(self.env, self.model, self.learned)
        return trial_name(variant, self.task, self.object, self.seed)


def run_trial(
    config: TrialConfig, env, mpc, frames: list | None = None, frame_every: int = 5
) -> dict:
    """Run one trial to success or ``max_steps``; returns its record (a JSON-able dict)."""
    suite = SUITES[config.env]
    initial, target = suite.sample(env, config.task, config.object, config.seed)
    env.reset(initial, target)
    mpc.reset()
    criterion = dataclasses.replace(suite.criterion, max_steps=config.max_steps)
    tracker = tasks.SuccessTracker(target, criterion)
    aim = suite.aim(env, target)
    target_p = torch.as_tensor(aim[:3])
    target_quat = torch.as_tensor(aim[3:])
    detect_ms, solve_ms, sim_ms, iterations, found = [], [], [], [], []
    for step in range(criterion.max_steps):
        t0 = time.perf_counter()
        contacts = env.contacts(mpc.dtype)
        found.append(env.detector.found)
        t1 = time.perf_counter()
        plan = mpc.plan(torch.as_tensor(env.state()), contacts, target_p, target_quat)
        t2 = time.perf_counter()
        env.step(plan.control.numpy())
        t3 = time.perf_counter()
        detect_ms.append(1e3 * (t1 - t0))
        solve_ms.append(1e3 * (t2 - t1))
        sim_ms.append(1e3 * (t3 - t2))
        iterations.append(plan.iterations)
        if frames is not None and step % frame_every == 0:
            frames.append(env.render())
        tracker.update(env.state()[:7])
        if tracker.done:
            break
    final = env.state()[:7]
    return {
        **config.__dict__,
        "success": bool(tracker.succeeded),
        "steps": step + 1,
        "pos_err_mm": 1e3 * float(tasks.position_error(final[:3], target[:3])),
        "quat_err": float(tasks.quaternion_error(final[3:], target[3:])),
        "angle_err_deg": float(tasks.angle_error(final[3:], target[3:])),
        "initial_pose": initial.tolist(),
        "target_pose": target.tolist(),
        "aim_pose": aim.tolist(),
        "final_pose": final.tolist(),
        "fell": tasks.fell(initial, final),
        "detect_ms": detect_ms,
        "solve_ms": solve_ms,
        "sim_ms": sim_ms,
        "iterations": iterations,
        "contact_slots": env.detector.slots,
        "contacts_found_mean": float(np.mean(found)),
        "contacts_found_max": max(found),
        "steps_with_dropped_contacts": sum(n > env.detector.slots for n in found),
    }


def summarize(records: list[dict]) -> dict:
    """Success rate, mean final errors and MPC time statistics over trial records."""
    if not records:
        raise ValueError("records must hold at least one trial")
    solve = np.concatenate([r["solve_ms"] for r in records])
    success = [r for r in records if r["success"]]

    def mean_of(key, rows):
        return float(np.mean([r[key] for r in rows])) if rows else float("nan")

    fallen = [_fell(r) for r in records]

    return {
        "success_rate": len(success) / len(records),
        "pos_err_mm_mean": mean_of("pos_err_mm", records),
        "angle_err_deg_mean": mean_of("angle_err_deg", records),
        "quat_err_mean": mean_of("quat_err", records),
        "pos_err_mm_mean_success": mean_of("pos_err_mm", success),
        "angle_err_deg_mean_success": mean_of("angle_err_deg", success),
        "solve_ms_median": float(np.median(solve)),
        "solve_ms_p90": float(np.percentile(solve, 90)),
        "detect_ms_median": float(np.median(np.concatenate([r["detect_ms"] for r in records]))),
        "sim_ms_median": float(np.median(np.concatenate([r["sim_ms"] for r in records]))),
        "iterations_median": float(np.median(np.concatenate([r["iterations"] for r in records]))),
        "steps_median": float(np.median([r["steps"] for r in records])),
        "trials": len(records),
        # trials whose object left its support (see tasks.fell); None where a record cannot tell
        "falls": None if None in fallen else sum(fallen),
    }


def _fell(record: dict) -> bool | None:
    """A record's ``fell``; for records written before the key, from their poses (None
    when they have none)."""
    if "fell" in record:
        return record["fell"]
    if "initial_pose" in record and "final_pose" in record:
        return tasks.fell(record["initial_pose"], record["final_pose"])
    return None


def plot_results(records: list[dict], path: Path) -> Path:
    """The paper's figure: success per (task, object) and final errors, failures in grey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = sorted({(r["task"], r["object"]) for r in records})
    labels = [f"{task}\n{Path(obj).stem}" for task, obj in groups]
    figure, axes = plt.subplots(1, 3, figsize=(4 + 1.6 * len(groups), 3.6))
    rows = [[r for r in records if (r["task"], r["object"]) == g] for g in groups]
    rates = [100 * np.mean([r["success"] for r in rs]) for rs in rows]
    axes[0].bar(range(len(groups)), rates, color="tab:blue")
    axes[0].set_ylabel("success [%]")
    axes[0].set_ylim(0, 105)
    for axis, key, unit in ((axes[1], "pos_err_mm", "mm"), (axes[2], "angle_err_deg", "deg")):
        ok = [[r[key] for r in rs if r["success"]] for rs in rows]
        if any(ok):
            positions = [i for i, values in enumerate(ok) if values]
            axis.violinplot([ok[i] for i in positions], positions=positions, showmedians=True)
        for i, rs in enumerate(rows):
            failed = [r[key] for r in rs if not r["success"]]
            axis.scatter([i] * len(failed), failed, color="grey", s=12, zorder=3)
        axis.set_ylabel(f"final {key.split('_err')[0]} error [{unit}]")
    for axis in axes:
        axis.set_xticks(range(len(groups)), labels, fontsize=8)
    figure.tight_layout()
    path = save_figure(figure, path)
    plt.close(figure)
    return path


def save_gif(frames: list[np.ndarray], path: Path, fps: int = 10) -> Path:
    """Write RGB frames ``(H, W, 3) uint8`` as an animated GIF."""
    from PIL import Image

    images = [Image.fromarray(frame) for frame in frames]
    return atomic_write(
        path,
        lambda f: images[0].save(
            f, format="GIF", save_all=True, append_images=images[1:], duration=1000 // fps, loop=0
        ),
        binary=True,
    )


def _table_row(record: dict) -> str:
    return (
        f"{record['task']:>9s} {Path(record['object']).stem[:11]:>11s} {record['seed']:>4d} "
        f"{'yes' if record['success'] else 'no':>7s} {record['steps']:>5d} "
        f"{record['pos_err_mm']:>8.1f} {record['quat_err']:>8.4f} {record['angle_err_deg']:>7.1f} "
        f"{np.median(record['solve_ms']):>8.1f}"
    )


TABLE_HEADER = (
    f"{'task':>9s} {'object':>11s} {'seed':>4s} {'success':>7s} {'steps':>5s} "
    f"{'pos [mm]':>8s} {'quat err':>8s} {'ang [°]':>7s} {'solve ms':>8s}"
)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="torchcontact run", description="Closed-loop MPC trials in MuJoCo."
    )
    parser.add_argument("env", choices=sorted(SUITES), help="the environment")
    parser.add_argument("--task", default="all", help="a task of the environment or 'all'")
    parser.add_argument(
        "--object", default="cube", help="an object name, 'all', or (hands) a mesh file"
    )
    parser.add_argument("--trials", type=int, default=tasks.TRIALS, help="seeds 0…trials−1")
    parser.add_argument("--max-steps", type=int, default=None, help="default: the task's")
    parser.add_argument(
        "--preset",
        choices=NAMES,
        default=DEFAULT_PRESET,
        help="the environment's solver settings from the measured speed-accuracy front "
        "(README 'Choosing settings'); the options below override single values",
    )
    parser.add_argument("--max-iter", type=int, default=None, help="L-BFGS iterations per step")
    parser.add_argument("--memory", type=int, default=None, help="L-BFGS memory")
    parser.add_argument("--horizon", type=int, default=None, help="T, MPC steps planned ahead")
    parser.add_argument(
        "--gaps",
        choices=GAPS,
        default=None,
        help="contact distances over the horizon: frozen (the paper's Algorithm 1) or "
        "propagated along the frozen normal rows (complementarity_free only); default the "
        "preset's, frozen for qp",
    )
    parser.add_argument(
        "--model",
        choices=MPC_MODELS,
        default=DEFAULT_MODEL,
        help="contact model the MPC plans through: complementarity_free (default) or qp, the "
        "Anitescu QP with relaxed complementarity differentiated through its KKT conditions "
        "(the paper's implicit-MPC baseline; results in results/ENV_qp)",
    )
    parser.add_argument(
        "--stiffness",
        type=float,
        default=None,
        help="K (complementarity_free); default the paper's, except the fingertips' 4.64 "
        "(learn-k's best constant K on the cube)",
    )
    parser.add_argument(
        "--relaxation",
        type=float,
        default=None,
        help=f"the paper's κ in λ∘g = κ (qp); default {PAPER_RELAXATION:g}",
    )
    parser.add_argument(
        "--learned",
        type=Path,
        default=None,
        help="a `torchcontact learn-k` checkpoint (model.pt): plan with its learned K(q), D(q) "
        "(complementarity_free; results in results/ENV_learned)",
    )
    parser.add_argument(
        "--collision",
        choices=COLLISIONS,
        default=BENCHMARK_COLLISION,
        help="how the object collides: hull (default: its convex hull, as the paper's objects "
        "do), auto (the hull, but part by part for the bowl, cup, mug and torus, whose hole or "
        "cavity a fingertip reaches) or parts (every object part by part)",
    )
    parser.add_argument("--no-compile", action="store_true", help="eager objective")
    parser.add_argument("--dtype", choices=["float32", "float64"], default=None)
    parser.add_argument("--workers", type=int, default=1, help="parallel trial processes")
    parser.add_argument(
        "--out", type=Path, default=None, help="default results/ENV (results/ENV_qp for qp)"
    )
    parser.add_argument("--json", type=Path, default=None, help="write the summary here too")
    parser.add_argument("--video", action="store_true", help="record trial 0 of each pair")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    qp = args.model == "qp"
    if args.stiffness is not None and (qp or not args.stiffness > 0):
        parser.error(
            f"--stiffness must be positive and is for complementarity_free, got {args.stiffness}"
        )
    if args.relaxation is not None and (not qp or not 0 < args.relaxation < math.inf):
        parser.error(f"--relaxation must be positive and is for qp, got {args.relaxation}")
    if args.learned is not None and (qp or args.stiffness is not None):
        parser.error(
            "--learned replaces the constant K of complementarity_free: drop --model qp "
            "and --stiffness"
        )
    if qp and args.gaps == "propagated":
        parser.error("--gaps propagated is for complementarity_free; the qp plans with frozen gaps")
    if args.learned is not None and not args.learned.is_file():
        parser.error(f"--learned must be an existing checkpoint file, got {str(args.learned)!r}")
    for name in ("trials", "workers", "max_iter", "memory", "horizon"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    overrides = {
        "max_iter": args.max_iter,
        "memory": args.memory,
        "horizon": args.horizon,
        "gaps": "frozen" if qp and args.gaps is None else args.gaps,
        "dtype": args.dtype,
        "compile": False if args.no_compile else None,
    }
    args.settings = dataclasses.replace(
        preset(args.env, args.preset), **{k: v for k, v in overrides.items() if v is not None}
    )
    if args.max_steps is not None and args.max_steps < 1:
        parser.error(f"--max-steps must be >= 1, got {args.max_steps}")
    suite = SUITES[args.env]
    try:
        args.pairs = suite.select(args.task, args.object)
    except ValueError as error:
        parser.error(str(error))
    if qp:
        args.relaxation = PAPER_RELAXATION if args.relaxation is None else args.relaxation
    elif args.learned is not None:
        args.learned = str(args.learned.resolve())
    else:
        args.stiffness = suite.default_stiffness if args.stiffness is None else args.stiffness
    variant = variant_name(args.env, args.model, args.learned)
    args.out = Path("results") / variant if args.out is None else args.out
    return args


@dataclass(frozen=True)
class Job:
    """One trial to run, with where its record goes and whether to record frames."""

    config: TrialConfig
    path: Path
    video: Path | None


_CACHE: dict = {}  # per process: the plant and MPC of the last (env, object, options)


def _run_job(job: Job) -> dict:
    """Run ``job`` (reusing this process's plant and MPC when they match) and save it."""
    torch.set_num_threads(1)
    c = job.config
    key = (c.env, c.object, c.max_iter, c.compile, c.dtype, c.stiffness, c.model, c.relaxation)
    key += (c.learned, c.memory, c.horizon, c.collision, c.gaps)
    if _CACHE.get("key") != key:
        suite = SUITES[c.env]
        _CACHE.clear()
        # A new object brings new tensor shapes: drop the previous compiled graphs, or dynamo
        # reaches its recompile limit after a few objects and silently runs eager from then on.
        torch._dynamo.reset()
        env = suite.make_env(c.object, c.collision)
        _CACHE.update(
            key=key,
            env=env,
            mpc=suite.make_mpc(
                c.object,
                suite.stiffness if c.learned is not None else c.stiffness,  # then replaced
                plant=env,
                model=c.model,
                relaxation=c.relaxation,
                max_iter=c.max_iter,
                memory=c.memory,
                horizon=c.horizon,
                gaps=c.gaps,
                compile=c.compile,
                dtype=getattr(torch, c.dtype),
            ),
        )
        if c.learned is not None:
            _CACHE["mpc"].model = learned_model(c.learned, getattr(torch, c.dtype))
    frames = [] if job.video is not None else None
    record = run_trial(c, _CACHE["env"], _CACHE["mpc"], frames)
    write_json(job.path, record)
    if frames:
        save_gif(frames, job.video)
    return record


def learned_model(path: str | Path, dtype: torch.dtype):
    """The complementarity-free model of a ``learn-k`` checkpoint, frozen, in ``dtype``."""
    from torchcontact.learn.fit import load_checkpoint  # learn builds on mpc: import on use

    model, _, _ = load_checkpoint(path)
    return model.to(dtype).requires_grad_(False)


def _finished(path: Path, config: TrialConfig) -> dict | None:
    """The saved record of ``config`` at ``path``, None if absent or run with other settings."""
    if not path.exists():
        return None
    record = read_json(path)
    same = all(record.get(k, LEGACY_DEFAULTS.get(k)) == v for k, v in config.__dict__.items())
    return record if same else None


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    torch.set_num_threads(1)
    args = parse_args(argv)
    suite = SUITES[args.env]
    settings: MPCSettings = args.settings
    trials_dir = args.out / "trials"
    done: dict[TrialConfig, dict] = {}
    jobs: list[Job] = []
    for task, obj in args.pairs:
        for seed in range(args.trials):
            config = TrialConfig(
                env=args.env,
                task=task,
                object=obj,
                seed=seed,
                max_steps=args.max_steps or suite.criterion.max_steps,
                max_iter=settings.max_iter,
                compile=settings.compile,
                dtype=settings.dtype,
                stiffness=args.stiffness,
                model=args.model,
                relaxation=args.relaxation,
                learned=args.learned,
                memory=settings.memory,
                horizon=settings.horizon,
                collision=args.collision,
                gaps=settings.gaps,
            )
            path = trials_dir / f"{config.name}.json"
            record = _finished(path, config)
            if record is not None:
                done[config] = record
                continue
            video = args.out / f"{config.name}.gif" if args.video and seed == 0 else None
            jobs.append(Job(config, path, video))
    qp = args.model == "qp"
    if qp:
        about = f"relaxed QP, paper's κ = {args.relaxation:g}"
    elif args.learned is not None:
        about = f"learned K(q), D(q) from {args.learned}"
    else:
        about = f"K = {args.stiffness:g}"
    print(f"MPC through the {args.model} model ({about}); solver {settings.label}")
    print(TABLE_HEADER)
    for record in done.values():
        tqdm.write(_table_row(record))
    bar = tqdm(total=len(jobs), desc=f"{args.env} trials", disable=args.no_progress)
    new = []
    if args.workers == 1:
        results = map(_run_job, jobs)
        pool = None
    else:
        pool = multiprocessing.get_context("spawn").Pool(min(args.workers, len(jobs) or 1))
        results = pool.imap_unordered(_run_job, jobs)
    try:
        for record in results:
            new.append(record)
            tqdm.write(_table_row(record))
            bar.update()
            bar.set_postfix(success=f"{np.mean([r['success'] for r in new]):.0%}")
    finally:
        bar.close()
        if pool is not None:
            pool.close()
            pool.join()
    records = list(done.values()) + new
    records.sort(key=lambda r: (args.pairs.index((r["task"], r["object"])), r["seed"]))
    summary = summarize(records)
    summary["model"], summary["relaxation"] = args.model, args.relaxation
    summary["learned"] = args.learned
    # the preset's name only when no option overrode it
    summary["preset"] = args.preset if settings == preset(args.env, args.preset) else None
    summary["settings"] = dataclasses.asdict(settings)
    summary["pairs"] = {
        f"{task} {obj}": summarize([r for r in records if (r["task"], r["object"]) == (task, obj)])
        for task, obj in args.pairs
    }
    write_json(args.out / "summary.json", summary)
    write_csv(args.out / "trials.csv", [_csv_row(r) for r in records])
    plot_results(records, args.out / "results.png")
    if args.json is not None:
        write_json(args.json, summary)
    if len(args.pairs) > 1:
        print(
            f"{'pair':>30s} {'success':>8s} {'falls':>5s} {'pos [mm]':>9s} {'ang [°]':>8s} "
            f"{'solve ms':>9s}"
        )
        for pair, s in summary["pairs"].items():
            print(
                f"{pair:>30s} {100 * s['success_rate']:>7.0f}% {_count(s['falls']):>5s} "
                f"{s['pos_err_mm_mean']:>9.1f} {s['angle_err_deg_mean']:>8.1f} "
                f"{s['solve_ms_median']:>9.1f}"
            )
    print(
        f"success {100 * summary['success_rate']:.1f}% of {summary['trials']}, "
        f"falls {_count(summary['falls'])} | "
        f"final position {summary['pos_err_mm_mean']:.1f} mm, "
        f"angle {summary['angle_err_deg_mean']:.1f}° (quat err {summary['quat_err_mean']:.4f}) | "
        f"MPC solve median {summary['solve_ms_median']:.1f} ms, p90 {summary['solve_ms_p90']:.1f}"
        f" ms | detect {summary['detect_ms_median']:.2f} ms, sim {summary['sim_ms_median']:.2f} ms"
    )
    print(f"wrote {args.out}/summary.json, trials.csv, results.png")
    return 0


def _count(n: int | None) -> str:
    return "?" if n is None else str(n)


def _csv_row(record: dict) -> dict:
    keys = ("task", "object", "seed", "success", "steps", "pos_err_mm", "quat_err")
    row = {k: record[k] for k in (*keys, "angle_err_deg")}
    row["fell"] = _fell(record)
    row["solve_ms_median"] = float(np.median(record["solve_ms"]))
    return row
