"""Receding-horizon contact-implicit MPC through the complementarity-free model (Algorithm 1).

At each real state: detect contacts once and freeze J̃ and φ̃ over the horizon; roll the model
out for T steps (optionally advancing φ̃ along the frozen normal rows, ``gaps="propagated"``);
minimize Σₜ c(qₜ, uₜ) + V(q_T) over u₀…u_{T−1} in their box with projected L-BFGS (gradients
by autograd); apply u₀; warm-start the next solve from the shifted plan.

The same controller plans through the complementarity-based baseline, the Anitescu QP with
relaxed complementarity (:class:`RelaxedQP`, the paper's "implicit MPC"), chosen by name with
:func:`mpc_model`: only the step's velocity changes, the cost, box, optimizer and warm start are
the same.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import torch

from torchcontact.contacts import Contacts
from torchcontact.environments.costs import ManipulationCost
from torchcontact.environments.presets import GAPS
from torchcontact.functional import cf_velocity
from torchcontact.integrate import JointLayout, integrate
from torchcontact.model import ComplementarityFree, RelaxedQP
from torchcontact.mpc.optim import lbfgs_box
from torchcontact.relaxed_qp import (
    PAPER_RELAXATION,
    RelaxedQPSolution,
    paper_relaxation,
    relaxed_qp_solve,
    relaxed_qp_velocity,
)
from torchcontact.stiffness import Constant, Relative
from torchcontact.systems import QuasiDynamic
from torchcontact.validation import check_shape, validate_args

Fingertips = Callable[[torch.Tensor], torch.Tensor]
"""Forward kinematics ``q (..., nq) ↦ fingertip positions (..., n_tips, 3)`` [m]."""


CONTACT_BUCKET = 4
"""The MPC pads the detected contacts with inert slots to a multiple of this many: a compiled
plan is specialised to its number of rows, and this way scenes of 13–16 slots (most of the
Allegro's objects) share one compiled graph instead of compiling one each, a minute or more
apiece. Padding rows are zero, so they change no velocity."""

MPC_MODELS = ("complementarity_free", "qp")
"""Contact models the MPC plans through, by name; ``"qp"`` is the relaxed, differentiable QP."""


def paper_model(stiffness: float) -> ComplementarityFree:
    """The paper's MPC contact model: constant K = ``stiffness``, D = 0.1·K, γ = 100, n_d = 4."""
    return ComplementarityFree(
        stiffness=Constant(stiffness, learnable=False),
        damping=Relative(0.1, learnable=False),
        gamma=100.0,
        facets=4,
    )


def mpc_model(
    name: str, stiffness: float | None = None, relaxation: float | None = None, h: float = 0.1
) -> ComplementarityFree | RelaxedQP:
    """The MPC's contact model by name (one of :data:`MPC_MODELS`), n_d = 4.

    ``"complementarity_free"``: :func:`paper_model` with K = ``stiffness``.
    ``"qp"``: the Anitescu QP with complementarity relaxed to the paper's κ = ``relaxation``
    (default :data:`~torchcontact.relaxed_qp.PAPER_RELAXATION`, 5e-4, in the paper's scaling of
    the QP; converted for the model's step ``h`` [s] by
    :func:`~torchcontact.relaxed_qp.paper_relaxation`).
    """
    if name == "complementarity_free":
        if stiffness is None:
            raise ValueError("stiffness is required by the complementarity-free model")
        return paper_model(stiffness)
    if name == "qp":
        kappa = PAPER_RELAXATION if relaxation is None else relaxation
        return RelaxedQP(paper_relaxation(h, kappa), facets=4)
    raise ValueError(f"model must be one of {MPC_MODELS}, got {name!r}")


@dataclass(frozen=True)
class Plan:
    """One MPC solve: the control to apply and how the solve went."""

    control: torch.Tensor  # (n_u,) u₀
    controls: torch.Tensor  # (T, n_u) the whole plan
    cost: float
    iterations: int
    evaluations: int
    solve_ms: float


class ContactImplicitMPC:
    """MPC over a quasi-dynamic system whose contacts are frozen over the horizon.

    Args:
        system: the quasi-dynamic system (Q, b(u)).
        model: the contact model: :class:`ComplementarityFree` (its K, D, γ, facets are used) or
            :class:`RelaxedQP` (its κ, facets and iterations).
        layout: the joint layout of q (object free joint first, then the robot).
        fingertips: forward kinematics of the fingertips, see :data:`Fingertips`.
        cost: the cost weights.
        u_lower, u_upper: ``(n_u,)`` or floats, the control box.
        horizon: T steps; h: the model's time step [s].
        max_iter, memory: L-BFGS iterations per solve and its memory.
        compile: compile the objective and the optimizer's steps with ``torch.compile``
            (fast steps; the first call compiles, cached on disk after that); for the relaxed
            QP also each of its interior-point iterations.
        dtype: of the solve.
        gaps: ``"frozen"`` or ``"propagated"`` distances over the horizon, see :data:`GAPS`.
    """

    def __init__(
        self,
        system: QuasiDynamic,
        model: ComplementarityFree | RelaxedQP,
        layout: JointLayout,
        fingertips: Fingertips,
        cost: ManipulationCost,
        u_lower,
        u_upper,
        horizon: int = 4,
        h: float = 0.1,
        max_iter: int = 30,
        memory: int = 8,
        compile: bool = False,
        dtype: torch.dtype = torch.float64,
        gaps: str = "frozen",
    ):
        if not isinstance(horizon, int) or horizon < 1:
            raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
        if not h > 0:
            raise ValueError(f"h must be positive, got {h!r}")
        if not isinstance(model, (ComplementarityFree, RelaxedQP)):
            raise ValueError(
                "model must be a ComplementarityFree or a RelaxedQP (the MPC differentiates "
                f"through it), got {type(model).__name__}"
            )
        if gaps not in GAPS:
            raise ValueError(f"gaps must be one of {GAPS}, got {gaps!r}")
        if gaps == "propagated" and isinstance(model, RelaxedQP):
            raise ValueError("gaps='propagated' needs the complementarity-free model, not a QP")
        self.system = system.to(dtype)
        self.model = model.to(dtype)
        self.layout, self.fingertips, self.cost = layout, fingertips, cost
        self.horizon, self.h, self.dtype = horizon, float(h), dtype
        self.max_iter, self.memory, self.gaps = max_iter, memory, gaps
        n_u = system.n_robot
        self.lower = torch.as_tensor(u_lower, dtype=dtype).expand(horizon, n_u).reshape(1, -1)
        self.upper = torch.as_tensor(u_upper, dtype=dtype).expand(horizon, n_u).reshape(1, -1)
        if bool((self.lower > self.upper).any()):
            raise ValueError("u_lower must not exceed u_upper")
        self.compiled = compile
        self._differentiate = (
            torch.compile(self.differentiate, dynamic=False) if compile else self.differentiate
        )
        self._warm = torch.zeros(1, horizon * n_u, dtype=dtype)

    def reset(self) -> None:
        """Forget the warm start (call between episodes)."""
        self._warm.zero_()

    def frozen_rows(self, q: torch.Tensor, contacts: Contacts) -> tuple:
        """The model's data frozen over the horizon, from the contacts at ``q (nq,)``.

        Complementarity-free: ``(J̃ (m, nv), φ̃ (m,), K (m,), D (m,) or None)``, and with
        propagated gaps also each row's contact normal row ``Jⁿ (m, nv)``; relaxed QP:
        ``(J̃, φ̃, active (m,))``, to which :meth:`value_and_grad` appends the QP's solution.
        """
        jac, phi, active = contacts.dual_rows(self.model.facets)
        if isinstance(self.model, RelaxedQP):
            return jac, phi, active
        K, D = self.model.coefficients(contacts, q)
        rows = (jac, phi, K.expand(phi.shape), None if D is None else D.expand(phi.shape))
        if self.gaps == "frozen":
            return rows
        normal = contacts.jac_normal * contacts.active.to(phi.dtype).unsqueeze(-1)
        return (*rows, normal.repeat_interleave(self.model.facets, dim=-2))

    def velocity(self, Q: torch.Tensor, b: torch.Tensor, rows: tuple) -> torch.Tensor:
        """The model's next velocity ``(..., nv)`` with the :meth:`frozen_rows` ``rows``."""
        if isinstance(self.model, RelaxedQP):
            jac, phi, active, *solution = rows
            v, _ = relaxed_qp_velocity(
                Q,
                b,
                jac,
                phi,
                self.h,
                active,
                self.model.relaxation,
                self.model.iterations,
                solution=solution[0] if solution else None,
            )
            return v
        jac, phi, K, D = rows
        return cf_velocity(Q, b, jac, phi, self.h, K, D, self.model.gamma)

    def rollout(self, q0, controls, rows: tuple) -> torch.Tensor:
        """States ``(..., T+1, nq)`` from ``q0 (nq,)`` under ``controls (..., T, n_u)``.

        The :meth:`frozen_rows` ``rows`` stay frozen over the horizon, as does Q: so with
        frozen gaps each step's velocity depends on its own control only and all T are computed
        at once; propagated gaps chain the steps through φ̃.
        """
        Q, b = self.system(controls)
        states = [q0.expand(*controls.shape[:-2], -1)]
        if self.gaps == "propagated":
            jac, phi, K, D, normal = rows
            for t in range(self.horizon):
                v = self.velocity(Q, b[..., t, :], (jac, phi, K, D))
                states.append(integrate(states[-1], v, self.h, self.layout))
                phi = phi + self.h * (normal @ v.unsqueeze(-1)).squeeze(-1)
            return torch.stack(states, dim=-2)
        v = self.velocity(Q, b, rows)
        for t in range(self.horizon):
            states.append(integrate(states[-1], v[..., t, :], self.h, self.layout))
        return torch.stack(states, dim=-2)

    def objective(self, controls, q0, rows: tuple, target_p, target_quat):
        """Cost ``(...)`` of ``controls (..., T, n_u)`` (arguments as :meth:`rollout`)."""
        states = self.rollout(q0, controls, rows)
        return self.cost(
            states[..., 0:3],
            states[..., 3:7],
            self.fingertips(states),
            controls,
            target_p,
            target_quat,
        )

    def qp_solution(self, controls: torch.Tensor, rows: tuple) -> RelaxedQPSolution:
        """The relaxed QP's interior-point solution for each step of ``controls (..., T, n_u)``."""
        Q, b = self.system(controls)
        jac, phi, active = rows
        return relaxed_qp_solve(
            Q,
            b,
            jac,
            phi,
            self.h,
            active,
            self.model.relaxation,
            self.model.iterations,
            compile_steps=self.compiled,
        )

    def value_and_grad(
        self, controls, q0, rows: tuple, target_p, target_quat
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Cost ``(B,)`` and its gradient ``(B, T, n_u)`` for ``controls (B, T, n_u)``.

        For the relaxed QP, its interior-point iteration runs first, outside the gradient
        transform (a loop with a convergence test, which would break a compiled graph), and
        the transform differentiates only the implicit-function step from that solution.
        """
        if isinstance(self.model, RelaxedQP):
            rows = (*rows, self.qp_solution(controls, rows))
        return self._differentiate(controls, q0, rows, target_p, target_quat)

    def differentiate(self, controls, *args) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`value_and_grad` of :meth:`objective` by ``torch.func.grad``, given the rows.

        ``torch.func.grad`` rather than a recorded tape: one traced graph for value and
        gradient, which ``torch.compile`` fuses (about 2× faster than compiling the tape).
        """

        def total(c):
            cost = self.objective(c, *args)
            return cost.sum(), cost  # rows are independent: ∇ of the sum is each row's ∇

        grad, cost = torch.func.grad(total, has_aux=True)(controls)
        return cost, grad

    def _flat_value_and_grad(self, x: torch.Tensor, *args) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`value_and_grad` of flat controls ``x (N, T·n_u)``; grad ``(N, T·n_u)``."""
        f, grad = self.value_and_grad(x.unflatten(-1, (self.horizon, -1)), *args)
        return f, grad.flatten(-2)

    def _flat_differentiate(self, x: torch.Tensor, *args) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`differentiate` of flat controls ``x (N, T·n_u)``, for a traced round."""
        f, grad = self.differentiate(x.unflatten(-1, (self.horizon, -1)), *args)
        return f, grad.flatten(-2)

    def plan(
        self, q: torch.Tensor, contacts: Contacts, target_p: torch.Tensor, target_quat: torch.Tensor
    ) -> Plan:
        """Solve the MPC problem at state ``q (nq,)`` with the contacts detected there."""
        check_shape("q", q, f"({self.layout.nq},)", q.shape == (self.layout.nq,))
        start = time.perf_counter()
        q, contacts = q.to(self.dtype), contacts.to(self.dtype)
        contacts = contacts.padded(-(-contacts.slots // CONTACT_BUCKET) * CONTACT_BUCKET)
        target_p, target_quat = target_p.to(self.dtype), target_quat.to(self.dtype)
        with torch.no_grad():
            rows = self.frozen_rows(q, contacts)
        shape = (self.horizon, self.system.n_robot)
        # Complementarity-free and compiled: the objective is traced into the optimizer's
        # rounds, several L-BFGS rounds per compiled call (the QP's solve cannot be traced).
        traced = self.compiled and not isinstance(self.model, RelaxedQP)
        with validate_args(False):
            result = lbfgs_box(
                self._flat_differentiate if traced else self._flat_value_and_grad,
                self._warm.clone(),
                self.lower,
                self.upper,
                memory=self.memory,
                max_iter=self.max_iter,
                compile_steps=self.compiled,
                args=(q, rows, target_p, target_quat),
                compile_fun=traced,
            )
        controls = result.x.reshape(shape)
        self._warm = torch.cat([controls[1:], controls[-1:]]).reshape(1, -1)
        return Plan(
            control=controls[0].clone(),
            controls=controls,
            cost=float(result.f[0]),
            iterations=int(result.n_iter),
            evaluations=int(result.n_evals),
            solve_ms=1e3 * (time.perf_counter() - start),
        )
