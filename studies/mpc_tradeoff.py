"""MPC-level speed–accuracy trade-off: closed-loop success and error against solve time.

For each solver setting of :data:`GRID` (one-at-a-time variations of ``balanced``: L-BFGS
iterations and memory, horizon T, dtype, compiled or eager, plus the presets) and each
environment of :data:`PAIRS` (fingertip cube rotation and in-air, TriFinger cube, foam brick,
stick), runs ``trials`` closed-loop trials with ``torchcontact run`` (so each trial is written
atomically and an interrupted sweep resumes) and tabulates success rate, mean final errors and
the median MPC solve time per step.

A setting is on an environment's Pareto front when no other setting is at least as fast, at
least as successful and at least as accurate in mean final angle, and better in one of them.

Outputs under ``out`` (default ``results/tradeoff/mpc``): ``mpc_tradeoff.csv``, ``.json``,
``.md`` (a table per environment, the front and where the presets lie) and
``mpc_pareto_ENV.png`` (success and angle error against solve time, front and presets marked).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from collections.abc import Sequence
from pathlib import Path

from tqdm.auto import tqdm

from studies import report
from torchcontact.environments import environment
from torchcontact.environments.presets import NAMES, PAPER, MPCSettings
from torchcontact.mpc.report import summarize
from torchcontact.mpc.trial_config import trial_configs
from torchcontact.mpc.trials import run_trials
from torchcontact.parallel import BACKENDS
from torchcontact.results import pareto_front, read_json

PAIRS: dict[str, tuple[tuple[str, str], ...]] = {
    "fingertips": (("rotation", "cube"), ("in-air", "cube")),
    "trifinger": (("in-hand", "cube"), ("in-hand", "foam_brick"), ("in-hand", "stick")),
}
"""(task, object) pairs run per environment: an easy and a hard fingertip task, and TriFinger's
easiest, a soft and its hardest object of the paper's set."""


def _grid() -> dict[str, MPCSettings]:
    base = PAPER
    variations = [
        *(dict(max_iter=n) for n in (5, 10, 20, 50)),
        *(dict(memory=m) for m in (3, 16)),
        *(dict(horizon=t) for t in (2, 6, 8)),
        dict(dtype="float32"),
        dict(compile=False),
    ]
    presets = [p for env in PAIRS for p in environment(env).presets.values()]
    settings = [base, *(dataclasses.replace(base, **v) for v in variations), *presets]
    return {s.label: s for s in settings}  # labels are unique per settings: presets dedupe


GRID: dict[str, MPCSettings] = _grid()
"""The swept settings by label."""

TRIALS = 10


def _folder(label: str) -> str:
    return label.replace(" ", "_")


def sweep_configs(env: str, label: str, trials: int, max_steps: int | None = None):
    """The trials of one (environment, setting): seeds 0…trials−1 of each of its pairs."""
    return trial_configs(env, PAIRS[env], range(trials), GRID[label], max_steps)


def run_sweep(
    out: Path,
    envs: Sequence[str],
    labels: Sequence[str],
    trials: int,
    workers: int = 1,
    max_steps: int | None = None,
    progress: bool = True,
    backend: str = "local",
    address: str | None = None,
) -> dict[tuple[str, str], list[dict]]:
    """Run every (environment, setting) not finished yet (on ``backend``, see
    :func:`~torchcontact.mpc.trials.run_trials`); returns their records by (environment,
    label). Each setting's records resume from ``out/ENV/LABEL/trials``."""
    units = [(env, label) for env in envs for label in labels]
    records = {}
    for env, label in tqdm(units, desc="MPC settings", disable=not progress):
        configs = sweep_configs(env, label, trials, max_steps)
        folder = out / env / _folder(label)
        done = run_trials(
            configs, workers, folder, progress=False, backend=backend, address=address
        )
        records[env, label] = [record.to_dict() for record in done]
    return records


def collect(out: Path, envs: Sequence[str], labels: Sequence[str], trials: int) -> list[dict]:
    """One row per (environment, setting) from the saved trial records of the swept pairs."""
    rows = []
    for env in envs:
        for label in labels:
            settings = GRID[label]
            records = []
            for config in sweep_configs(env, label, trials):
                path = out / env / _folder(label) / "trials" / f"{config.name}.json"
                if not path.exists():
                    raise FileNotFoundError(f"missing trial record {path}: run the sweep")
                record = read_json(path)
                if any(record[k] != v for k, v in dataclasses.asdict(settings).items()):
                    raise ValueError(f"{path} was run with other settings than {label!r}")
                records.append(record)
            summary = summarize(records)
            presets = [name for name in NAMES if environment(env).preset(name) == settings]
            rows.append(
                {
                    "env": env,
                    "label": label,
                    "preset": "/".join(presets),
                    **dataclasses.asdict(settings),
                    **{k: summary[k] for k in ROW_METRICS},
                }
            )
    return mark_front(rows)


ROW_METRICS = (
    "success_rate",
    "pos_err_mm_mean",
    "angle_err_deg_mean",
    "solve_ms_median",
    "solve_ms_p90",
    "iterations_median",
    "trials",
)


def objectives(row: dict) -> tuple[float, float, float]:
    """What the front minimizes: solve time, failure rate, mean final angle error."""
    return row["solve_ms_median"], 1.0 - row["success_rate"], row["angle_err_deg_mean"]


def mark_front(rows: list[dict]) -> list[dict]:
    """Set each row's ``on_front``: is it on its environment's Pareto front of
    :func:`objectives`."""
    for env in dict.fromkeys(r["env"] for r in rows):
        group = [r for r in rows if r["env"] == env]
        front = set(pareto_front([objectives(r) for r in group]))
        for i, row in enumerate(group):
            row["on_front"] = i in front
    return rows


def preset_report(rows: Sequence[dict]) -> list[str]:
    """One line per environment and preset: on the front or not."""
    lines = []
    for env in dict.fromkeys(r["env"] for r in rows):
        for name in NAMES:
            settings = environment(env).preset(name)
            row = next((r for r in rows if r["env"] == env and r["label"] == settings.label), None)
            if row is None:
                lines.append(f"- {env}, `{name}`: not measured")
                continue
            where = "on the front" if row["on_front"] else "NOT on the front"
            lines.append(
                f"- {env}, `{name}` ({settings.label}): {where}: "
                f"{100 * row['success_rate']:.0f} % success, {row['pos_err_mm_mean']:.1f} mm, "
                f"{row['angle_err_deg_mean']:.1f}°, {row['solve_ms_median']:.1f} ms median solve"
            )
    return lines


MARKDOWN_COLUMNS = ("setting", "preset", "success", "pos [mm]", "angle [°]", "solve ms", "p90 ms")


def _markdown_cells(row: dict) -> list[str]:
    """One row of an environment's table; front rows' labels in bold."""
    return [
        f"**{row['label']}**" if row["on_front"] else row["label"],
        row["preset"],
        f"{100 * row['success_rate']:.0f} %",
        f"{row['pos_err_mm_mean']:.1f}",
        f"{row['angle_err_deg_mean']:.1f}",
        f"{row['solve_ms_median']:.1f}",
        f"{row['solve_ms_p90']:.1f}",
    ]


def markdown(rows: Sequence[dict], trials: int) -> str:
    """The report: a table per environment (front rows in bold) and where the presets lie."""
    lines = [
        f"MPC settings, {trials} trials per pair; the front minimizes median solve time, failure "
        "rate and mean final angle error (front rows in **bold**).",
        "",
    ]
    for env in dict.fromkeys(r["env"] for r in rows):
        pairs = ", ".join(f"{task} {obj}" for task, obj in PAIRS[env])
        group = sorted((r for r in rows if r["env"] == env), key=lambda r: r["solve_ms_median"])
        table = report.markdown_table(MARKDOWN_COLUMNS, [_markdown_cells(r) for r in group])
        lines += [f"**{env}** ({pairs})", "", table, ""]
    lines += ["Presets:", "", *preset_report(rows), ""]
    return "\n".join(lines)


def _annotate(ax, x: float, y: float, row: dict) -> None:
    """The setting's label at its point; a red star and the preset's name for a preset."""
    ax.annotate(row["label"], (x, y), fontsize=6, xytext=(3, 3), textcoords="offset points")
    if row["preset"]:
        ax.scatter([x], [y], marker="*", s=180, color="tab:red", zorder=4)
        ax.annotate(
            row["preset"],
            (x, y),
            fontsize=9,
            color="tab:red",
            xytext=(4, -12),
            textcoords="offset points",
        )


def plot(path: Path, rows: Sequence[dict], env: str) -> Path:
    """Success and mean final angle error against median solve time, front and presets marked."""
    group = sorted((r for r in rows if r["env"] == env), key=lambda r: r["solve_ms_median"])
    figure, axes = report.figure(1, 2, size=(11, 4.2))
    for ax, key, scale, name in (
        (axes[0], "success_rate", 100.0, "success [%]"),
        (axes[1], "angle_err_deg_mean", 1.0, "mean final angle error [°]"),
    ):
        x = [r["solve_ms_median"] for r in group]
        y = [scale * r[key] for r in group]
        ax.scatter(x, y, color="grey", s=18, zorder=2)
        front = [(a, b) for a, b, r in zip(x, y, group, strict=True) if r["on_front"]]
        front_x, front_y = zip(*front, strict=True)
        ax.plot(front_x, front_y, "o-", color="tab:blue", ms=5, label="Pareto front", zorder=3)
        for a, b, r in zip(x, y, group, strict=True):
            _annotate(ax, a, b, r)
        ax.set_xscale("log")
        ax.set_xlabel("median MPC solve per step [ms]")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="lower right")
    figure.suptitle(f"{env}: closed-loop MPC, settings and presets (red stars)")
    figure.tight_layout()
    return report.save_figure(figure, path)


def write_outputs(out: Path, rows: list[dict], trials: int) -> list[Path]:
    """CSV, JSON, markdown report and one plot per environment."""
    paths = [
        report.write_csv(out / "mpc_tradeoff.csv", rows),
        report.write_json(
            out / "mpc_tradeoff.json", {"trials": trials, "pairs": PAIRS, "rows": rows}
        ),
        report.write_text(out / "mpc_tradeoff.md", markdown(rows, trials)),
    ]
    for env in dict.fromkeys(r["env"] for r in rows):
        paths.append(plot(out / f"mpc_pareto_{env}.png", rows, env))
    return paths


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The options: ``--env``, ``--settings`` (labels of :data:`GRID`), ``--trials``,
    ``--workers``, ``--max-steps``, the outputs."""
    parser = report.parser(
        "benchmarks/tradeoff.py --level mpc",
        "Closed-loop MPC success and error against solve time, per solver setting.",
        "results/tradeoff/mpc",
    )
    positive_int = report.positive_int
    parser.add_argument("--env", choices=sorted(PAIRS), nargs="+", default=sorted(PAIRS))
    parser.add_argument("--settings", nargs="+", default=list(GRID), help=f"labels of {list(GRID)}")
    parser.add_argument("--trials", type=positive_int, default=TRIALS, help="seeds per pair")
    parser.add_argument("--workers", type=positive_int, default=1, help="parallel trial processes")
    parser.add_argument("--max-steps", type=positive_int, help="default: the task's")
    parser.add_argument("--backend", choices=BACKENDS, default="local", help="local or ray")
    parser.add_argument("--address", default=None, help="(ray) a running cluster's address")
    args = parser.parse_args(argv)
    unknown = [label for label in args.settings if label not in GRID]
    if unknown:
        parser.error(f"--settings must be labels of {list(GRID)}, got {unknown}")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Run what is missing, then print the report and write the outputs; exit status 0."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    args = parse_args(argv)
    run_sweep(
        args.out,
        args.env,
        args.settings,
        args.trials,
        args.workers,
        args.max_steps,
        not args.no_progress,
        args.backend,
        args.address,
    )
    rows = collect(args.out, args.env, args.settings, args.trials)
    paths = write_outputs(args.out, rows, args.trials)
    print()
    print(markdown(rows, args.trials))
    report.written(paths)
    return 0


if __name__ == "__main__":
    report.run_main(main)
