"""Reporting a sweep's trial records: summary statistics, the per-trial table, CSV rows, the
paper-style figure and GIFs. Records are the dicts of
:meth:`~torchcontact.mpc.trials.TrialRecord.to_dict` (older ones may lack later keys)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchcontact.environments import tasks
from torchcontact.results import atomic_write, save_figure

SUMMARY_KEYS = (
    "success_rate",
    "pos_err_mm_mean",
    "angle_err_deg_mean",
    "solve_ms_median",
    "solve_ms_p90",
    "trials",
)


def summarize(records: list[dict]) -> dict:
    """Success rate, mean final errors and MPC time statistics over trial records."""
    if not records:
        raise ValueError("records must hold at least one trial")
    solve = np.concatenate([r["solve_ms"] for r in records])
    success = [r for r in records if r["success"]]

    def mean_of(key, rows):
        return float(np.mean([r[key] for r in rows])) if rows else float("nan")

    fallen = [fell(r) for r in records]

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


def fell(record: dict) -> bool | None:
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


def table_row(record: dict) -> str:
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


def count(n: int | None) -> str:
    return "?" if n is None else str(n)


def csv_row(record: dict) -> dict:
    keys = ("task", "object", "seed", "success", "steps", "pos_err_mm", "quat_err")
    row = {k: record[k] for k in (*keys, "angle_err_deg")}
    row["fell"] = fell(record)
    row["solve_ms_median"] = float(np.median(record["solve_ms"]))
    return row
