"""``torchcontact learn-k``'s settings: the command line, checked and resolved per scene, as one
frozen :class:`LearnConfig` that the pipeline (:mod:`torchcontact.cli.learn_k`) reads.

The fields are the options by their names, plus what they resolve to (``objects``, ``grid``,
``results``); the fit's options are one :class:`~torchcontact.checkpoint.FitConfig`. A split's
saved record is found by a digest of these values as they are
(:func:`torchcontact.cli.learn_k.deciding_options`), so a field renamed or a value retyped
(``sweep``'s ``16`` as ``16.0``) would leave every saved split unused.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import re
from dataclasses import dataclass, fields
from pathlib import Path

import torch

from torchcontact.calibration import MOMENTUM, OPTIONAL, PARTS
from torchcontact.checkpoint import DAMPING_KINDS, LOSS_CONTACTS, STIFFNESS_KINDS, FitConfig
from torchcontact.cli import Parser
from torchcontact.environments import environment
from torchcontact.learn.evaluate import log_grid
from torchcontact.learn.policies import ACTIONS
from torchcontact.learn.scenes import BOX_PUSHING, SCENES
from torchcontact.object_sources import mesh_file_of
from torchcontact.parallel import BACKENDS, RAY_EXTRA, check_backend
from torchcontact.shapes import load_object

DEFAULT_STEPS = {"fingertips": 120, "trifinger": 50, "allegro": 50, "box_pushing": 100}
"""Steps per trajectory by scene: the fingertips start 0.2 m from the object."""

DEFAULT_OBJECTS = {
    "trifinger": "all,random:0-99",
    "allegro": "all,random:0-29",
    "fingertips": "cube,stick,bunny",
}
"""Objects by scene (``cube`` for box pushing): the hands' built-in ones and 30 generated
tuning objects (seeds below 1000, so the reported generated objects stay unseen); the
fingertips' objects whose model shares h = 0.1 s (the foam brick's has 0.05 s)."""

DEFAULT_CALIBRATE = {
    "trifinger": PARTS + (MOMENTUM,),
    "allegro": tuple(part for part in PARTS if part != "friction"),
}
"""The system factors fitted by default, by scene: the four parts (measured best with μ,
docs/experiments.md); on the TriFinger the object's momentum too (measured there: its objects
tip); on the Allegro all but μ (a fitted μ of 2.9 doubled its falls in closed loop, and no
later Allegro fit used it: docs/experiments.md, "why the learned Allegro model drops
objects")."""

ABLATIONS = {
    "calibrated_constant_k": {"stiffness": "constant", "damping": "paper"},
    "uncalibrated_learned": {"calibrate": ()},
}
"""``--ablate``'s extra fits per split: the best constant K with the system factors fitted, and
the learned K(q), D(q) without them (each otherwise as the learned model)."""

RESULTS_LABEL_LIMIT = 80
"""The longest ``--object`` label a results folder's name takes whole (a file name holds 255
bytes); a longer one is cut and given a digest of the whole spec, so it stays unique."""

_POSITIVE = ("hidden", "epochs", "batch_size", "patience", "horizon", "stride", "workers")
_POSITIVE += ("trajectories", "steps", "splits", "loss_horizon")
"""The integer options that must be at least 1."""

_FIT_OPTIONS = tuple(field.name for field in fields(FitConfig) if field.name != "initial_stiffness")
"""The options that are :class:`FitConfig` fields (its initial K is the sweep's, per split)."""


@dataclass(frozen=True)
class LearnConfig:
    """What ``torchcontact learn-k`` collects, fits, judges and writes."""

    scene: str
    """The scene the data come from, one of :data:`~torchcontact.learn.scenes.SCENES`."""
    object: str
    """``--object`` as given, or the scene's default (:data:`DEFAULT_OBJECTS`)."""
    objects: tuple[str, ...]
    """The objects ``object`` names, each once, in order."""
    task: str | None
    """The suite task whose sampler starts each trajectory; None: the scene's."""
    trajectories: int
    """Trajectories per object."""
    steps: int
    """Steps per trajectory (:data:`DEFAULT_STEPS` by scene)."""
    actions: str
    """The action source, one of :data:`~torchcontact.learn.policies.ACTIONS`."""
    noise: float | None
    """Exploration noise, a fraction of the control bound; None: the collector's."""
    seed: int
    """The data's seed, and the first split's (split i has ``seed + i``)."""
    no_compile: bool
    """Plan eagerly while collecting."""
    workers: int
    """Collection processes (or Ray CPUs), and splits fitted at a time."""
    backend: str
    """Where collection runs, one of :data:`~torchcontact.parallel.BACKENDS`."""
    address: str | None
    """A running Ray cluster's address."""
    split: str
    """What a split holds out: ``"objects"`` (3+ objects) or ``"trajectories"``."""
    splits: int
    """Random splits, each fitted and judged."""
    fit: FitConfig
    """The fit's settings, with ``seed`` and the paper's K: each split replaces them with its
    own seed and its best constant K."""
    gamma: float | None
    """Softplus sharpness γ of the fitted and compared models; None: the scene's."""
    device: str
    """Where the fit runs: ``"cpu"``, ``"cuda"`` or ``"cuda:N"``."""
    sweep: tuple[float, float, float]
    """``--sweep`` as given: LOW and HIGH K [N/m] and the count N of the constant-K grid."""
    grid: tuple[float, ...]
    """The constant Ks swept [N/m]: N log-spaced from LOW to HIGH."""
    horizon: int
    """Steps of each evaluation rollout."""
    stride: int
    """Steps between the starts of evaluation rollouts."""
    ablate: bool
    """Also fit and evaluate each of :data:`ABLATIONS` on every split."""
    out: Path
    """The folder of the results."""
    results: Path
    """This run's results folder: ``out/SCENE_OBJECTS``."""
    data: Path
    """The folder of the datasets (default ``out/data``)."""
    json: Path | None
    """Where the headline figures go; None: nowhere."""
    ship: bool
    """Also install the first split's model as the scene's shipped default."""
    no_progress: bool
    """Show no progress bars."""

    @classmethod
    def from_args(cls, parser: argparse.ArgumentParser, args: argparse.Namespace) -> LearnConfig:
        """The settings of the parsed ``args`` with the scene's defaults; a bad value ends the
        parse with ``parser.error`` naming its option."""
        _check_numbers(parser, args)
        fit = _fit_config(parser, args)
        spec, objects = _objects(parser, args)
        steps = DEFAULT_STEPS[args.scene] if args.steps is None else args.steps
        actions = args.actions
        if actions is None:
            actions = "random" if args.scene == BOX_PUSHING else "mpc"
        elif args.scene == BOX_PUSHING and actions != "random":
            parser.error(f"--actions must be random for box_pushing (no MPC task), got {actions}")
        longest = max(args.horizon, args.loss_horizon)
        if steps <= longest:
            parser.error(
                f"--steps must exceed --horizon and --loss-horizon ({longest}), got {steps}"
            )
        split = _split(parser, args, objects)
        low, high, count = args.sweep
        if not (0 < low < high < math.inf) or count < 2 or count != int(count):
            parser.error(
                f"--sweep needs finite 0 < LOW < HIGH and an integer N >= 2, got {args.sweep}"
            )
        return cls(
            scene=args.scene,
            object=spec,
            objects=objects,
            task=args.task,
            trajectories=args.trajectories,
            steps=steps,
            actions=actions,
            noise=args.noise,
            seed=args.seed,
            no_compile=args.no_compile,
            workers=args.workers,
            backend=args.backend,
            address=args.address,
            split=split,
            splits=args.splits,
            fit=fit,
            gamma=args.gamma,
            device=args.device,
            sweep=tuple(args.sweep),
            grid=tuple(log_grid(low, high, int(count))),
            horizon=args.horizon,
            stride=args.stride,
            ablate=args.ablate,
            out=args.out,
            results=args.out / f"{args.scene}_{results_label(spec, objects)}",
            data=args.out / "data" if args.data is None else args.data,
            json=args.json,
            ship=args.ship,
            no_progress=args.no_progress,
        )


def parse_config(argv: list[str] | None) -> LearnConfig:
    """``learn-k``'s settings from its command line ``argv`` (None: ``sys.argv``)."""
    parser = build_parser()
    return LearnConfig.from_args(parser, parser.parse_args(argv))


def build_parser() -> Parser:
    """``learn-k``'s options."""
    parser = Parser(
        prog="torchcontact learn-k",
        description="Learn the contact model K(q), D(q) and the system's factors from MuJoCo "
        "rollouts of many objects; judge it on held-out objects.",
    )
    add = parser.add_argument
    add("--scene", choices=SCENES, default="trifinger")
    add(
        "--object",
        default=None,
        help="objects, comma-separated: names, 'all' (the built-in ones), random-SEED, "
        f"random:A-B (tune on seeds < 1000) or mesh files (default {DEFAULT_OBJECTS}, else all)",
    )
    add("--task", default=None, help="the suite task whose sampler starts each trajectory")
    add(
        "--trajectories",
        type=int,
        default=20,
        help="trajectories per object (collected if missing)",
    )
    add("--steps", type=int, default=None, help=f"steps per trajectory (default {DEFAULT_STEPS})")
    add(
        "--actions",
        choices=ACTIONS,
        default=None,
        help="action source (default mpc; random for box_pushing, which has no MPC task)",
    )
    add("--noise", type=float, default=None, help="exploration noise, fraction of the bound")
    add("--no-compile", action="store_true", help="eager MPC while collecting")
    add(
        "--workers",
        type=int,
        default=1,
        help="parallel collection processes (or Ray CPUs), and splits fitted at a time (local "
        "processes)",
    )
    add("--backend", choices=BACKENDS, default="local", help=f"local or Ray ({RAY_EXTRA})")
    add("--address", default=None, help="(ray) a running cluster's address")
    add("--data", type=Path, default=None, help="folder of the datasets (default OUT/data)")
    add(
        "--split",
        choices=("objects", "trajectories"),
        default=None,
        help="hold out whole objects (default, 3+ objects) or trajectories (one object)",
    )
    add("--splits", type=int, default=5, help="random splits, each fitted and judged")
    add("--stiffness", choices=STIFFNESS_KINDS, default="contact_network", help="K(q)")
    add("--damping", choices=DAMPING_KINDS, default="contact_network", help="D(q)")
    add(
        "--calibrate",
        default=None,
        help=f"system factors fitted with K and D, comma-separated from {PARTS + OPTIONAL}, "
        f"or 'none' (default {','.join(PARTS)}, with {MOMENTUM} on the TriFinger and "
        "without friction on the Allegro)",
    )
    add("--loss-horizon", type=int, default=1, help="steps of the training loss's rollouts")
    add(
        "--loss-contacts",
        choices=LOSS_CONTACTS,
        default="frozen",
        help="contacts of the loss's steps after a window's first: frozen (those recorded at "
        "its first state, as the MPC plans; default) or geometry (each object's torch contact "
        "geometry at every predicted state; needs --loss-horizon 2 or more)",
    )
    add(
        "--residual",
        type=int,
        default=0,
        metavar="H",
        help="fit an object residual of H hidden units after K, D and the factors "
        "(torchcontact.residual): better prediction; the MPC plans with it, but on the Allegro "
        "it planned worse (README); 0: none (default)",
    )
    add(
        "--robot-weight",
        type=float,
        default=1.0,
        help="weight of the robot's coordinates' squared error in the loss [1/rad² or 1/m²]",
    )
    add(
        "--gamma",
        type=float,
        default=None,
        help="softplus sharpness γ of the fitted and compared models (default the scene's, "
        "as its MPC plans)",
    )
    add("--hidden", type=int, default=32, help="hidden units of the networks")
    add("--distance-scale", type=float, default=1e-4, help="φ feature scale [m]")
    add("--epochs", type=int, default=300)
    add("--batch-size", type=int, default=512)
    add("--lr", type=float, default=3e-3)
    add("--patience", type=int, default=40, help="early stopping patience [epochs]")
    add("--device", default="cpu", help="where the fit runs: cpu or cuda")
    add(
        "--sweep",
        type=float,
        nargs=3,
        default=(1e-3, 1e2, 16),
        metavar=("LOW", "HIGH", "N"),
        help="constant-K grid: N log-spaced values",
    )
    add("--horizon", type=int, default=10, help="rollout steps of the evaluation")
    add("--stride", type=int, default=5, help="a rollout starts every STRIDE steps")
    add("--seed", type=int, default=0, help="data seed and the first split's seed")
    add("--out", type=Path, default=Path("results/learn"))
    add("--json", type=Path, default=None, help="write the headline figures here")
    add(
        "--ship",
        action="store_true",
        help="also install the first split's model as the scene's shipped default, with its "
        "manifest (torchcontact/assets/models/SCENE.pt and .json)",
    )
    add(
        "--ablate",
        action="store_true",
        help=f"also fit and evaluate {tuple(ABLATIONS)} on each split (two more fits)",
    )
    add("--no-progress", action="store_true")
    return parser


def results_label(spec: str, objects: tuple[str, ...]) -> str:
    """The results folder's label for ``--object spec`` (expanded to ``objects``): a lone
    object's file stem, or the spec with its separators as ``_``, cut to
    :data:`RESULTS_LABEL_LIMIT` characters plus a digest of ``spec`` when longer."""
    label = Path(spec).stem if len(objects) == 1 else re.sub(r"[,:/]", "_", spec)
    if len(label) <= RESULTS_LABEL_LIMIT:
        return label
    digest = hashlib.sha256(spec.encode()).hexdigest()[:12]
    return f"{label[: RESULTS_LABEL_LIMIT - len(digest) - 1]}_{digest}"


def _check_numbers(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """The counts, seeds, scales, noise, parallelism and device, each on its own."""
    for name in _POSITIVE:
        if getattr(args, name) is not None and getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    try:
        check_backend(args.workers, args.backend, args.address)
    except (ValueError, ImportError) as error:
        parser.error(f"--backend/--address/--workers: {error}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    for name in ("distance_scale", "gamma"):  # gamma None: the scene's
        value = getattr(args, name)
        if value is not None and not 0 < value < math.inf:
            parser.error(f"--{name.replace('_', '-')} must be positive and finite, got {value}")
    if args.noise is not None and not 0 <= args.noise < math.inf:
        parser.error(
            f"--noise must be a non-negative finite fraction of the control bound, got {args.noise}"
        )
    if args.device not in ("cpu", "cuda") and not args.device.startswith("cuda:"):
        parser.error(f"--device must be cpu or cuda, got {args.device!r}")
    if args.device != "cpu" and not torch.cuda.is_available():
        parser.error(f"--device {args.device}: this machine has no CUDA device")


def _fit_config(parser: argparse.ArgumentParser, args: argparse.Namespace) -> FitConfig:
    """The fit's options as a :class:`FitConfig`, ``--calibrate`` defaulted by scene; its
    refusal names the option."""
    if args.calibrate is None:
        calibrate = DEFAULT_CALIBRATE.get(args.scene, PARTS)
    else:
        calibrate = () if args.calibrate == "none" else tuple(args.calibrate.split(","))
    if args.loss_contacts == "geometry" and args.loss_horizon == 1:
        parser.error(
            "--loss-contacts geometry needs --loss-horizon 2 or more: one step sees no new state"
        )
    given = {name: getattr(args, name) for name in _FIT_OPTIONS if name != "calibrate"}
    try:
        return FitConfig(**given, calibrate=calibrate)
    except ValueError as error:
        field, _, rest = str(error).partition(" ")
        parser.error(f"--{field.replace('_', '-')} {rest}")


def _objects(
    parser: argparse.ArgumentParser, args: argparse.Namespace
) -> tuple[str, tuple[str, ...]]:
    """``--object`` (defaulted by scene) against the scene and ``--task`` (as
    :func:`~torchcontact.learn.scenes.make_scene` checks them) and the object names it
    gives, each once, in order; each mesh file is read once here, before anything runs."""
    if args.scene == BOX_PUSHING:
        spec = args.object or "cube"
        if spec != "cube" or args.task not in (None, "push"):
            parser.error(
                f"--object and --task of box_pushing are cube and push only, got "
                f"{spec!r}, {args.task!r}"
            )
        return spec, ("cube",)
    env = environment(args.scene)
    spec = DEFAULT_OBJECTS.get(args.scene, "all") if args.object is None else args.object
    objects = []
    for piece in spec.split(","):
        try:
            pairs = env.select(args.task or "all", piece)
        except ValueError as error:
            parser.error(str(error))
        objects += [obj for _, obj in pairs]
    objects = tuple(dict.fromkeys(objects))
    for obj in objects:
        path = mesh_file_of(obj)
        if path is not None:
            try:
                load_object(path, decomposition="hull")
            except ValueError as error:
                parser.error(f"--object {obj!r} must be a usable mesh file: {error}")
    return spec, objects


def _split(parser: argparse.ArgumentParser, args: argparse.Namespace, objects: tuple) -> str:
    """``--split`` (by default ``objects`` for 3+ objects) against the objects and
    trajectories."""
    split = args.split
    if split is None:
        split = "objects" if len(objects) >= 3 else "trajectories"
    if split == "objects" and len(objects) < 3:
        parser.error(
            f"--split objects needs 3 or more objects (train, val, test), got {list(objects)}; "
            "use --split trajectories"
        )
    if split == "trajectories" and args.trajectories * len(objects) < 3:
        parser.error(
            f"--trajectories must give 3 or more trajectories (train, val, test), got "
            f"{args.trajectories}"
        )
    return split
