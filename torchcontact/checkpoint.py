"""Saving and loading a complementarity-free model with the architecture that rebuilds it.

A checkpoint stores the model's ``state_dict`` beside the :class:`FitConfig` (which K and D
parameterizations, their sizes) and the dataset metadata (γ, facets, slots, nq, the paper's K)
that :func:`build_model` needs, so :func:`load_model` rebuilds the same module from the file
alone. Pure torch: the MPC loads a learned model without the learning package.
"""

from __future__ import annotations

import datetime
import importlib.metadata
import io
import json
import math
import pickle
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol

import torch

from torchcontact.calibration import OPTIONAL, PARTS, SystemCalibration
from torchcontact.digests import file_sha256
from torchcontact.integrate import object_indices
from torchcontact.model import ComplementarityFree
from torchcontact.networks import ObjectContactNetwork
from torchcontact.residual import ObjectResidual
from torchcontact.results import atomic_write
from torchcontact.stiffness import (
    Constant,
    ContactNetwork,
    Parameterization,
    PerRow,
    Relative,
    StateNetwork,
)
from torchcontact.validation import is_finite_number


def _rows(meta: dict) -> int:
    """Rows of K per step: slots × facets."""
    return meta["slots"] * meta["facets"]


Factory = Callable[[float, dict, "FitConfig"], Parameterization]
"""``(value, meta, config) ↦`` a learnable parameterization started at ``value`` everywhere."""

PARAMETERIZATIONS: dict[str, Factory] = {
    "constant": lambda value, meta, config: Constant(value),
    "per_row": lambda value, meta, config: PerRow(_rows(meta), value),
    "contact_network": lambda value, meta, config: ContactNetwork(
        config.hidden, value, config.distance_scale
    ),
    "state_network": lambda value, meta, config: StateNetwork(
        meta["nq"], _rows(meta), hidden=config.hidden, value=value
    ),
    "object_network": lambda value, meta, config: ObjectContactNetwork(
        meta["facets"], config.hidden, value, config.distance_scale
    ),
}
"""The learnable parameterizations of K (and of D) by name: those of
:mod:`torchcontact.stiffness` and :class:`~torchcontact.networks.ObjectContactNetwork`."""

STIFFNESS_KINDS = tuple(PARAMETERIZATIONS)
"""The names of :data:`PARAMETERIZATIONS`."""

DAMPING_KINDS = ("paper", "none", "relative", *STIFFNESS_KINDS)
"""D: ``"paper"`` fixed 0.1·K, ``"none"``, ``"relative"`` a learned ratio·K, or its own
learnable parameterization (started at 0.1 × the initial K)."""

LOSS_CONTACTS = ("frozen", "geometry")
"""The contacts of a multi-step loss's later steps: ``"frozen"`` those recorded at the window's
first state, held (as the MPC plans); ``"geometry"`` re-evaluated at every predicted state by
the object's torch contact geometry (:func:`~torchcontact.sim.geometry.scene_geometry`)."""

CHECKPOINT_VERSION = 1

META_KEYS = ("gamma", "facets", "slots", "nq", "nv", "nu", "joints", "paper_stiffness")
"""What :func:`build_model` reads from a dataset's ``meta``: γ, facets n_d, contact slots nc,
nq, nv, nu, the joint types of q (its state layout) and the K [N/m] a model starts at when
its config names none."""


class CheckpointError(ValueError):
    """A file is not a torchcontact checkpoint, or not one this version can rebuild."""


@dataclass(frozen=True)
class FitConfig:
    """What to fit and how.

    Attributes:
        stiffness: parameterization of K, one of :data:`STIFFNESS_KINDS`.
        damping: parameterization of D, one of :data:`DAMPING_KINDS`.
        initial_stiffness: K everywhere at the start [N/m per row]; None: the paper's K.
        hidden: hidden units of the network parameterizations.
        distance_scale: φ scale [m] of the contact-network features (φ/scale, clamped to ±10).
        epochs: at most this many passes over the training set.
        batch_size: transitions per Adam step.
        lr: Adam's learning rate.
        patience: stop after this many epochs without a better validation loss.
        seed: seed of the initialization and the batch order.
        calibrate: the system factors fitted with K and D (a subset of
            :data:`~torchcontact.calibration.PARTS` and ``OPTIONAL``); empty: none, the model has no
            calibration.
        loss_horizon: steps of the training loss: 1 the one-step pose error, H > 1 the mean
            pose error over H steps rolled out with the contacts of ``loss_contacts`` (by
            default frozen at the window's first state, as the MPC plans).
        robot_weight: weight of the robot's coordinates' squared error in the loss [1/m² or
            1/rad²]; 0: the objects' pose error only (the robot's stiffness factor then has no
            gradient: unopposed, the command gain alone moves the robot).
        residual: hidden units of an object residual fitted after K, D and the factors; 0:
            none.
        loss_contacts: the contacts of the loss's steps after a window's first, one of
            :data:`LOSS_CONTACTS`: ``"frozen"`` (the window's first, held) or ``"geometry"``
            (each object's geometry at every predicted state; needs ``loss_horizon`` > 1:
            one step sees no new state). A checkpoint saved before the field loads as
            ``"frozen"``, the only loss there was.
    """

    stiffness: str = "contact_network"
    damping: str = "relative"
    initial_stiffness: float | None = None
    hidden: int = 32
    distance_scale: float = 0.01
    epochs: int = 200
    batch_size: int = 512
    lr: float = 1e-2
    patience: int = 20
    seed: int = 0
    calibrate: tuple[str, ...] = ()
    loss_horizon: int = 1
    robot_weight: float = 0.0
    residual: int = 0
    loss_contacts: str = "frozen"

    def __post_init__(self) -> None:
        if self.stiffness not in STIFFNESS_KINDS:
            raise ValueError(f"stiffness must be one of {STIFFNESS_KINDS}, got {self.stiffness!r}")
        if self.damping not in DAMPING_KINDS:
            raise ValueError(f"damping must be one of {DAMPING_KINDS}, got {self.damping!r}")
        if self.initial_stiffness is not None and not (
            math.isfinite(self.initial_stiffness) and self.initial_stiffness > 0
        ):
            raise ValueError(f"initial_stiffness must be positive, got {self.initial_stiffness!r}")
        object.__setattr__(self, "calibrate", tuple(self.calibrate))
        unknown = [part for part in self.calibrate if part not in PARTS + OPTIONAL]
        if unknown or len(set(self.calibrate)) != len(self.calibrate):
            raise ValueError(
                f"calibrate must name distinct factors of {PARTS + OPTIONAL}, got {self.calibrate}"
            )
        for name in ("hidden", "epochs", "batch_size", "patience", "loss_horizon"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        residual = self.residual
        if isinstance(residual, bool) or not isinstance(residual, int) or residual < 0:
            raise ValueError(f"residual must be a non-negative integer, got {self.residual!r}")
        if not (math.isfinite(self.robot_weight) and self.robot_weight >= 0):
            raise ValueError(
                f"robot_weight must be non-negative and finite, got {self.robot_weight!r}"
            )
        for name in ("lr", "distance_scale"):
            value = getattr(self, name)
            if not (is_finite_number(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        seed = self.seed
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        if self.loss_contacts not in LOSS_CONTACTS:
            raise ValueError(
                f"loss_contacts must be one of {LOSS_CONTACTS}, got {self.loss_contacts!r}"
            )
        if self.loss_contacts == "geometry" and self.loss_horizon == 1:
            raise ValueError(
                "loss_contacts 'geometry' needs a loss_horizon above 1 (one step sees no new "
                "state), got loss_horizon 1"
            )


def _check_types(config, meta) -> None:
    """``TypeError`` naming ``config`` or ``meta`` when it is not a FitConfig or a dict, and
    ``ValueError`` naming the keys of :data:`META_KEYS` that ``meta`` lacks."""
    if not isinstance(config, FitConfig):
        raise TypeError(f"config must be a FitConfig, got {type(config).__name__}")
    if not isinstance(meta, dict):
        raise TypeError(f"meta must be a dict (a dataset's meta), got {type(meta).__name__}")
    missing = [key for key in META_KEYS if key not in meta]
    if missing:
        raise ValueError(
            f"meta must hold {', '.join(META_KEYS)} (what rebuilds the model); it lacks "
            f"{', '.join(missing)}"
        )


def build_model(config: FitConfig, meta: dict) -> ComplementarityFree:
    """The scene's model (γ, facets of ``meta``) with the learnable K and D of ``config``, and
    its residual (unfitted: zero) when ``config.residual``.

    ``meta`` holds at least :data:`META_KEYS`; ``TypeError`` or ``ValueError`` naming the
    argument otherwise. Seeds torch's global generator with ``config.seed``."""
    _check_types(config, meta)
    torch.manual_seed(config.seed)
    value = config.initial_stiffness or meta["paper_stiffness"]
    stiffness = PARAMETERIZATIONS[config.stiffness](value, meta, config)
    if config.damping == "paper":
        damping = Relative(0.1, learnable=False)
    elif config.damping == "relative":
        damping = Relative(0.1)
    elif config.damping == "none":
        damping = None
    else:
        damping = PARAMETERIZATIONS[config.damping](0.1 * value, meta, config)
    calibration = SystemCalibration(meta["nu"], config.calibrate) if config.calibrate else None
    residual = None
    if config.residual:
        residual = ObjectResidual(
            *object_indices(meta["joints"]), meta["nq"], meta["nv"], hidden=config.residual
        )
    return ComplementarityFree(
        stiffness,
        damping,
        gamma=meta["gamma"],
        facets=meta["facets"],
        calibration=calibration,
        residual=residual,
    )


def constant_model(stiffness: float, meta: dict) -> ComplementarityFree:
    """The paper's model of the scene at constant K = ``stiffness``: D = 0.1·K, fixed."""
    return ComplementarityFree(
        Constant(stiffness, learnable=False, name="stiffness"),
        Relative(0.1, learnable=False),
        gamma=meta["gamma"],
        facets=meta["facets"],
    )


def save_checkpoint(path: str | Path, model: ComplementarityFree, config: FitConfig, meta: dict):
    """Write ``model``'s ``state_dict`` with ``config`` and the dataset ``meta`` atomically.

    ``TypeError`` naming the argument that is not a ComplementarityFree, a FitConfig or a
    dict; ``ValueError`` when ``meta`` lacks a key of :data:`META_KEYS` or ``model`` is not
    the architecture ``config`` and ``meta`` rebuild (:func:`build_model`), so that every file
    written loads."""
    if not isinstance(model, ComplementarityFree):
        raise TypeError(f"model must be a ComplementarityFree, got {type(model).__name__}")
    _check_types(config, meta)
    with torch.random.fork_rng(devices=[]):  # build_model seeds the global generator
        rebuilt = build_model(config, meta).to(_dtype(model.state_dict()))
    try:
        rebuilt.load_state_dict(model.state_dict())
    except RuntimeError as error:
        raise ValueError(
            f"model is not the architecture config and meta describe ({_first_line(error)}): "
            "build it with build_model(config, meta)"
        ) from None
    payload = {
        "version": CHECKPOINT_VERSION,
        "config": asdict(config),
        "meta": meta,
        "state_dict": model.state_dict(),
    }
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    return atomic_write(path, lambda f: f.write(buffer.getvalue()), binary=True)


def _dtype(state: dict) -> torch.dtype:
    """The dtype of a state dict's first floating tensor (float32 when it holds none)."""
    return next((x.dtype for x in state.values() if x.is_floating_point()), torch.float32)


def _first_line(error: Exception) -> str:
    """``error``'s message in one line: torch's state-dict errors list one mismatch a line;
    the first is named, with how many more there are."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    if len(lines) > 1 and lines[0].startswith("Error(s) in loading state_dict"):
        lines = lines[1:]  # the header names only the class
    more = f" and {len(lines) - 1} more" if len(lines) > 1 else ""
    return (lines[0].rstrip(".") if lines else type(error).__name__) + more


def load_checkpoint(path: str | Path) -> tuple[ComplementarityFree, FitConfig, dict]:
    """Rebuild the model saved by :func:`save_checkpoint`: ``(model, config, meta)``.

    Raises :class:`CheckpointError` in one line naming the file when it is unreadable, not a
    checkpoint (only tensors and plain data are ever unpickled), of another version, or does
    not rebuild its model (a meta without its state layout, weights of other sizes).
    """
    path = Path(path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise CheckpointError(
            f"{path}: not a torchcontact checkpoint (expected the model.pt of learn-k)"
        ) from None
    except IsADirectoryError:
        raise CheckpointError(f"{path}: a directory, not a checkpoint file") from None
    except Exception as error:  # whatever torch's loader raises on bytes that are no checkpoint
        raise CheckpointError(f"{path}: not a readable checkpoint ({_reason(error)})") from None
    if not isinstance(payload, dict) or payload.get("version") != CHECKPOINT_VERSION:
        found = payload.get("version") if isinstance(payload, dict) else None
        raise CheckpointError(
            f"{path}: not a torchcontact checkpoint: expected version {CHECKPOINT_VERSION}, "
            f"found {found!r}"
        )
    meta = payload.get("meta")
    if not isinstance(meta, dict) or not meta.get("joints"):
        raise CheckpointError(
            f"{path}: a damaged checkpoint: its meta records no joints (the state layout it "
            "was learned on)"
        )
    try:
        config = FitConfig(**payload["config"])
        model = build_model(config, meta)
        state = payload["state_dict"]
        model = model.to(_dtype(state))
        model.load_state_dict(state)
        broken = [
            key for key, x in state.items() if x.is_floating_point() and not x.isfinite().all()
        ]
    except (KeyError, TypeError, ValueError, RuntimeError, AttributeError, StopIteration) as error:
        raise CheckpointError(
            f"{path}: a damaged checkpoint: it does not rebuild its model ({_reason(error)})"
        ) from None
    if broken:
        raise CheckpointError(
            f"{path}: a damaged checkpoint: its weights {broken[0]} hold NaN or Inf"
        )
    return model, config, meta


def _reason(error: Exception) -> str:
    """``"Type: message"`` of ``error`` in one line (:func:`_first_line`)."""
    if not str(error):
        return type(error).__name__
    message = _first_line(error) if isinstance(error, RuntimeError) else str(error)
    return f"{type(error).__name__}: {' '.join(message.split())}"


def _joints(joints: Sequence[str]) -> str:
    """``"free + 9 hinge"``: joint types and counts in order of first appearance."""
    counts = Counter(joints)
    return " + ".join(kind if n == 1 else f"{n} {kind}" for kind, n in counts.items()) or "none"


def _where(scene: str | None) -> str:
    """Where a checkpoint was learned, for messages: an environment's name or a user's robot."""
    return "on a user's robot" if scene is None else f"in the {scene!r} environment"


def check_fits(path: str | Path, meta: dict, env: str | None, joints: Sequence[str]) -> None:
    """Refuse, with :class:`CheckpointError` in one line naming the file and both sides, a
    checkpoint (its ``meta``) learned in another environment than ``env`` (None: a user's
    robot, which takes a checkpoint saved for a user's robot, ``meta["scene"]`` None) or on
    states of other ``joints`` than the MPC's (its state layout)."""
    scene = meta.get("scene")
    learned = list(meta.get("joints") or ())
    if scene != env and env is not None:
        raise CheckpointError(
            f"{path}: a checkpoint learned {_where(scene)}, not {env!r}: plan {env} with a "
            f"model learned there (learn-k --scene {env})"
        )
    if scene != env:
        raise CheckpointError(
            f"{path}: a checkpoint learned {_where(scene)} on states of joints "
            f"{_joints(learned)}, not for this robot (joints {_joints(joints)}): fit a model on "
            "its transitions (learn.fit.fit, then save_model)"
        )
    if learned != list(joints):
        raise CheckpointError(
            f"{path}: learned on states of joints {_joints(learned)}, but this scene's are "
            f"{_joints(joints)} (learned {_where(scene)}): learn a model on "
            "this scene"
        )


def load_model(path: str | Path) -> ComplementarityFree:
    """The model of the checkpoint at ``path`` (see :func:`load_checkpoint`), as
    :func:`save_model` or ``learn-k`` wrote it."""
    return load_checkpoint(path)[0]


class Fitted(Protocol):
    """What :func:`save_model` saves: a :class:`~torchcontact.learn.fit.FitResult`."""

    model: ComplementarityFree
    config: FitConfig
    meta: dict
    manifest: dict


def save_model(path: str | Path, fitted: Fitted) -> Path:
    """Write the fitted model of :func:`torchcontact.learn.fit.fit` at ``path`` (a
    :func:`save_checkpoint` file that :func:`load_model` and ``torchcontact run ENV --learned
    PATH`` read), and its manifest beside it, ``path`` with the suffix ``.json``: the fit's
    own record (data size, settings, validation figures), the library versions, the date and
    the file's SHA-256.

    The checkpoint is for the environment ``fitted.meta["scene"]`` (``fit(..., scene=ENV)``),
    or, when None, for a user's robot (``run custom --robot ...``). ``TypeError`` naming
    ``fitted`` when it is not a fit's result. Returns the checkpoint's path."""
    missing = [
        name for name in ("model", "config", "meta", "manifest") if not hasattr(fitted, name)
    ]
    if missing:
        raise TypeError(
            f"fitted must be the result of torchcontact.learn.fit.fit (a FitResult), got "
            f"{type(fitted).__name__} without {', '.join(missing)}"
        )
    path = Path(path)
    save_checkpoint(path, fitted.model, fitted.config, fitted.meta)
    manifest = {
        "environment": fitted.meta.get("scene"),
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "sha256": file_sha256(path),
        **fitted.manifest,
        "versions": library_versions(),
    }
    text = json.dumps(manifest, indent=2, sort_keys=False) + "\n"
    atomic_write(path.with_suffix(".json"), lambda f: f.write(text))
    return path


def library_versions() -> dict[str, str]:
    """The installed versions of torchcontact, torch and MuJoCo (``"unknown"`` for one that
    is not installed as a distribution), read without importing them."""
    versions = {}
    for name in ("torchcontact", "torch", "mujoco"):
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "unknown"
    return versions
