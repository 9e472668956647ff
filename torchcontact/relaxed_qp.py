"""The Anitescu QP contact model with relaxed complementarity: batched, differentiable, pure torch.

The QP of :mod:`torchcontact.qp`, ``min_v ½h²vᵀQv − h vᵀb  s.t.  s = J̃v + φ̃/h ≥ 0``, has the
KKT conditions

    h²Qv − hb − J̃ᵀβ = 0,     J̃v + φ̃/h − s = 0,     β ≥ 0,  s ≥ 0,  β∘s = 0.

Relaxing complementarity to ``β∘s = κ`` (κ > 0, the *relaxation*) makes the solution a smooth
function of Q, b, J̃, φ̃ and h: it is the minimizer of the log-barrier problem

    min_v ½h²vᵀQv − h vᵀb − κ Σᵢ log(J̃ᵢv + φ̃ᵢ/h),

the point of the interior-point central path at μ = κ. κ is an energy in the objective's unit
(N·m for the quasi-dynamic systems, where ``½h²vᵀQv − h vᵀb = ½δqᵀQδq − δqᵀb`` with δq = hv):
a row whose predicted distance is d = h·s [m] pushes with the force β/h = κ/d [N], however far
apart. As κ → 0 the solution tends to the QP's: a row the QP loads with β keeps a slack κ/β, a
row it leaves slack at s carries an impulse κ/s, and degenerate rows (both 0) err by O(√κ).

Forward: a primal–dual interior-point Newton iteration on the relaxed KKT equations in
(v, s, β), without autograd (:func:`relaxed_qp_solve`). It starts at the unconstrained minimizer
with s, β > 0 (an infeasible start), aims each step at ``β∘s = max(κ, σ·mean(β∘s))``
(σ = :data:`CENTERING`), so that it follows the central path down to κ and then converges
quadratically to the relaxed point, and keeps s, β > 0 by the fraction-to-boundary rule.
Eliminating s and β leaves one ``(nv, nv)`` SPD system per step, ``(h²Q + J̃ᵀ diag(β/s) J̃)
dv = ·``, solved by a batched Cholesky factorization. The step is plain path-following, not
Mehrotra's predictor–corrector, whose second solve per step costs more than it saves here.

Backward: the implicit function theorem, as one differentiable Newton step from the detached
solution z* = (v*, s*, β*): ``z = z* − J_F(z*)⁻¹ F(z*; θ)`` with the Jacobian J_F held constant
(:func:`relaxed_qp_velocity`). Its value is z* (F(z*) = 0; the step also polishes the last
iterate) and its derivative is ``−J_F⁻¹ ∂F/∂θ``, exactly the IFT gradient, w.r.t. every input
θ = (Q, b, J̃, φ̃, h). Being plain tensor operations, it composes with ``torch.autograd``,
``torch.func.grad`` and ``torch.compile``, which a custom ``autograd.Function`` would not all
do; and as the solve can run apart from the step (``solution=``), a gradient transform or a
compiled graph need only contain the step.

The relaxed problem needs a strictly feasible v (some v with every active row's J̃v + φ̃/h > 0).
Contact problems have one (bodies can always move apart); without one β diverges and the
iteration stops at its cap. In float32, badly scaled problems may stall at a relative residual
near 1e-4 (the default tolerance) and also run to the cap.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import torch

from torchcontact.functional import (
    Scalar,
    _batch_scalar,
    _check_step_inputs,
    _matvec,
    is_dense_metric,
    metric_solver,
)
from torchcontact.validation import check_number, check_positive, check_shape

PAPER_RELAXATION = 5e-4
"""The paper's κ, in its code's scaling of the same QP: ``min ½vᵀQv − vᵀb/h`` s.t.
``g = J̃v + φ̃/h ≥ 0`` with ``λ∘g = κ`` (see :func:`paper_relaxation`)."""


def paper_relaxation(h: float, kappa: float = PAPER_RELAXATION) -> float:
    """κ here [N·m] for the paper's ``kappa`` at time step ``h`` [s]: ``h²·kappa``.

    The paper's objective is this module's divided by h², so its multipliers are λ = β/h² and
    its ``λ∘g = κ`` reads ``β∘s = h²κ`` here (5e-6 N·m for 5e-4 at h = 0.1 s). Taken
    unconverted, 5e-4 would make every row push with 5e-4/d N at predicted distance d: a
    resting 10 g cube would rise about 12 mm per step.
    """
    return _check_relaxation(kappa) * float(h) ** 2


RELAXATION = PAPER_RELAXATION * 0.1**2  # paper_relaxation(0.1)
"""Default κ in ``β∘s = κ`` [N·m]: the paper's 5e-4 at its h = 0.1 s (:func:`paper_relaxation`)."""

CENTERING = 0.1
"""σ: each Newton step aims at ``β∘s = max(κ, σ·mean(β∘s))``."""

FRACTION_TO_BOUNDARY = 0.99
"""A step goes at most this fraction of the way to where some s or β would reach 0."""

MAX_ITER = 100
"""Iteration cap of the tolerance-driven mode (``iterations=None``)."""

DIAGONAL_SHIFT = 10.0
"""The Newton matrix's diagonal is scaled by 1 + DIAGONAL_SHIFT·ε (see ``_Problem.factor``)."""


def default_tolerance(dtype: torch.dtype) -> float:
    """Relative KKT residual at which the iteration stops: 1e-10 in float64, 1.2e-4 in float32.

    float32 iterations stall at 1e-5–1e-4: the residuals cancel terms that size larger.
    """
    return max(1e-10, 1000 * torch.finfo(dtype).eps)


class RelaxedQPSolution(NamedTuple):
    """A detached solution of the relaxed KKT system (dropped rows: J̃ = 0, s = 1).

    Attributes:
        v: ``(..., nv)`` velocity; s: ``(..., m)`` row slacks J̃v + φ̃/h [m/s];
        beta: ``(..., m)`` row impulses, ``β∘s = κ``.
    """

    v: torch.Tensor
    s: torch.Tensor
    beta: torch.Tensor


def _check_relaxation(relaxation: float) -> float:
    if not (
        isinstance(relaxation, (int, float))
        and not isinstance(relaxation, bool)
        and math.isfinite(relaxation)
        and relaxation > 0
    ):
        raise ValueError(f"relaxation must be a positive finite number, got {relaxation!r}")
    return float(relaxation)


def _check_iterations(iterations: int | None, name: str = "iterations", optional=True) -> None:
    if optional and iterations is None:
        return
    if not isinstance(iterations, int) or isinstance(iterations, bool) or iterations < 1:
        allowed = "a positive integer or None" if optional else "a positive integer"
        raise ValueError(f"{name} must be {allowed}, got {iterations!r}")


def _checked_rows(Q, b, jac, phi, h, active, relaxation, iterations, max_iter, tol):
    """Check the inputs; return ``jac, phi`` with the inactive rows dropped and κ."""
    _check_step_inputs(Q, b, jac, phi, h, 1.0, None, None)
    kappa = _check_relaxation(relaxation)
    _check_iterations(iterations)
    _check_iterations(max_iter, "max_iter", optional=False)
    if tol is not None:
        check_number("tol", tol)
        check_positive("tol", tol)
    if active is None:
        return jac, phi, kappa
    m = phi.shape[-1]
    check_shape(
        "active",
        active,
        f"(..., m={m}) bool",
        active.dtype == torch.bool and active.dim() >= 1 and active.shape[-1] == m,
    )
    # A dropped row acts on nothing (J̃ = 0) and sits at slack φ̃/h = 1, whatever its φ̃ was.
    jac = jac * active.unsqueeze(-1).to(jac.dtype)
    phi = torch.where(active, phi, _batch_scalar(h) * torch.ones_like(phi))
    return jac, phi, kappa


def _detach(x):
    return x.detach() if isinstance(x, torch.Tensor) else x


class _Problem:
    """One batch of relaxed QPs: the residuals F(v, s, β) and the Newton step on them."""

    def __init__(self, Q, b, jac, phi, h, relaxation):
        self.dense = is_dense_metric(Q, b)
        self.Q, self.b, self.jac, self.phi = Q, b, jac, phi
        self.h = _batch_scalar(h)
        self.relaxation = relaxation

    def metric_times(self, v: torch.Tensor) -> torch.Tensor:
        """``h²Qv``."""
        Qv = _matvec(self.Q, v) if self.dense else self.Q * v
        return self.h * self.h * Qv

    def residuals(self, v, s, beta):
        """Stationarity ``h²Qv − hb − J̃ᵀβ`` and primal feasibility ``J̃v + φ̃/h − s``."""
        r1 = self.metric_times(v) - self.h * self.b - _matvec(self.jac.mT, beta)
        r2 = _matvec(self.jac, v) + self.phi / self.h - s
        return r1, r2

    def factor(self, s, beta):
        """Cholesky factor of ``h²Q + J̃ᵀ diag(β/s) J̃`` and the weights ``β/s``.

        Near the solution a loaded row's weight β/s = β²/κ is huge, and the matrix's condition
        number can pass 1/ε in float32; its diagonal is raised by the relative
        :data:`DIAGONAL_SHIFT`·ε so that the factorization never breaks down (a step that is
        inexact only along those stiff rows; in float64 the shift is below round-off).
        """
        weight = beta / s
        hh = self.h * self.h
        if self.dense:
            hhQ = (hh.unsqueeze(-1) if isinstance(hh, torch.Tensor) else hh) * self.Q
        else:
            hhQ = torch.diag_embed(hh * self.Q)
        matrix = self.jac.mT @ (weight.unsqueeze(-1) * self.jac) + hhQ
        eye = torch.eye(matrix.shape[-1], dtype=matrix.dtype, device=matrix.device)
        shifted = matrix * (1 + DIAGONAL_SHIFT * torch.finfo(matrix.dtype).eps * eye)
        return torch.linalg.cholesky_ex(shifted)[0], weight

    def newton(self, factor, weight, s, r1, r2, r3):
        """The Newton step ``(dv, ds, dβ)`` on residuals r1, r2 and ``r3 = β∘s − target``."""
        rhs = -r1 - _matvec(self.jac.mT, weight * r2 + r3 / s)
        dv = torch.cholesky_solve(rhs.unsqueeze(-1), factor).squeeze(-1)
        ds = r2 + _matvec(self.jac, dv)
        return dv, ds, -weight * ds - r3 / s

    def kkt_error(self, v, s, beta, r1, r2) -> torch.Tensor:
        """Largest relative residual over the batch: stationarity, feasibility, ``β∘s/κ − 1``."""
        tiny = torch.finfo(v.dtype).tiny

        def relative(r, *terms):
            scale = functools.reduce(torch.maximum, [t.abs().amax(-1) for t in terms])
            return (r.abs().amax(-1) / scale.clamp_min(tiny)).amax()

        stationarity = relative(
            r1, self.metric_times(v), self.h * self.b, _matvec(self.jac.mT, beta)
        )
        feasibility = relative(r2, _matvec(self.jac, v), self.phi / self.h, s)
        centrality = (beta * s / self.relaxation - 1).abs().amax()
        return torch.stack([stationarity, feasibility, centrality]).amax()

    def start(self, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Slacks and impulses to start from at ``v``, the unconstrained minimizer.

        s = max(gap, 0) + margin, the margin being the largest |gap| of a live row (dropped
        rows sit at gap 1 and would set the scale); β = μ₀/s with μ₀ = max(κ, margin·β̄) and
        β̄ = |hb|∞/|J̃|∞ the size of the impulses that can balance hb, which starts β at the
        scale of the solution's impulses.
        """
        gap = _matvec(self.jac, v) + self.phi / self.h
        live = self.jac.abs().amax(-1) > 0
        margin = torch.where(live, gap.abs(), 0).amax(-1, keepdim=True)
        margin = margin.clamp_min(math.sqrt(self.relaxation))
        s = gap.clamp_min(0) + margin
        rows = self.jac.abs().amax((-2, -1)).unsqueeze(-1)
        impulse = (self.h * self.b).abs().amax(-1, keepdim=True) / rows.clamp_min(1e-30)
        return s, (margin * impulse).clamp_min(self.relaxation) / s


def _step_length(x: torch.Tensor, dx: torch.Tensor) -> torch.Tensor:
    """``(..., 1)`` the largest α with x + α·dx ≥ 0, per batch element (inf if none binds)."""
    ratio = torch.where(dx < 0, -x / dx.clamp(max=-torch.finfo(x.dtype).tiny), math.inf)
    return ratio.amin(-1, keepdim=True)


def _iteration(Q, b, jac, phi, h, kappa, v, s, beta):
    """One interior-point step from ``(v, s, β)``: the new iterate and the old one's KKT error."""
    problem = _Problem(Q, b, jac, phi, h, kappa)
    r1, r2 = problem.residuals(v, s, beta)
    error = problem.kkt_error(v, s, beta, r1, r2)
    target = (CENTERING * (beta * s).mean(-1, keepdim=True)).clamp_min(kappa)
    factor, weight = problem.factor(s, beta)
    dv, ds, dbeta = problem.newton(factor, weight, s, r1, r2, beta * s - target)
    reach = torch.minimum(_step_length(s, ds), _step_length(beta, dbeta))
    alpha = (FRACTION_TO_BOUNDARY * reach).clamp(max=1.0)
    return v + alpha * dv, s + alpha * ds, beta + alpha * dbeta, error


@functools.cache
def _compiled_iteration():
    """:func:`_iteration` through ``torch.compile`` (one graph; built once per shape/dtype)."""
    return torch.compile(_iteration, dynamic=False, fullgraph=True)


def _solve(Q, b, jac, phi, h, kappa, iterations, tol, max_iter, compile_steps):
    """The interior-point iteration on checked, detached inputs."""
    h_rows = _batch_scalar(h)
    v = metric_solver(Q, b)(b) / h_rows  # the unconstrained minimizer; checks Q is SPD
    if jac.shape[-2] == 0:
        empty = v.new_zeros(*v.shape[:-1], 0)
        return RelaxedQPSolution(v, empty, empty)
    s, beta = _Problem(Q, b, jac, phi, h, kappa).start(v)
    step = _compiled_iteration() if compile_steps else _iteration
    for _ in range(max_iter if iterations is None else iterations):
        new_v, new_s, new_beta, error = step(Q, b, jac, phi, h, kappa, v, s, beta)
        if iterations is None and not float(error) > tol:  # converged, or broke down (NaN)
            break
        v, s, beta = new_v, new_s, new_beta
    return RelaxedQPSolution(v, s, beta)


def relaxed_qp_solve(
    Q: torch.Tensor,
    b: torch.Tensor,
    jac: torch.Tensor,
    phi: torch.Tensor,
    h: Scalar,
    active: torch.Tensor | None = None,
    relaxation: float = RELAXATION,
    iterations: int | None = None,
    tol: float | None = None,
    max_iter: int = MAX_ITER,
    compile_steps: bool = False,
) -> RelaxedQPSolution:
    """Solve the relaxed KKT system by the interior-point iteration, without autograd.

    Arguments as :func:`relaxed_qp_velocity`, plus ``compile_steps``: run each iteration as one
    ``torch.compile`` graph (seconds to compile once per shape and dtype; worth it in a loop).
    Returns a detached :class:`RelaxedQPSolution` to hand to :func:`relaxed_qp_velocity`.
    """
    jac, phi, kappa = _checked_rows(
        Q, b, jac, phi, h, active, relaxation, iterations, max_iter, tol
    )
    tol = default_tolerance(b.dtype) if tol is None else tol
    with torch.no_grad():
        inputs = [_detach(x) for x in (Q, b, jac, phi, h)]
        return _solve(*inputs, kappa, iterations, tol, max_iter, compile_steps)


def relaxed_qp_velocity(
    Q: torch.Tensor,
    b: torch.Tensor,
    jac: torch.Tensor,
    phi: torch.Tensor,
    h: Scalar,
    active: torch.Tensor | None = None,
    relaxation: float = RELAXATION,
    iterations: int | None = None,
    tol: float | None = None,
    max_iter: int = MAX_ITER,
    solution: RelaxedQPSolution | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Next velocity and row impulses of the Anitescu QP with complementarity relaxed to κ.

    Differentiable w.r.t. ``Q``, ``b``, ``jac``, ``phi`` and ``h`` (implicit function theorem;
    see the module docstring), batched over any leading dimensions, on any device, in float32
    or float64.

    Args:
        Q: ``(..., nv)`` positive diagonal or ``(..., nv, nv)`` SPD metric, as in
            :func:`torchcontact.functional.cf_velocity`.
        b: ``(..., nv)`` linear term.
        jac: ``(..., m, nv)`` dual-cone rows J̃.
        phi: ``(..., m)`` row distances φ̃ [m].
        h: time step [s], a float or a tensor of the batch shape ``(...)``.
        active: ``(..., m)`` bool rows to keep, or None for all. The others are dropped (their
            J̃ row is zeroed and their slack set to 1, so they act on nothing) and their β is 0.
        relaxation: κ > 0 in ``β∘s = κ`` [N·m]; by default the paper's at h = 0.1 s
            (:func:`paper_relaxation`).
        iterations: run exactly this many interior-point iterations (no host sync: a fixed
            cost, traceable by ``torch.compile``), or None to iterate until the relative KKT
            residual is at most ``tol`` or ``max_iter`` iterations have run.
        tol: that tolerance; default :func:`default_tolerance` of the dtype.
        max_iter: the iteration cap when ``iterations`` is None.
        solution: the :func:`relaxed_qp_solve` solution of this very problem, to skip the
            iteration (e.g. to solve outside a gradient transform); None solves here.

    Returns:
        v: ``(..., nv)`` next velocity ``Q⁻¹b/h + Q⁻¹J̃ᵀβ/h²``; beta: ``(..., m)`` row impulses
        β > 0 (0 on dropped rows), with slack ``J̃v + φ̃/h = κ/β > 0``.
    """
    jac, phi, kappa = _checked_rows(
        Q, b, jac, phi, h, active, relaxation, iterations, max_iter, tol
    )
    if jac.shape[-2] == 0:  # no rows: the unconstrained minimizer
        v = metric_solver(Q, b)(b) / _batch_scalar(h)
        return v, phi.new_zeros(*v.shape[:-1], 0)
    inputs = [_detach(x) for x in (Q, b, jac, phi, h)]
    if solution is None:
        tol = default_tolerance(b.dtype) if tol is None else tol
        with torch.no_grad():
            solution = _solve(*inputs, kappa, iterations, tol, max_iter, compile_steps=False)
    v, s, beta = (x.detach() for x in solution)
    # One Newton step with the live inputs and J_F held at the solution: the IFT gradient.
    held = _Problem(*inputs, kappa)
    with torch.no_grad():
        factor, weight = held.factor(s, beta)
    r1, r2 = _Problem(Q, b, jac, phi, h, kappa).residuals(v, s, beta)
    dv, _, dbeta = held.newton(factor, weight, s, r1, r2, beta * s - kappa)
    v, beta = v + dv, beta + dbeta
    if active is not None:
        beta = beta * active.to(beta.dtype)
    return v, beta


__all__ = [
    "PAPER_RELAXATION",
    "RELAXATION",
    "RelaxedQPSolution",
    "default_tolerance",
    "paper_relaxation",
    "relaxed_qp_solve",
    "relaxed_qp_velocity",
]
