"""The planner's ablation: the paper's L-BFGS against the hybrid planner, on the same trials
in one run.

    python benchmarks/planner_ablation.py allegro --object random:0-49 --trials 1 --workers 2
    python benchmarks/planner_ablation.py trifinger --object random:30-79 --variants lbfgs hybrid

Each variant is the environment's defaults with one change (``torchcontact run ENV --planner P``,
:data:`VARIANTS`), run on the same
objects and trial seeds through :func:`~torchcontact.mpc.trials.run_trials`, each in its own
folder under ``--out`` (default ``results/ablation/ENV``), so an interrupted run resumes trial
by trial and a rerun only reprints. It prints, per variant, success, falls, mean final errors
and the median and p90 MPC solve time, and writes ``ablation.json`` and ``ablation.csv``
there. Solve times are comparable between the rows of one run only (the same machine and
load); run nothing else meanwhile.
"""

import os

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op

import argparse  # noqa: E402
import dataclasses  # noqa: E402
from pathlib import Path  # noqa: E402

from torchcontact.environments import environment  # noqa: E402
from torchcontact.mpc.report import summarize  # noqa: E402
from torchcontact.mpc.trial_config import trial_configs  # noqa: E402
from torchcontact.mpc.trials import run_trials  # noqa: E402
from torchcontact.results import write_csv, write_json  # noqa: E402

VARIANTS = {"lbfgs": {"planner": "lbfgs"}, "hybrid": {"planner": "hybrid"}}
"""Variants by name: the :class:`~torchcontact.mpc.trial_config.TrialConfig` fields they set, as
``torchcontact run ENV --planner P`` does (the rest the environment's defaults)."""


WIDTHS = (18, 8, 6, 7, 6, 7, 6)
"""Printed width of the table's columns."""

COLUMNS = ("success_rate", "falls", "pos_err_mm_mean", "angle_err_deg_mean")
TIMES = ("solve_ms_median", "solve_ms_p90")


def run_variant(name: str, args: argparse.Namespace, pairs) -> dict:
    """One variant's summary row (its records resume from ``out/NAME/trials``)."""
    settings = args.env_description.preset()
    if args.no_compile:
        settings = dataclasses.replace(settings, compile=False)
    configs = trial_configs(
        args.env, pairs, range(args.trials), settings, args.max_steps, **VARIANTS[name]
    )
    records = run_trials(configs, workers=args.workers, out=args.out / name)
    summary = summarize([record.to_dict() for record in records])
    return {"variant": name, **{key: summary[key] for key in (*COLUMNS, *TIMES, "trials")}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("env", choices=("fingertips", "trifinger", "allegro"))
    parser.add_argument("--task", default=None, help="default the environment's first task")
    parser.add_argument("--object", default="random:0-49", help="as `torchcontact run`'s")
    parser.add_argument("--trials", type=int, default=1, help="seeds 0…trials−1 per object")
    parser.add_argument("--variants", nargs="+", choices=sorted(VARIANTS), default=None)
    parser.add_argument("--max-steps", type=int, default=None, help="default the task's")
    parser.add_argument("--no-compile", action="store_true", help="eager objective")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", type=Path, default=None, help="default results/ablation/ENV")
    args = parser.parse_args(argv)
    if args.trials < 1 or args.workers < 1 or (args.max_steps or 1) < 1:
        parser.error("--trials, --workers and --max-steps must be >= 1")
    env = args.env_description = environment(args.env)
    args.out = args.out or Path("results/ablation") / args.env
    try:
        pairs = env.select(args.task or env.pairs[0][0], args.object)
    except ValueError as error:
        parser.error(str(error))
    rows = [run_variant(name, args, pairs) for name in args.variants or VARIANTS]
    print(f"{args.env}, --object {args.object}, {args.trials} trial(s) per object")
    header = ("variant", "success", "falls", "pos mm", "ang °", "median", "p90")
    print(" ".join(f"{name:>{width}}" for name, width in zip(header, WIDTHS, strict=True)))
    for row in rows:
        print(
            f"{row['variant']:>18} {100 * row['success_rate']:7.1f}% {row['falls']:>6}"
            f" {row['pos_err_mm_mean']:7.1f} {row['angle_err_deg_mean']:6.1f}"
            f" {row['solve_ms_median']:7.1f} {row['solve_ms_p90']:6.1f}"
        )  # fmt: skip
    settings = {k: v for k, v in vars(args).items() if k != "env_description"}
    write_json(args.out / "ablation.json", {"rows": rows, "settings": settings})
    write_csv(args.out / "ablation.csv", rows)
    print(f"wrote {args.out / 'ablation.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
