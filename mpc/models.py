"""The contact models an MPC plans through, by name, and the one it plans through by default.

A trial, ``torchcontact run --model NAME`` and ``ContactImplicitMPC.from_env`` look a model up
here: what it takes (a constant K, a relaxation κ) and whether its plan may move its contacts
are fields of its :class:`MPCModel`, so no layer above tests its name.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from torchcontact.environments import environment
from torchcontact.environments.base import Environment
from torchcontact.model import ComplementarityFree, ContactModel, RelaxedQP, contact_model
from torchcontact.relaxed_qp import PAPER_RELAXATION, paper_relaxation
from torchcontact.shipped import SHIPPED, resolve_learned
from torchcontact.validation import register


@dataclass(frozen=True)
class MPCModel:
    """A contact model an MPC may plan through.

    Attributes:
        name: its registered name.
        build: ``(h [s], stiffness, relaxation) ↦`` the model (``stiffness`` None or K;
            ``relaxation`` None or the paper's κ, as its fields allow).
        stiffness: whether it takes the paper model's K (and so a learned K(q), D(q)).
        relaxation: the paper's κ it takes by default; None where it takes none.
        moving_gaps: whether its plan may move its contacts over the horizon (``gaps`` other
            than ``frozen``); otherwise it plans with frozen gaps.
        about: one line for ``--help``.
    """

    name: str
    build: Callable[[float, float | None, float | None], ContactModel]
    stiffness: bool
    relaxation: float | None
    moving_gaps: bool
    about: str


def _paper(h: float, stiffness: float | None, relaxation: float | None) -> ContactModel:
    return contact_model("paper", stiffness=stiffness)


def _relaxed_qp(h: float, stiffness: float | None, relaxation: float | None) -> ContactModel:
    kappa = PAPER_RELAXATION if relaxation is None else relaxation
    return RelaxedQP(paper_relaxation(h, kappa), facets=4)


MPC_MODELS: dict[str, MPCModel] = {
    model.name: model
    for model in (
        MPCModel("paper", _paper, True, None, True, "the complementarity-free model"),
        MPCModel(
            "relaxed_qp",
            _relaxed_qp,
            False,
            PAPER_RELAXATION,
            False,
            "the Anitescu QP with relaxed complementarity, the paper's implicit-MPC baseline",
        ),
    )
}
"""Models a trial may name (a learned K(q), D(q) comes with ``learned``, on the paper model)."""


def register_mpc_model(model: MPCModel) -> MPCModel:
    """Make ``model`` a model a trial, ``ContactImplicitMPC`` and ``torchcontact run --model``
    (from a module ``--import`` names) may plan through, under ``model.name``, which must be
    new. Returns it."""
    register(MPC_MODELS, getattr(model, "name", None), model, "MPC model", _is_model)
    return model


def _is_model(entry) -> bool:
    return isinstance(entry, MPCModel)


DEFAULT_MODEL = "paper"
"""The contact model the MPC plans through unless told otherwise."""

LEGACY_MODELS = {"complementarity_free": "paper", "qp": "relaxed_qp"}
"""The models' names in records written before the MPC took these names."""


def mpc_model(name: str) -> MPCModel:
    """The :class:`MPCModel` registered as ``name``; ``ValueError`` naming the choices."""
    if name not in MPC_MODELS:
        raise ValueError(f"model must be one of {tuple(MPC_MODELS)}, got {name!r}")
    return MPC_MODELS[name]


def load_learned(
    learned: str, env: str, robot: str | None = None, tips: Sequence[str] | None = None
) -> ComplementarityFree:
    """The model (no gradients) of checkpoint ``learned`` (a path or :data:`~torchcontact
    .shipped.SHIPPED`) for environment ``env`` (``robot``, ``tips``: a user's): a
    :class:`~torchcontact.checkpoint.CheckpointError` naming the file when it is no
    checkpoint, or one learned in another environment or on another state layout."""
    from torchcontact.checkpoint import check_fits, load_checkpoint

    path = resolve_learned(learned, env)
    model, _, meta = load_checkpoint(path)
    layout = environment(env, robot, None if tips is None else tuple(tips)).layout
    check_fits(path, meta, None if robot is not None else env, layout.joints)
    return model.requires_grad_(False)


def default_model_fields(env: Environment) -> dict:
    """The model fields of a trial naming none (``learned`` and ``stiffness``): ``env``'s
    shipped model (:data:`~torchcontact.shipped.SHIPPED`) where it ships one, otherwise the
    paper model at ``env.default_stiffness``. Trials (and so ``torchcontact run``) and
    :func:`default_model` (``ContactImplicitMPC.from_env`` without a model) both resolve the
    default here."""
    if env.ships_model:
        return {"learned": SHIPPED, "stiffness": None}
    return {"learned": None, "stiffness": env.default_stiffness}


def default_model(env: Environment) -> ContactModel:
    """The contact model an MPC of ``env`` plans through unless told otherwise, the one a
    default trial builds: the model of :func:`default_model_fields`."""
    fields = default_model_fields(env)
    if fields["learned"] is not None:
        return load_learned(fields["learned"], env.name)
    return contact_model(DEFAULT_MODEL, stiffness=fields["stiffness"])
