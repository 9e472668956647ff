"""Reporting a sweep's trial records: summary statistics, the per-trial table, CSV rows, the
paper-style figure and GIFs. Records are the dicts of
:meth:`~torchcontact.mpc.trial_config.TrialRecord.to_dict` (older ones may lack later keys)."""

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


def solve_times(record: dict) -> np.ndarray:
    """The record's MPC solve times [ms] of the steps its MPC planned as configured: those
    planned eagerly while the graph compiled (``eager_steps``) are left out (all of them may
    be; see :func:`eager_solve_times`)."""
    return np.delete(np.asarray(record["solve_ms"], dtype=float), record.get("eager_steps") or [])


def eager_solve_times(record: dict) -> np.ndarray:
    """The record's solve times [ms] of the steps planned eagerly while its MPC compiled."""
    return np.asarray(record["solve_ms"], dtype=float)[record.get("eager_steps") or []]


def _statistics(times: list[np.ndarray], prefix: str, count: str) -> dict:
    """``{prefix}_ms_median``, ``{prefix}_ms_p90`` (None where ``times`` hold none) and the
    number ``count`` of the concatenated ``times``."""
    times = np.concatenate(times)
    empty = times.size == 0
    return {
        f"{prefix}_ms_median": None if empty else float(np.median(times)),
        f"{prefix}_ms_p90": None if empty else float(np.percentile(times, 90)),
        count: int(times.size),
    }


def ms(value: float | None) -> str:
    """A solve time [ms] for a table: ``-`` where there is none (no step was compiled)."""
    return "-" if value is None else f"{value:.1f}"


def summarize(records: list[dict]) -> dict:
    """Success rate, mean final errors and MPC time statistics over trial records: the solve
    times of the steps planned as configured (:func:`solve_times`; None where every step was
    planned eagerly while the MPC compiled) and, apart, of those planned eagerly meanwhile
    (:func:`eager_solve_times`), each with its count."""
    if not records:
        raise ValueError("records must hold at least one trial")
    success = [r for r in records if r["success"]]

    def mean_of(key, rows):
        return float(np.mean([r[key] for r in rows])) if rows else float("nan")

    fallen = [fell(r) for r in records]
    toppled = [tipped(r) for r in records]

    return {
        "success_rate": len(success) / len(records),
        "pos_err_mm_mean": mean_of("pos_err_mm", records),
        "angle_err_deg_mean": mean_of("angle_err_deg", records),
        "quat_err_mean": mean_of("quat_err", records),
        "pos_err_mm_mean_success": mean_of("pos_err_mm", success),
        "angle_err_deg_mean_success": mean_of("angle_err_deg", success),
        # the steps planned as configured (compiled, or eager by choice) apart from those
        # planned eagerly while the MPC compiled: never one median of both
        **_statistics([solve_times(r) for r in records], "solve", "solve_steps"),
        **_statistics([eager_solve_times(r) for r in records], "eager_solve", "eager_steps"),
        "detect_ms_median": float(np.median(np.concatenate([r["detect_ms"] for r in records]))),
        "sim_ms_median": float(np.median(np.concatenate([r["sim_ms"] for r in records]))),
        "iterations_median": float(np.median(np.concatenate([r["iterations"] for r in records]))),
        "steps_median": float(np.median([r["steps"] for r in records])),
        "trials": len(records),
        # trials whose object left its support (see tasks.fell); None where a record cannot tell
        "falls": None if None in fallen else sum(fallen),
        # trials whose object ended tipped over (see tasks.tilt_error); None likewise
        "tipped": None if None in toppled else sum(toppled),
    }


def fell(record: dict) -> bool | None:
    """A record's ``fell``; for records written before the key, from their poses (None
    when they have none)."""
    if "fell" in record:
        return record["fell"]
    if "initial_pose" in record and "final_pose" in record:
        return tasks.fell(record["initial_pose"], record["final_pose"])
    return None


def tilt_error_deg(record: dict) -> float | None:
    """The record's final :func:`~torchcontact.environments.tasks.tilt_error` [deg], from its
    final and target poses (None when it has none)."""
    if "final_pose" not in record or "target_pose" not in record:
        return None
    return float(tasks.tilt_error(record["final_pose"][3:], record["target_pose"][3:]))


def tipped(record: dict) -> bool | None:
    """Whether the record's object ended tipped over: its :func:`tilt_error_deg` past
    :data:`~torchcontact.environments.tasks.TIPPED_TILT` (None when it has no poses)."""
    tilt = tilt_error_deg(record)
    return None if tilt is None else tilt > tasks.TIPPED_TILT


MAX_LABELLED_GROUPS = 24
"""Above this many (task, object) pairs a sweep is drawn as a population (against the objects'
size and aspect ratio) rather than one bar per pair."""


def plot_results(records: list[dict], path: Path) -> Path:
    """The sweep's figure, a grid readable at page width: success and final errors per (task,
    object) pair with failures in grey; above :data:`MAX_LABELLED_GROUPS` pairs, success
    against each object's size and aspect ratio and the distributions of the final errors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = sorted({(r["task"], r["object"]) for r in records})
    if len(groups) > MAX_LABELLED_GROUPS:
        figure = _plot_population(plt, records)
    else:
        figure = _plot_pairs(plt, records, groups)
    figure.tight_layout()
    path = save_figure(figure, path)
    plt.close(figure)
    return path


def _plot_pairs(plt, records: list[dict], groups: list[tuple[str, str]]):
    """Three stacked panels sharing the pairs' axis: success, final position, final angle."""
    labels = [f"{task} {Path(obj).stem}" for task, obj in groups]
    figure, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    rows = [[r for r in records if (r["task"], r["object"]) == g] for g in groups]
    rates = [100 * np.mean([r["success"] for r in rs]) for rs in rows]
    axes[0].bar(range(len(groups)), rates, color="tab:blue")
    for i, rate in enumerate(rates):
        axes[0].text(i, rate + 1, f"{rate:.0f}", ha="center", fontsize=8)
    axes[0].set_ylabel("success [%]")
    axes[0].set_ylim(0, 112)
    for axis, key, unit in ((axes[1], "pos_err_mm", "mm"), (axes[2], "angle_err_deg", "°")):
        ok = [[r[key] for r in rs if r["success"]] for rs in rows]
        if any(ok):
            positions = [i for i, values in enumerate(ok) if values]
            axis.violinplot([ok[i] for i in positions], positions=positions, showmedians=True)
        for i, rs in enumerate(rows):
            failed = [r[key] for r in rs if not r["success"]]
            axis.scatter([i] * len(failed), failed, color="grey", s=12, zorder=3)
        axis.set_ylabel(f"final {key.split('_err')[0]} error [{unit}]")
    axes[2].set_xticks(range(len(groups)), labels, rotation=40, ha="right", fontsize=9)
    axes[0].set_title(f"{len(records)} trials; failed trials as grey dots", fontsize=10)
    return figure


def _plot_population(plt, records: list[dict]):
    """A 2 × 2 grid: success against largest extent and aspect ratio (per trial, jittered),
    and histograms of the final errors of successes and failures."""
    figure, axes = plt.subplots(2, 2, figsize=(10, 7))
    sized = [r for r in records if r.get("object_extent")]
    success = np.array([r["success"] for r in sized], dtype=float)
    jitter = np.random.default_rng(0).uniform(-0.04, 0.04, len(sized))
    extent = np.array([100 * max(r["object_extent"]) for r in sized])
    aspect = np.array([max(r["object_extent"]) / min(r["object_extent"]) for r in sized])
    panels = (
        (axes[0, 0], extent, "largest extent [cm]"),
        (axes[0, 1], aspect, "aspect ratio (longest / shortest side)"),
    )
    for axis, x, label in panels:
        axis.scatter(x, success + jitter, c=np.where(success > 0, "tab:blue", "grey"), s=14)
        axis.set_yticks([0, 1], ["failed", "succeeded"])
        axis.set_xlabel(label)
    for axis, key, unit in ((axes[1, 0], "pos_err_mm", "mm"), (axes[1, 1], "angle_err_deg", "°")):
        bins = np.histogram_bin_edges([r[key] for r in records], bins=30)
        for outcome, colour, name in ((True, "tab:blue", "succeeded"), (False, "grey", "failed")):
            values = [r[key] for r in records if r["success"] == outcome]
            if values:
                axis.hist(values, bins=bins, color=colour, alpha=0.7, label=name)
        axis.set_xlabel(f"final {key.split('_err')[0]} error [{unit}]")
        axis.set_ylabel("trials")
        axis.legend(fontsize=8)
    objects = len({r["object"] for r in records})
    rate = 100 * np.mean([r["success"] for r in records])
    figure.suptitle(f"{objects} objects, {len(records)} trials: {rate:.1f} % succeeded")
    return figure


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
        f"{ms(_median_or_none(solve_times(record))):>8s}"
    )


TABLE_HEADER = (
    f"{'task':>9s} {'object':>11s} {'seed':>4s} {'success':>7s} {'steps':>5s} "
    f"{'pos [mm]':>8s} {'quat err':>8s} {'ang [°]':>7s} {'solve ms':>8s}"
)


def _median_or_none(times: np.ndarray) -> float | None:
    return float(np.median(times)) if times.size else None


def count(n: int | None) -> str:
    return "?" if n is None else str(n)


def csv_row(record: dict) -> dict:
    keys = ("task", "object", "seed", "success", "steps", "pos_err_mm", "quat_err")
    row = {k: record[k] for k in (*keys, "angle_err_deg")}
    row["fell"] = fell(record)
    row["tilt_err_deg"] = tilt_error_deg(record)
    row["solve_ms_median"] = _median_or_none(solve_times(record))
    return row
