"""How to set K: closed-loop MPC performance against the contact stiffness (the paper's figure).

    python benchmarks/stiffness_sweep.py                      # K = 1e-3 … 1e2, 10 trials each
    python benchmarks/stiffness_sweep.py --stiffness 0.1 1 10 --trials 3 --workers 2

Runs the trials of ``torchcontact run fingertips --task rotation --object bunny --max-steps
500`` once per K through :func:`~torchcontact.mpc.trials.run_trials` (trial seeds
0…trials−1, each K in its own folder under ``--out``, so an interrupted sweep resumes trial by
trial), then prints success, final errors and solve time per K and writes
``stiffness_sweep.json``, ``stiffness_sweep.csv`` and ``stiffness_sweep.png`` (default under
results/stiffness_sweep/).
"""

import os

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from torchcontact.mpc.model_options import ModelOptions  # noqa: E402
from torchcontact.mpc.report import SUMMARY_KEYS, summarize  # noqa: E402
from torchcontact.mpc.trial_config import trial_configs  # noqa: E402
from torchcontact.mpc.trials import run_trials  # noqa: E402
from torchcontact.results import save_figure, write_csv, write_json  # noqa: E402

STIFFNESS = (1e-3, 1e-2, 0.1, 0.3, 1.0, 3.0, 10.0, 100.0)
"""K [per row] from 1e-3 to 1e2, denser around the paper's K = 1."""


def run_one(stiffness: float, args: argparse.Namespace) -> dict:
    """One K: the summary of its trials (their records resume from ``out/K_…/trials``)."""
    configs = trial_configs(
        "fingertips",
        [("rotation", "bunny")],
        range(args.trials),
        max_steps=args.max_steps,
        model_options=ModelOptions(stiffness=stiffness),
    )
    records = run_trials(configs, workers=args.workers, out=args.out / f"K_{stiffness:g}")
    summary = summarize([record.to_dict() for record in records])
    return {"stiffness": stiffness, **{key: summary[key] for key in SUMMARY_KEYS}}


def plot(rows: list[dict], path: Path) -> Path:
    figure, axes = plt.subplots(1, 3, figsize=(12, 3.5))
    ks = [row["stiffness"] for row in rows]
    panels = (
        ("success_rate", "success rate", 1.0),
        ("pos_err_mm_mean", "final position error [mm]", 1.0),
        ("angle_err_deg_mean", "final angle error [°]", 1.0),
    )
    for axis, (key, label, scale) in zip(axes, panels, strict=True):
        axis.semilogx(ks, [scale * row[key] for row in rows], "o-")
        axis.set_xlabel("contact stiffness K")
        axis.set_ylabel(label)
        axis.grid(True, which="both", alpha=0.3)
    figure.suptitle("fingertips, bunny on-ground rotation: MPC performance against K")
    figure.tight_layout()
    saved = save_figure(figure, path)
    plt.close(figure)
    return saved


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stiffness", type=float, nargs="+", default=list(STIFFNESS))
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--max-steps", type=int, default=500)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("results/stiffness_sweep"))
    args = parser.parse_args(argv)
    if any(not k > 0 for k in args.stiffness):
        parser.error(f"--stiffness values must be positive, got {args.stiffness}")
    rows = [run_one(k, args) for k in sorted(args.stiffness)]
    print(f"{'K':>8} {'success':>8} {'pos mm':>8} {'ang °':>7} {'solve ms':>9}")
    for row in rows:
        print(
            f"{row['stiffness']:8g} {100 * row['success_rate']:7.0f}% {row['pos_err_mm_mean']:8.1f}"
            f" {row['angle_err_deg_mean']:7.1f} {row['solve_ms_median']:9.1f}"
        )
    write_json(args.out / "stiffness_sweep.json", {"rows": rows, "settings": vars(args)})
    write_csv(args.out / "stiffness_sweep.csv", rows)
    print(f"wrote {plot(rows, args.out / 'stiffness_sweep.png')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
