"""``torchcontact run ENV``: closed-loop MPC trials from the command line.

``torchcontact run fingertips --task in-air --object cube --trials 20`` (or ``run trifinger``,
``run allegro``, or ``run custom --robot hand.xml --tips a,b --object mesh.stl``) runs trial
seeds 0…19 of each selected (task, object) pair through :func:`~torchcontact.mpc.trials.
run_trials` (one JSON record per finished trial, so an interrupted sweep resumes), then writes
a summary (JSON + CSV) and the paper-style figure. The options map one to one onto the fields
of :class:`~torchcontact.mpc.trial_config.TrialConfig`.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from pathlib import Path

import torch
from tqdm.auto import tqdm

from torchcontact import generated
from torchcontact.cli import Parser
from torchcontact.cli.options import (
    add_options,
    given_options,
    named_as_option,
    option_name,
    options_object,
)
from torchcontact.environments import ENVIRONMENTS, environment, import_environments
from torchcontact.environments.base import BENCHMARK_COLLISION
from torchcontact.environments.costs import COSTS
from torchcontact.environments.options import CostOptions
from torchcontact.environments.presets import DEFAULT_PRESET, NAMES, MPCSettings
from torchcontact.environments.robot_options import RobotOptions
from torchcontact.environments.tasks import TRIALS
from torchcontact.mpc import report
from torchcontact.mpc.model_options import ModelOptions
from torchcontact.mpc.models import load_learned, mpc_model
from torchcontact.mpc.planners import PLANNERS
from torchcontact.mpc.trial_config import MAX_TRIALS, TrialConfig, trial_configs
from torchcontact.mpc.trials import object_facts, report_compiling, run_trials
from torchcontact.object_sources import canonical_object, mesh_file_of
from torchcontact.objects import ObjectOptions, describe_pose, mesh_rest
from torchcontact.parallel import BACKENDS, RAY_EXTRA, check_backend
from torchcontact.results import (
    locked_folder,
    writable_directory,
    writable_file,
    write_csv,
    write_json,
)
from torchcontact.shapes import COLLISIONS, load_object

SUMMARY_FILES = ("summary.json", "trials.csv", "results.png")
"""What :func:`write_summary` writes in ``--out``."""

IMPORT = "--import"
"""``torchcontact run NAME --import MODULE``: an environment a user's module registers."""

CUSTOM = "custom"
"""``torchcontact run custom --robot FILE --tips SITES``: a user's robot."""


def build_parser(
    prog: str = "torchcontact run", description: str = "Closed-loop MPC trials in MuJoCo."
) -> argparse.ArgumentParser:
    """The options of ``run`` (``torchcontact warm`` takes them too, under its own name)."""
    parser = Parser(prog=prog, description=description)
    parser.add_argument("env", choices=sorted([*ENVIRONMENTS, CUSTOM]), help="the environment")
    parser.add_argument("--task", default="all", help="a task of the environment or 'all'")
    parser.add_argument(
        "--object",
        default="cube",
        help="a built-in object, 'all', or (hands, custom) a mesh file in metres, a generated "
        f"object random-SEED, or a set of them: random:N (N objects from seed "
        f"{generated.REPORT_SEEDS}, the reported set) or random:A-B (seeds A to B; tune on "
        f"seeds below {generated.REPORT_SEEDS}), or PREFIX:NAME of a source a module "
        f"registers (register_object_source, {IMPORT}); several, comma-separated",
    )
    parser.add_argument(
        "--trials", type=int, default=TRIALS, help="seeds first-seed…first-seed+trials−1"
    )
    parser.add_argument(
        "--first-seed",
        type=int,
        default=0,
        help="the first trial seed (default 0, the reported seeds; tune on others)",
    )
    parser.add_argument("--max-steps", type=int, default=None, help="default: the task's")
    parser.add_argument(
        "--robot", type=Path, default=None, help="(custom) the robot's MJCF, attached to a scene"
    )
    parser.add_argument(
        "--tips", default=None, help="(custom) fingertip site names, comma-separated"
    )
    parser.add_argument(
        IMPORT,
        dest="env_module",
        default=None,
        metavar="MODULE",
        help="a module or .py file that registers environments (register_environment) or "
        "object sources (register_object_source), to run them by name",
    )
    parser.add_argument(
        "--preset",
        choices=NAMES,
        default=DEFAULT_PRESET,
        help="the environment's solver settings from the measured speed-accuracy front "
        "(README 'Choosing settings'); the options below override single values",
    )
    parser.add_argument(
        "--planner",
        choices=sorted(PLANNERS),
        default=None,
        help="lbfgs (the paper's) or hybrid (sampling choosing L-BFGS's second start); "
        "default the environment's",
    )
    parser.add_argument(
        "--cost", choices=sorted(COSTS), default=None, help="the MPC cost; default the env's"
    )
    parser.add_argument(
        "--collision",
        choices=COLLISIONS,
        default=BENCHMARK_COLLISION,
        help="how the object collides: hull (default: its convex hull, as the paper's objects "
        "do), auto (part by part for the bowl, cup, mug and torus) or parts (every object "
        "part by part)",
    )
    parser.add_argument(
        "--workers", type=int, default=1, help="parallel trial processes (or local Ray CPUs)"
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="local",
        help=f"where trials run: local processes, or Ray tasks ({RAY_EXTRA})",
    )
    parser.add_argument(
        "--address", default=None, help="(ray) a running cluster's address; default a local one"
    )
    parser.add_argument("--out", type=_folder, default=None, help="default results/VARIANT")
    parser.add_argument("--json", type=Path, default=None, help="write the summary here too")
    parser.add_argument(
        "--figure", type=Path, default=None, help="write the results figure here too (.png)"
    )
    parser.add_argument("--video", action="store_true", help="record trial 0 of each pair")
    parser.add_argument("--no-progress", action="store_true")
    add_options(parser, ModelOptions, title="the contact model the MPC plans through")
    add_options(parser, MPCSettings, title="solver settings, each overriding the --preset's")
    add_options(parser, ObjectOptions, "object", "the object (hands, custom), default the scene's")
    add_options(parser, CostOptions, title="the environment's cost terms (hands)")
    add_options(parser, RobotOptions, title="a user robot (custom), default from its MJCF")
    return parser


def _folder(text: str) -> Path:
    """``--out``: a folder's path; an empty one would write into the current folder."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must name a folder, got an empty path")
    return Path(text)


def _check_options(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Reject option combinations that mean nothing, naming the option."""
    args.model_options = options_object(parser, args, ModelOptions())
    model = mpc_model(args.model_options.model)
    if not model.moving_gaps and args.gaps not in (None, "frozen"):
        parser.error(
            f"--gaps {args.gaps} is for the paper model; {model.name} plans with frozen gaps"
        )
    if not model.moving_gaps:
        args.gaps = "frozen"
    learned = args.model_options.learned
    if learned is not None:
        if not Path(learned).is_file():
            parser.error(f"--learned must be an existing checkpoint file, got {learned!r}")
        learned = str(Path(learned).resolve())  # one record name however it was typed
        args.model_options = dataclasses.replace(args.model_options, learned=learned)
    for name in ("trials", "workers", "max_steps"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.trials > MAX_TRIALS:
        parser.error(f"--trials must be at most {MAX_TRIALS}, got {args.trials}")
    if args.first_seed < 0:
        parser.error(f"--first-seed must be >= 0, got {args.first_seed}")
    try:
        check_backend(args.workers, args.backend, args.address)
    except (ValueError, ImportError) as error:
        parser.error(f"--backend/--address/--workers: {error}")
    custom = args.env == CUSTOM
    if custom != (args.robot is not None):
        parser.error("--robot is required by, and only for, the custom environment")
    if args.tips is not None and not custom:
        parser.error("--tips is for the custom environment")
    args.cost_options = options_object(parser, args, CostOptions())
    given = given_options(args, CostOptions)
    if given and args.cost is not None:
        parser.error(
            f"{option_name(next(iter(given)))} is a term of the environment's cost: drop --cost"
        )
    args.robot_options = options_object(parser, args, RobotOptions())
    given = given_options(args, RobotOptions)
    if given and not custom:
        parser.error(f"{option_name(next(iter(given)))} is for the custom environment")
    args.object_options = options_object(parser, args, ObjectOptions(), "object")
    if custom and not args.robot.is_file():
        parser.error(f"--robot must be an existing MJCF file, got {str(args.robot)!r}")


def _import_named_module(argv: list[str] | None) -> None:
    """Import the module of ``--import`` before the parser lists the environments."""
    found = argparse.ArgumentParser(add_help=False)
    found.add_argument(IMPORT, dest="env_module", default=None)
    module = found.parse_known_args(argv)[0].env_module
    if module is not None:
        try:
            import_environments(module)
        except ValueError as error:
            Parser(prog="torchcontact run").error(f"{IMPORT}: {error}")


def parse_args(argv: list[str] | None, **parser_names) -> argparse.Namespace:
    """``run``'s options, checked (``parser_names``: :func:`build_parser`'s prog and
    description, for another job that takes them)."""
    _import_named_module(argv)
    parser = build_parser(**parser_names)
    args = parser.parse_args(argv)
    if args.env_module is not None and args.env_module.endswith(".py"):
        args.env_module = str(Path(args.env_module).resolve())  # the same file for every worker
    _check_options(parser, args)
    args.tips = None if args.tips is None else tuple(args.tips.split(","))
    args.robot = None if args.robot is None else str(args.robot.resolve())
    try:
        env = environment(args.env, args.robot, args.tips, args.robot_options)
        pairs = env.select(args.task, args.object)
        args.pairs = [(task, canonical_object(obj)) for task, obj in pairs]
        pose = args.object_options.pose
        named = [obj for _, obj in args.pairs if mesh_file_of(obj) is None]
        if pose != "stable" and named:
            raise ValueError(f"--object-pose {pose} is for mesh files, got {named[0]!r}")
        if not env.user_meshes and not args.object_options.is_default:
            raise ValueError(f"--object-size/-scale/-mass/-friction/-pose are not for {args.env}")
        # a cost option or a robot's: a scene it applies to and a value that fits, before
        # any trial
        if not (args.cost_options.is_default and args.robot_options.is_default):
            plant = env.make_plant(args.pairs[0][1], args.collision, args.object_options)
            env.cost(plant, args.cost_options)
    except ValueError as error:
        parser.error(named_as_option(named_as_option(str(error), RobotOptions), CostOptions))
    args.settings = options_object(parser, args, env.preset(args.preset))
    args.max_steps = args.max_steps or env.criterion.max_steps
    try:
        args.model_options = args.model_options.resolved(env)
    except ValueError as error:
        parser.error(named_as_option(str(error), ModelOptions))
    args.planner = args.planner or env.planner
    args.env_description = env
    _load_inputs(args, env)
    return args


def _load_inputs(args: argparse.Namespace, env) -> None:
    """Read the checkpoint of ``--learned`` and each mesh file of ``--object`` once, before any
    trial: ``ValueError`` naming the option when one is not what it should be."""
    if args.model_options.learned is not None:
        try:
            load_learned(args.model_options.learned, args.env, args.robot, args.tips)
        except ValueError as error:
            raise ValueError(f"--learned: {error}") from None
    options = args.object_options
    for obj in sorted({obj for _, obj in args.pairs if mesh_file_of(obj) is not None}):
        try:
            loaded = load_object(
                mesh_file_of(obj), options.size, decomposition="hull", scale=options.scale
            )
            if options.pose == "stable":
                mesh_rest(loaded)
        except ValueError as error:
            raise ValueError(f"--object {obj!r} must be a usable mesh file: {error}") from None


def configs_of(args: argparse.Namespace) -> list[TrialConfig]:
    """The configuration of every selected trial: the options named as the fields of
    :class:`TrialConfig`, the solver settings and the selected pairs and seeds."""
    set_apart = {"env", "task", "object", "seed", "max_steps", "settings"}
    names = [f.name for f in dataclasses.fields(TrialConfig) if f.name not in set_apart]
    options = {name: getattr(args, name) for name in names if hasattr(args, name)}
    return trial_configs(
        args.env,
        args.pairs,
        range(args.first_seed, args.first_seed + args.trials),
        args.settings,
        args.max_steps,
        **options,
    )


def describe_objects(args: argparse.Namespace, at_most: int = 4) -> list[str]:
    """One line per object of the run (up to ``at_most``; a count beyond): the size, mass,
    friction and collision shape its plant uses, and what the environment derived for it."""
    env, objects = args.env_description, list(dict.fromkeys(obj for _, obj in args.pairs))
    lines = []
    for obj in objects[:at_most]:
        plant = env.make_plant(obj, args.collision, args.object_options)
        facts = object_facts(plant)
        extent = " × ".join(f"{100 * x:.1f}" for x in facts["object_extent"])
        lines.append(
            f"object {Path(obj).name}: {extent} cm, {1e3 * facts['object_mass_kg']:g} g, "
            f"friction {facts['object_friction_mu']:g}, collides as {facts['object_collision']}"
        )
        if mesh_file_of(obj) is not None:
            lines[-1] += f"; {describe_pose(obj, args.object_options, args.collision)}"
        lines += env.describe(plant)
    if len(objects) > at_most:
        lines.append(f"... and {len(objects) - at_most} more objects (each record stores its own)")
    return lines


def write_summary(args: argparse.Namespace, records: list[dict], out: Path) -> dict:
    """Summarize ``records`` overall and per pair, and write the summary, CSV and figure."""
    summary = report.summarize(records)
    model = args.model_options
    summary.update(model=model.model, relaxation=model.relaxation, learned=model.learned)
    # the preset's name only when no option overrode it
    unchanged = args.settings == args.env_description.preset(args.preset)
    summary["preset"] = args.preset if unchanged else None
    summary["settings"] = dataclasses.asdict(args.settings)
    summary["pairs"] = {
        f"{task} {obj}": report.summarize(
            [r for r in records if (r["task"], r["object"]) == (task, obj)]
        )
        for task, obj in args.pairs
    }
    json_file, csv_file, figure = (out / name for name in SUMMARY_FILES)
    write_json(json_file, summary)
    write_csv(csv_file, [report.csv_row(r) for r in records])
    report.plot_results(records, figure)
    if args.figure is not None:
        report.plot_results(records, args.figure)
    if args.json is not None:
        write_json(args.json, summary)
    return summary


def print_summary(summary: dict, pairs: list) -> None:
    """The per-pair table (several pairs) and the closing line of a sweep."""
    if len(pairs) > 1:
        print(
            f"{'pair':>30s} {'success':>8s} {'falls':>5s} {'pos [mm]':>9s} {'ang [°]':>8s} "
            f"{'solve ms':>9s}"
        )
        for pair, s in summary["pairs"].items():
            print(
                f"{pair:>30s} {100 * s['success_rate']:>7.0f}% {report.count(s['falls']):>5s} "
                f"{s['pos_err_mm_mean']:>9.1f} {s['angle_err_deg_mean']:>8.1f} "
                f"{report.ms(s['solve_ms_median']):>9s}"
            )
    print(
        f"success {100 * summary['success_rate']:.1f}% of {summary['trials']}, "
        f"falls {report.count(summary['falls'])}, tipped {report.count(summary['tipped'])} | "
        f"final position {summary['pos_err_mm_mean']:.1f} mm, "
        f"angle {summary['angle_err_deg_mean']:.1f}° (quat err {summary['quat_err_mean']:.4f}) | "
        f"{solve_line(summary)} | detect {summary['detect_ms_median']:.2f} ms, "
        f"sim {summary['sim_ms_median']:.2f} ms"
    )
    eager = summary.get("eager_steps")
    if eager:
        steps = "1 step was" if eager == 1 else f"{eager} steps were"
        print(
            f"({steps} planned eagerly while the MPC compiled, median "
            f"{summary['eager_solve_ms_median']:.1f} ms, p90 {summary['eager_solve_ms_p90']:.1f} "
            "ms: left out of the MPC's solve times)"
        )


def solve_line(summary: dict) -> str:
    """The summary's MPC solve times, or that no step was planned by the compiled MPC."""
    if summary["solve_ms_median"] is None:
        return "MPC solve: no step was compiled"
    return (
        f"MPC solve median {summary['solve_ms_median']:.1f} ms, p90 "
        f"{summary['solve_ms_p90']:.1f} ms ({summary['solve_steps']} steps)"
    )


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    torch.set_num_threads(1)
    args = parse_args(argv)
    configs = configs_of(args)
    out = Path("results") / configs[0].variant if args.out is None else args.out
    videos = [c for c in configs if c.seed == 0] if args.video else []
    writable_directory("--out", out)
    for name in SUMMARY_FILES:
        writable_file(f"--out's {name}", out / name)
    for option, path in (("--json", args.json), ("--figure", args.figure)):
        if path is not None:
            writable_file(option, path)
    planner = "" if args.planner == args.env_description.planner else f", planner {args.planner}"
    terms = configs[0].cost_options.describe()
    print(
        f"MPC through the {args.model_options.model} model "
        f"({args.model_options.describe(args.env)}); solver "
        f"{args.settings.label}{planner}{', ' + terms if terms else ''}"
    )
    for line in describe_objects(args):
        print(line)
    with locked_folder(out, "--out"):
        print(report.TABLE_HEADER)
        records = run_trials(
            configs,
            workers=args.workers,
            out=out,
            videos=videos,
            progress=not args.no_progress,
            on_record=lambda record, reused: tqdm.write(report.table_row(record.to_dict())),
            backend=args.backend,
            address=args.address,
        )
        summary = write_summary(args, [r.to_dict() for r in records], out)
    print_summary(summary, args.pairs)
    print(f"wrote {out}/summary.json, trials.csv, results.png")
    report_compiling()
    return 0
