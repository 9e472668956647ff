"""Closed-loop evaluation: run MPC trials in MuJoCo, summarize, plot, record.

``torchcontact run fingertips --task in-air --object cube --trials 20`` runs trial seeds
0…19, writes one JSON per finished trial (atomically, so an interrupted sweep resumes where it
stopped), then a summary (JSON + CSV), the paper-style figure and, on request, a GIF.

Per control step: detect contacts at the real state (MuJoCo), solve the MPC (torch), and
simulate the applied control (MuJoCo); the three times are recorded separately.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from torchcontact.mpc import tasks
from torchcontact.mpc.fingertips import STIFFNESS, fingertips_mpc
from torchcontact.results import atomic_write, read_json, save_figure, write_csv, write_json

SUMMARY_KEYS = (
    "success_rate",
    "pos_err_mm_mean",
    "angle_err_deg_mean",
    "solve_ms_median",
    "solve_ms_p90",
    "trials",
)


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
    stiffness: float

    @property
    def name(self) -> str:
        return f"{self.env}_{self.task}_{self.object}_seed{self.seed}"


def _fingertips_env(obj: str):
    from torchcontact.sim import FingertipsEnv

    settings = tasks.OBJECT_SETTINGS[obj]
    # A multi-part mesh can touch in more places than the model has slots; the MPC then keeps
    # the deepest contacts and every trial records how often that happened.
    return FingertipsEnv(
        obj,
        object_friction=settings.object_friction,
        contact_slots=settings.contact_slots,
        overflow="deepest",
    )


def run_trial(config: TrialConfig, env, mpc, frames: list | None = None, frame_every: int = 5):
    """Run one trial to success or ``max_steps``; returns its record (a JSON-able dict)."""
    initial, target = tasks.sample(config.task, config.object, config.seed)
    env.reset(initial, target)
    mpc.reset()
    tracker = tasks.SuccessTracker(target)
    target_p = torch.as_tensor(target[:3])
    target_quat = torch.as_tensor(target[3:])
    detect_ms, solve_ms, sim_ms, iterations, found = [], [], [], [], []
    for step in range(config.max_steps):
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
        "final_pose": final.tolist(),
        "detect_ms": detect_ms,
        "solve_ms": solve_ms,
        "sim_ms": sim_ms,
        "iterations": iterations,
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
    }


def plot_results(records: list[dict], path: Path) -> Path:
    """The paper's figure: success per (task, object) and final errors, failures in grey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = sorted({(r["task"], r["object"]) for r in records})
    labels = [f"{task}\n{obj}" for task, obj in groups]
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
        f"{record['task']:>9s} {record['object']:>11s} {record['seed']:>4d} "
        f"{'yes' if record['success'] else 'no':>7s} {record['steps']:>5d} "
        f"{record['pos_err_mm']:>8.1f} {record['quat_err']:>8.4f} {record['angle_err_deg']:>7.1f} "
        f"{np.median(record['solve_ms']):>8.1f}"
    )


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="torchcontact run", description="Closed-loop MPC trials in MuJoCo."
    )
    parser.add_argument("env", choices=["fingertips"], help="the environment")
    parser.add_argument("--task", default="rotation", help=f"one of {tasks.TASKS} or 'all'")
    parser.add_argument("--object", default="cube", help="an object name or 'all'")
    parser.add_argument("--trials", type=int, default=tasks.TRIALS, help="seeds 0…trials−1")
    parser.add_argument("--max-steps", type=int, default=None, help="default: the task's")
    parser.add_argument("--max-iter", type=int, default=30, help="L-BFGS iterations per step")
    parser.add_argument("--stiffness", type=float, default=STIFFNESS, help="the model's K")
    parser.add_argument("--no-compile", action="store_true", help="eager objective")
    parser.add_argument("--dtype", choices=["float32", "float64"], default="float64")
    parser.add_argument("--out", type=Path, default=Path("results/mpc"), help="output folder")
    parser.add_argument("--json", type=Path, default=None, help="write the summary here too")
    parser.add_argument("--video", action="store_true", help="record trial 0 of each pair")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    if not args.stiffness > 0:
        parser.error(f"--stiffness must be positive, got {args.stiffness}")
    if args.trials < 1:
        parser.error(f"--trials must be >= 1, got {args.trials}")
    if args.max_steps is not None and args.max_steps < 1:
        parser.error(f"--max-steps must be >= 1, got {args.max_steps}")
    return args


def _pairs(task: str, obj: str) -> list[tuple[str, str]]:
    pairs = [(t, o) for t, o in tasks.PAPER_PAIRS if task in ("all", t) and obj in ("all", o)]
    if task not in ("all", *tasks.TASKS):
        raise SystemExit(f"--task must be one of {tasks.TASKS} or 'all', got {task!r}")
    if obj not in ("all", *tasks.OBJECT_SETTINGS):
        raise SystemExit(
            f"--object must be one of {tuple(tasks.OBJECT_SETTINGS)} or 'all', got {obj!r}"
        )
    if not pairs:
        raise SystemExit(f"no paper task pairs {task!r} with object {obj!r}")
    return pairs


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    torch.set_num_threads(1)
    args = parse_args(argv)
    dtype = getattr(torch, args.dtype)
    records = []
    trials_dir = args.out / "trials"
    header = f"{'task':>9s} {'object':>11s} {'seed':>4s} {'success':>7s} {'steps':>5s} "
    header += f"{'pos [mm]':>8s} {'quat err':>8s} {'ang [°]':>7s} {'solve ms':>8s}"
    print(header)
    for task, obj in _pairs(args.task, args.object):
        max_steps = args.max_steps or tasks.FINGERTIPS_SUCCESS.max_steps
        env, mpc, pair_records = None, None, []
        bar = tqdm(range(args.trials), desc=f"{task} {obj}", disable=args.no_progress)
        for seed in bar:
            config = TrialConfig(
                "fingertips",
                task,
                obj,
                seed,
                max_steps,
                args.max_iter,
                not args.no_compile,
                args.dtype,
                args.stiffness,
            )
            path = trials_dir / f"{config.name}.json"
            record = read_json(path) if path.exists() else None
            if record is None or any(record.get(k) != v for k, v in config.__dict__.items()):
                if env is None:
                    env = _fingertips_env(obj)
                    mpc = fingertips_mpc(
                        obj,
                        stiffness=args.stiffness,
                        max_iter=args.max_iter,
                        compile=not args.no_compile,
                        dtype=dtype,
                    )
                frames = [] if args.video and seed == 0 else None
                record = run_trial(config, env, mpc, frames)
                write_json(path, record)
                if frames:
                    save_gif(frames, args.out / f"{config.name}.gif")
            pair_records.append(record)
            tqdm.write(_table_row(record))
            bar.set_postfix(success=f"{np.mean([r['success'] for r in pair_records]):.0%}")
        records += pair_records
    summary = summarize(records)
    summary["pairs"] = {
        f"{task} {obj}": summarize([r for r in records if (r["task"], r["object"]) == (task, obj)])
        for task, obj in sorted({(r["task"], r["object"]) for r in records})
    }
    write_json(args.out / "summary.json", summary)
    write_csv(args.out / "trials.csv", [_csv_row(r) for r in records])
    plot_results(records, args.out / "results.png")
    if args.json is not None:
        write_json(args.json, summary)
    print(
        f"success {100 * summary['success_rate']:.1f}% of {summary['trials']} | "
        f"final position {summary['pos_err_mm_mean']:.1f} mm, "
        f"angle {summary['angle_err_deg_mean']:.1f}° (quat err {summary['quat_err_mean']:.4f}) | "
        f"MPC solve median {summary['solve_ms_median']:.1f} ms, p90 {summary['solve_ms_p90']:.1f}"
        f" ms | detect {summary['detect_ms_median']:.2f} ms, sim {summary['sim_ms_median']:.2f} ms"
    )
    print(f"wrote {args.out}/summary.json, trials.csv, results.png")
    return 0


def _csv_row(record: dict) -> dict:
    keys = ("task", "object", "seed", "success", "steps", "pos_err_mm", "quat_err")
    row = {k: record[k] for k in (*keys, "angle_err_deg")}
    row["solve_ms_median"] = float(np.median(record["solve_ms"]))
    return row
