"""What a trial sets of the contact model its MPC plans through: one typed part.

Each field is the one home of its setting: ``torchcontact run`` generates its option from it
(:mod:`torchcontact.cli.options`), a trial's configuration holds it
(:class:`~torchcontact.mpc.trial_config.TrialConfig`) and :meth:`ModelOptions.build` makes the model
of it. A trial holds the part :meth:`ModelOptions.resolved` for its environment: its K a number
or its learned model named, never ``"paper"`` or ``"shipped"`` as a K.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

from torchcontact.environments.base import Environment
from torchcontact.model import ContactModel
from torchcontact.mpc.controller import RESIDUAL_PLANS
from torchcontact.mpc.models import (
    DEFAULT_MODEL,
    MPC_MODELS,
    default_model_fields,
    load_learned,
    mpc_model,
)
from torchcontact.shipped import SHIPPED, resolve_learned, shipped_path
from torchcontact.validation import is_finite_number

MAX_STIFFNESS = 1e9
"""The largest K a trial takes: far above any contact's (the paper's are 0.5 to 5), and far
below where the MPC's float32 cost overflows (K = 1e20 makes it NaN at its first plan)."""

PAPER_STIFFNESS = "paper"
"""``stiffness="paper"``: the environment's constant K from the paper."""

STIFFNESS_NAMES = (SHIPPED, PAPER_STIFFNESS)
"""The names a ``stiffness`` may take instead of a number."""


def _stiffness_text(text: str) -> float | str:
    """``--stiffness``'s text: one of :data:`STIFFNESS_NAMES`, else a number (checked by
    :class:`ModelOptions`; a text that is neither stays text, and is refused there)."""
    if text in STIFFNESS_NAMES:
        return text
    try:
        return float(text)
    except ValueError:
        return text


@dataclass(frozen=True)
class ModelOptions:
    """The contact model the MPC plans through, default the environment's."""

    model: str = field(
        default=DEFAULT_MODEL,
        metadata={
            "help": "contact model the MPC plans through: "
            + "; ".join(f"{name} ({m.about})" for name, m in MPC_MODELS.items())
            + f"; default {DEFAULT_MODEL}",
            "choices": MPC_MODELS,  # the live registry: a model registered later is a choice
        },
    )
    stiffness: float | str | None = field(
        default=None,
        metadata={
            "help": f"the paper model's K: '{SHIPPED}' (the environment's learned K(q), D(q) "
            f"shipped with the package, the default where it has one), '{PAPER_STIFFNESS}' "
            "(the paper's constant K) or a number",
            "parse": _stiffness_text,
            "record_kind": "number?",  # a trial holds it resolved (ModelOptions.resolved)
        },
    )
    relaxation: float | None = field(
        default=None,
        metadata={
            "help": "the paper's κ in λ∘g = κ, for a model that takes one; default "
            + ", ".join(f"{n}'s {m.relaxation:g}" for n, m in MPC_MODELS.items() if m.relaxation)
        },
    )
    learned: str | None = field(
        default=None,
        metadata={
            "help": "a `torchcontact learn-k` checkpoint (model.pt): plan with its learned "
            "K(q), D(q)",
            "metavar": "FILE",
        },
    )
    residual_plan: str = field(
        default="fixed",
        metadata={
            "help": "how a --learned model's object residual enters the plan: fixed (its "
            "correction along the warm start, added as a constant; default) or full "
            "(re-evaluated and differentiated at every planned state)",
            "choices": RESIDUAL_PLANS,
        },
    )

    def __post_init__(self):
        spec = mpc_model(self.model)
        k = self.stiffness
        if k is not None and k not in STIFFNESS_NAMES:
            if isinstance(k, str) or not (is_finite_number(k) and 0 < k <= MAX_STIFFNESS):
                raise ValueError(
                    f"stiffness must be {STIFFNESS_NAMES[0]!r}, {STIFFNESS_NAMES[1]!r} or a "
                    f"positive number at most {MAX_STIFFNESS:g}, got {k!r}"
                )
        if k is not None and not spec.stiffness:
            raise ValueError(f"stiffness is for the paper model, not {self.model}, got {k!r}")
        kappa = self.relaxation
        if kappa is not None and not (is_finite_number(kappa) and kappa > 0):
            raise ValueError(f"relaxation must be a positive finite number, got {kappa!r}")
        if kappa is not None and spec.relaxation is None:
            takes = [name for name, m in MPC_MODELS.items() if m.relaxation is not None]
            raise ValueError(f"relaxation is for {', '.join(takes)}, not {self.model}")
        if self.learned is not None and not isinstance(self.learned, str):
            raise ValueError(f"learned must be a checkpoint's path, got {self.learned!r}")
        if self.learned is not None and (not spec.stiffness or k is not None):
            raise ValueError(
                "learned replaces the paper model's constant K: give it no stiffness, on the "
                f"paper model, got stiffness {k!r} on {self.model}"
            )
        if self.residual_plan not in RESIDUAL_PLANS:
            raise ValueError(
                f"residual_plan must be one of {RESIDUAL_PLANS}, got {self.residual_plan!r}"
            )

    def resolved(self, env: Environment) -> ModelOptions:
        """These options as a trial of ``env`` holds them: the relaxation a model takes by
        default, ``stiffness="shipped"`` as the shipped model (``learned``), ``"paper"`` as
        ``env``'s K, and nothing given as ``env``'s default model
        (:func:`~torchcontact.mpc.models.default_model_fields`). ``ValueError`` naming the
        field when ``env`` ships no model, or the checkpoint is missing."""
        spec = mpc_model(self.model)
        if spec.relaxation is not None:
            relaxation = spec.relaxation if self.relaxation is None else self.relaxation
            return replace(self, relaxation=relaxation)
        if not spec.stiffness:
            return self  # a registered model taking neither K nor κ
        if self.stiffness == SHIPPED:
            if not env.ships_model:
                raise ValueError(f"stiffness {SHIPPED}: {env.name} ships no model")
            return replace(self, learned=SHIPPED, stiffness=None)
        if self.stiffness == PAPER_STIFFNESS:
            return replace(self, stiffness=env.stiffness)
        if self.stiffness is None and self.learned is None:
            return replace(self, **default_model_fields(env))
        resolve_learned(self.learned, env.name)
        return self

    def build(
        self, env: str, h: float, robot: str | None = None, tips: Sequence[str] | None = None
    ) -> ContactModel:
        """The contact model of these (resolved) options for environment ``env`` (``robot``,
        ``tips``: a user's) at model step ``h`` [s]."""
        if self.learned is not None:
            return load_learned(self.learned, env, robot, tips)
        return mpc_model(self.model).build(h, self.stiffness, self.relaxation)

    def describe(self, env: str) -> str:
        """One line for a run's header: the model and where its K comes from."""
        spec = mpc_model(self.model)
        if spec.relaxation is not None:
            return f"{self.model}, paper's κ = {self.relaxation:g}"
        if not spec.stiffness:
            return spec.about
        if self.learned == SHIPPED:
            return f"learned K(q), D(q) shipped with the package: {shipped_path(env)}"
        if self.learned is not None:
            return f"learned K(q), D(q) from {self.learned}"
        return f"K = {self.stiffness:g}"
