"""Contact models as ``nn.Module``s, interchangeable by name: ``contact_model("qp")``.

Each maps one step's metric ``Q``, linear term ``b`` and :class:`Contacts` to the next velocity
``v⁺`` and exposes the row and contact impulses for inspection: the complementarity-free step,
the Anitescu QP solved exactly by OSQP, and the same QP with relaxed complementarity solved by a
differentiable interior-point method.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import nn

from torchcontact.calibration import SystemCalibration
from torchcontact.contacts import Contacts
from torchcontact.frozen import FrozenComplementarityFree, FrozenRelaxedQP
from torchcontact.functional import (
    Scalar,
    _batch_scalar,
    cf_multipliers,
    velocity_from_multipliers,
)
from torchcontact.qp import qp_solve
from torchcontact.relaxed_qp import (
    RELAXATION,
    _check_iterations,
    _check_relaxation,
    relaxed_qp_velocity,
)
from torchcontact.residual import ObjectResidual
from torchcontact.stiffness import Constant, Parameterization, Relative, parameterization
from torchcontact.validation import check_finite, register


class ContactModel(nn.Module):
    """Interface: ``forward(Q, b, contacts, h, q=None) -> v⁺`` and the impulses behind it."""

    facets: int

    def row_impulses(self, Q, b, contacts: Contacts, h: Scalar, q=None):
        """``(v⁺ (..., nv), β (..., nc·n_d))``: next velocity and row impulses (0 on padding)."""
        raise NotImplementedError

    def forward(self, Q, b, contacts: Contacts, h: Scalar, q=None) -> torch.Tensor:
        """Next velocity ``v⁺: (..., nv)``; arguments as :meth:`row_impulses`."""
        return self.row_impulses(Q, b, contacts, h, q)[0]

    def impulses(self, Q, b, contacts: Contacts, h: Scalar, q=None):
        """Per-contact impulses: ``normal (..., nc)`` and ``friction (..., nc, 2)`` in (t₁, t₂)."""
        row = self.row_impulses(Q, b, contacts, h, q)[1]
        return self.calibrated(contacts).impulses(row, self.facets)

    def calibrated(self, contacts: Contacts) -> Contacts:
        """``contacts`` as the model sees them (the complementarity-free model may scale μ)."""
        return contacts

    def freeze(self, contacts: Contacts, h: float, q=None, *, compile: bool = False):
        """The step at ``contacts`` (unbatched, ``nc`` slots) and state ``q (nq,)`` frozen, for
        an MPC horizon: an object with ``velocity(Q, b)``, ``advance_gaps(v)``,
        ``linearized(Q, b)`` and ``traceable`` (see :mod:`torchcontact.frozen`). ``h`` [s];
        ``compile``: compile the step's inner iterations, where it has any."""
        raise ValueError(
            f"{type(self).__name__} cannot be frozen into an MPC: it is not differentiable"
        )


def _check_contacts(contacts: object) -> None:
    if not isinstance(contacts, Contacts):
        raise TypeError(f"contacts must be Contacts, got {type(contacts).__name__}")


def _check_facets(facets: int) -> int:
    if not isinstance(facets, int) or facets < 3:
        raise ValueError(f"facets must be an integer >= 3, got {facets!r}")
    return facets


class ComplementarityFree(ContactModel):
    """The complementarity-free contact step (Jin 2024) with learnable K(q) and D(q).

    Args:
        stiffness: K, a float (a learnable constant), a name from
            :data:`torchcontact.stiffness.PARAMETERIZATIONS` or a :class:`Parameterization`.
        damping: D like ``stiffness``, or None for none. ``Relative(0.1)`` is the paper's
            D = 0.1·K.
        gamma: softplus sharpness γ; None for the exact ``max(·, 0)``.
        facets: friction-cone facets n_d per contact (4 by default, 8 for a finer cone).
        calibration: a fitted :class:`~torchcontact.calibration.SystemCalibration` or None.
            The model scales its contacts' μ by the calibration's friction factor; the
            caller's system should be ``calibration.apply(system)`` (the MPC's is).
        residual: a fitted :class:`~torchcontact.residual.ObjectResidual` added to the
            objects' velocity, or None. It needs ``q``. A frozen step cannot apply it (it
            sees one state), so :meth:`freeze` refuses unless told that the caller applies it
            at each state, as the MPC's rollout does.

    Call: ``model(Q, b, contacts, h, q=None)`` with ``Q (..., nv)`` or ``(..., nv, nv)``,
    ``b (..., nv)``, :class:`Contacts` of batch shape ``...``, ``h`` [s] and, for
    state-dependent K, ``q (..., nq)``. Returns ``v⁺ (..., nv)``.
    """

    def __init__(
        self,
        stiffness: Parameterization | float | str = 1.0,
        damping: Parameterization | float | str | None = None,
        gamma: float | None = 100.0,
        facets: int = 4,
        calibration: SystemCalibration | None = None,
        residual: ObjectResidual | None = None,
    ):
        super().__init__()
        if gamma is not None and not (
            isinstance(gamma, (int, float))
            and not isinstance(gamma, bool)
            and math.isfinite(gamma)
            and gamma > 0
        ):
            raise ValueError(f"gamma must be a positive finite number or None, got {gamma!r}")
        self.stiffness = parameterization(stiffness, name="stiffness")
        self.damping = None if damping is None else parameterization(damping, name="damping")
        self.gamma = None if gamma is None else float(gamma)
        self.facets = _check_facets(facets)
        if calibration is not None and not isinstance(calibration, SystemCalibration):
            raise ValueError(
                f"calibration must be a SystemCalibration or None, got {calibration!r}"
            )
        self.calibration = calibration
        if residual is not None and not isinstance(residual, ObjectResidual):
            raise ValueError(f"residual must be an ObjectResidual or None, got {residual!r}")
        self.residual = residual

    def __setstate__(self, state: dict) -> None:
        super().__setstate__(state)
        if "residual" not in self._modules:  # pickled before models had residuals
            self.__dict__.setdefault("residual", None)

    def calibrated(self, contacts: Contacts) -> Contacts:
        """``contacts`` as the model sees them: μ scaled by the calibration, if any."""
        return contacts if self.calibration is None else self.calibration.contacts(contacts)

    def coefficients(self, contacts: Contacts, q=None):
        """K(q) and D(q) (None without damping), each broadcastable to ``(..., nc·n_d)``.

        Raises ``ValueError`` naming ``q`` when a tensor ``q`` holds NaN or Inf."""
        if isinstance(q, torch.Tensor):
            check_finite("q", q)
        K = self.stiffness(contacts, self.facets, q)
        D = None if self.damping is None else self.damping(contacts, self.facets, q, K)
        return K, D

    def freeze(
        self,
        contacts: Contacts,
        h: float,
        q=None,
        *,
        compile: bool = False,
        without_residual: bool = False,
    ) -> FrozenComplementarityFree:
        """As :meth:`ContactModel.freeze`. A model holding a residual refuses, unless
        ``without_residual``: the contact step alone, for a caller that applies
        :attr:`residual` itself (as :func:`~torchcontact.learn.fit.predict` and the MPC's
        rollout do)."""
        if self.residual is not None and not without_residual:
            raise ValueError(
                "model holds an object residual, which a frozen step cannot apply (it sees one "
                "state): freeze with without_residual=True and apply model.residual at each "
                "state, as the MPC's rollout does"
            )
        contacts = self.calibrated(contacts)
        jac, phi, _ = contacts.dual_rows(self.facets)
        K, D = self.coefficients(contacts, q)
        normal = contacts.jac_normal * contacts.active.to(phi.dtype).unsqueeze(-1)
        return FrozenComplementarityFree(
            jac,
            phi,
            K.expand(phi.shape),
            None if D is None else D.expand(phi.shape),
            normal.repeat_interleave(self.facets, dim=-2),
            float(h),
            self.gamma,
        )

    def row_impulses(self, Q, b, contacts: Contacts, h: Scalar, q=None):
        _check_contacts(contacts)
        contacts = self.calibrated(contacts)
        jac, phi, active = contacts.dual_rows(self.facets)
        K, D = self.coefficients(contacts, q)
        lam, solve = cf_multipliers(Q, b, jac, phi, h, K, D, self.gamma)
        lam = lam * active.to(lam.dtype)
        v = velocity_from_multipliers(solve, b, jac, lam, h)
        if self.residual is not None:
            if q is None:
                raise ValueError("q must be given to a model with an object residual, got None")
            v = self.residual(q, b, v, h)
        return v, lam * _batch_scalar(h)

    def extra_repr(self) -> str:
        # the repr names what a compiled MPC graph is specialised to (mpc.background.graph_key)
        return f"gamma={self.gamma}, facets={self.facets}"


class AnitescuQP(ContactModel):
    """The Anitescu QP model solved by OSQP: the honest baseline. Not differentiable.

    Args:
        facets: friction-cone facets n_d per contact.
        settings: OSQP settings overriding :data:`torchcontact.qp.OSQP_SETTINGS`.
    """

    def __init__(self, facets: int = 4, settings: dict | None = None):
        super().__init__()
        self.facets = _check_facets(facets)
        self.settings = dict(settings or {})

    def row_impulses(self, Q, b, contacts: Contacts, h: Scalar, q=None):
        _check_contacts(contacts)
        jac, phi, active = contacts.dual_rows(self.facets)
        return qp_solve(Q, b, jac, phi, h, active, self.settings)


class RelaxedQP(ContactModel):
    """The Anitescu QP with complementarity relaxed to ``β∘s = κ``: differentiable, batched.

    The complementarity-based baseline of the paper's MPC comparison ("implicit MPC"); see
    :func:`torchcontact.relaxed_qp.relaxed_qp_velocity`.

    Args:
        relaxation: κ > 0 [N·m]; by default the paper's 5e-4 at h = 0.1 s, converted to this
            QP's scaling (:func:`torchcontact.relaxed_qp.paper_relaxation`).
        facets: friction-cone facets n_d per contact.
        iterations: a fixed number of interior-point iterations (for ``torch.compile``), or
            None to iterate to the dtype's tolerance.
    """

    def __init__(
        self, relaxation: float = RELAXATION, facets: int = 4, iterations: int | None = None
    ):
        super().__init__()
        self.relaxation = _check_relaxation(relaxation)
        self.facets = _check_facets(facets)
        _check_iterations(iterations)
        self.iterations = iterations

    def freeze(
        self, contacts: Contacts, h: float, q=None, *, compile: bool = False
    ) -> FrozenRelaxedQP:
        jac, phi, active = contacts.dual_rows(self.facets)
        return FrozenRelaxedQP(
            jac, phi, active, float(h), self.relaxation, self.iterations, compile_steps=compile
        )

    def row_impulses(self, Q, b, contacts: Contacts, h: Scalar, q=None):
        _check_contacts(contacts)
        jac, phi, active = contacts.dual_rows(self.facets)
        return relaxed_qp_velocity(
            Q, b, jac, phi, h, active, relaxation=self.relaxation, iterations=self.iterations
        )

    def extra_repr(self) -> str:
        return f"relaxation={self.relaxation}, facets={self.facets}, iterations={self.iterations}"


def paper_model(stiffness: float = 1.0) -> ComplementarityFree:
    """The paper's MPC model: constant K = ``stiffness``, D = 0.1·K (both fixed), γ = 100,
    n_d = 4."""
    return ComplementarityFree(
        stiffness=Constant(stiffness, learnable=False, name="stiffness"),
        damping=Relative(0.1, learnable=False),
        gamma=100.0,
        facets=4,
    )


MODELS: dict[str, Callable[..., ContactModel]] = {
    "complementarity_free": ComplementarityFree,
    "paper": paper_model,
    "qp": AnitescuQP,
    "relaxed_qp": RelaxedQP,
}
"""Contact models by name: the complementarity-free step (any K, D, γ), its paper
configuration, the Anitescu QP by OSQP, and the QP with relaxed complementarity."""


def register_model(name: str, factory: Callable[..., ContactModel]) -> None:
    """Make ``contact_model(name, **kw)`` call ``factory(**kw)``; ``name`` must be new."""
    register(MODELS, name, factory, "model")


def contact_model(name: str, **kwargs) -> ContactModel:
    """Build a contact model by name (one of :data:`MODELS`), e.g. ``contact_model("paper",
    stiffness=0.5)``; keyword arguments go to its constructor."""
    if name not in MODELS:
        raise ValueError(f"name must be one of {sorted(MODELS)}, got {name!r}")
    model = MODELS[name](**kwargs)
    if not isinstance(model, ContactModel):
        raise ValueError(f"model {name!r} built a {type(model).__name__}, not a ContactModel")
    return model


__all__ = [
    "AnitescuQP",
    "ComplementarityFree",
    "ContactModel",
    "MODELS",
    "RelaxedQP",
    "contact_model",
    "paper_model",
    "register_model",
]
