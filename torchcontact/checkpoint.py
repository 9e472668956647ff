"""Saving and loading a complementarity-free model with the architecture that rebuilds it.

A checkpoint stores the model's ``state_dict`` beside the :class:`FitConfig` (which K and D
parameterizations, their sizes) and the dataset metadata (γ, facets, slots, nq, the paper's K)
that :func:`build_model` needs, so :func:`load_model` rebuilds the same module from the file
alone. Pure torch: the MPC loads a learned model without the learning package.
"""

from __future__ import annotations

import io
import math
import pickle
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

from torchcontact.calibration import OPTIONAL, PARTS, SystemCalibration
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

STIFFNESS_KINDS = ("constant", "per_row", "contact_network", "state_network", "object_network")
"""Learnable parameterizations of K: those of :mod:`torchcontact.stiffness` and
:class:`~torchcontact.networks.ObjectContactNetwork`."""

DAMPING_KINDS = ("paper", "none", "relative", *STIFFNESS_KINDS)
"""D: ``"paper"`` fixed 0.1·K, ``"none"``, ``"relative"`` a learned ratio·K, or its own
learnable parameterization (started at 0.1 × the initial K)."""

LOSS_CONTACTS = ("frozen", "geometry")
"""The contacts of a multi-step loss's later steps: ``"frozen"`` those recorded at the window's
first state, held (as the MPC plans); ``"geometry"`` re-evaluated at every predicted state by
the object's torch contact geometry (:func:`~torchcontact.sim.geometry.scene_geometry`)."""

CHECKPOINT_VERSION = 1


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
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"lr must be a positive finite number, got {self.lr!r}")
        if self.loss_contacts not in LOSS_CONTACTS:
            raise ValueError(
                f"loss_contacts must be one of {LOSS_CONTACTS}, got {self.loss_contacts!r}"
            )
        if self.loss_contacts == "geometry" and self.loss_horizon == 1:
            raise ValueError(
                "loss_contacts 'geometry' needs a loss_horizon above 1 (one step sees no new "
                "state), got loss_horizon 1"
            )


def _parameterization(kind: str, value: float, meta: dict, config: FitConfig) -> Parameterization:
    rows = meta["slots"] * meta["facets"]
    if kind == "constant":
        return Constant(value)
    if kind == "per_row":
        return PerRow(rows, value)
    if kind == "contact_network":
        return ContactNetwork(config.hidden, value, config.distance_scale)
    if kind == "state_network":
        return StateNetwork(meta["nq"], rows, hidden=config.hidden, value=value)
    return ObjectContactNetwork(meta["facets"], config.hidden, value, config.distance_scale)


def build_model(config: FitConfig, meta: dict) -> ComplementarityFree:
    """The scene's model (γ, facets of ``meta``) with the learnable K and D of ``config``, and
    its residual (unfitted: zero) when ``config.residual``."""
    torch.manual_seed(config.seed)
    value = config.initial_stiffness or meta["paper_stiffness"]
    stiffness = _parameterization(config.stiffness, value, meta, config)
    if config.damping == "paper":
        damping = Relative(0.1, learnable=False)
    elif config.damping == "relative":
        damping = Relative(0.1)
    elif config.damping == "none":
        damping = None
    else:
        damping = _parameterization(config.damping, 0.1 * value, meta, config)
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
    """Write ``model``'s ``state_dict`` with ``config`` and the dataset ``meta`` atomically."""
    payload = {
        "version": CHECKPOINT_VERSION,
        "config": asdict(config),
        "meta": meta,
        "state_dict": model.state_dict(),
    }
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    return atomic_write(path, lambda f: f.write(buffer.getvalue()), binary=True)


def load_checkpoint(path: str | Path) -> tuple[ComplementarityFree, FitConfig, dict]:
    """Rebuild the model saved by :func:`save_checkpoint`: ``(model, config, meta)``.

    Raises :class:`CheckpointError` naming the file when it is unreadable, not a checkpoint
    (only tensors and plain data are ever unpickled) or of another version.
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
        reason = f"{type(error).__name__}: {error}" if str(error) else type(error).__name__
        raise CheckpointError(f"{path}: not a readable checkpoint ({reason})") from None
    if not isinstance(payload, dict) or payload.get("version") != CHECKPOINT_VERSION:
        found = payload.get("version") if isinstance(payload, dict) else None
        raise CheckpointError(
            f"{path}: not a torchcontact checkpoint: expected version {CHECKPOINT_VERSION}, "
            f"found {found!r}"
        )
    try:
        config = FitConfig(**payload["config"])
        meta = payload["meta"]
        model = build_model(config, meta)
        state = payload["state_dict"]
        model = model.to(next(iter(state.values())).dtype)
        model.load_state_dict(state)
        broken = [
            key for key, x in state.items() if x.is_floating_point() and not x.isfinite().all()
        ]
    except (KeyError, TypeError, ValueError, RuntimeError, AttributeError, StopIteration) as error:
        raise CheckpointError(
            f"{path}: a damaged checkpoint: it does not rebuild its model ({error})"
        ) from None
    if broken:
        raise CheckpointError(
            f"{path}: a damaged checkpoint: its weights {broken[0]} hold NaN or Inf"
        )
    return model, config, meta


def _joints(joints: Sequence[str]) -> str:
    """``"free + 9 hinge"``: joint types and counts in order of first appearance."""
    counts = Counter(joints)
    return " + ".join(kind if n == 1 else f"{n} {kind}" for kind, n in counts.items()) or "none"


def check_fits(path: str | Path, meta: dict, env: str | None, joints: Sequence[str]) -> None:
    """Refuse, with :class:`CheckpointError` naming the file, a checkpoint (its ``meta``)
    learned in another environment than ``env`` (None: any, for a user's robot) or on states
    of other ``joints`` than the MPC's (its state layout)."""
    scene = meta.get("scene")
    if env is not None and scene != env:
        raise CheckpointError(
            f"{path}: a checkpoint learned in the {scene!r} environment, not {env!r}: plan "
            f"{env} with a model learned there (learn-k --scene {env})"
        )
    learned = list(meta.get("joints") or ())
    if learned != list(joints):
        raise CheckpointError(
            f"{path}: learned on states of joints {_joints(learned)}, but this scene's are "
            f"{_joints(joints)}: learn a model on this scene"
        )


def load_model(path: str | Path) -> ComplementarityFree:
    """The model of the checkpoint at ``path`` (see :func:`load_checkpoint`)."""
    return load_checkpoint(path)[0]
