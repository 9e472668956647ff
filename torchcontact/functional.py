"""The complementarity-free contact step as pure tensor functions (no MuJoCo, no NumPy).

Notation (Jin 2024): ``Q`` the metric of the step's quadratic program, ``b`` its linear term,
``jac`` the dual-cone rows J̃ (one per contact and friction facet), ``phi`` the row distances φ̃,
``h`` the time step. Every function broadcasts over any leading batch dimensions ``...``.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F

from torchcontact.validation import (
    check_broadcasts_to,
    check_finite,
    check_nonnegative,
    check_positive,
    check_same_kind,
    check_shape,
    check_tensor,
    checking_values,
)

Scalar = float | torch.Tensor


def softplus(x: torch.Tensor, gamma: float | None) -> torch.Tensor:
    """Smooth ``max(x, 0)``: ``log(1 + exp(γx)) / γ``; the exact ``max(x, 0)`` when γ is None.

    Never overflows: past ``γx > 20`` it is ``x`` itself (the two differ by < 1e-9·|x|), and
    its gradient is ``sigmoid(γx)``, computed without forming ``exp(γx)`` for large ``γx``.
    """
    if gamma is None:
        return torch.relu(x)
    return F.softplus(x, beta=gamma, threshold=20.0)


def is_dense_metric(Q: torch.Tensor, b: torch.Tensor) -> bool:
    """Whether ``Q`` is a dense ``(..., nv, nv)`` matrix rather than a ``(..., nv)`` diagonal.

    ``Q`` is dense when it has more dimensions than ``b``, or when its last two dimensions are
    ``(nv, nv)`` and its batch shape differs from ``b``'s. A batch of diagonals shaped like ``b``
    stays diagonal even if its last batch size equals nv; to share one dense ``Q`` over such a
    batch give it a leading singleton dimension.
    """
    nv = b.shape[-1]
    if Q.dim() > b.dim():
        return True
    square = Q.dim() >= 2 and Q.shape[-2:] == (nv, nv)
    return square and Q.shape[:-1] != b.shape[:-1]


def _check_metric_entries(Q: torch.Tensor, b: torch.Tensor) -> bool:
    """Check what can be read of ``Q`` without factorizing it; return whether it is dense."""
    if not is_dense_metric(Q, b):
        check_positive("Q (diagonal)", Q)
        return False
    if checking_values(Q):
        check_finite("Q", Q)
        scale = Q.detach().abs().amax(dim=(-2, -1), keepdim=True).clamp_min(1e-300)
        asym = (Q.detach() - Q.detach().mT).abs() / scale
        if bool((asym > 1e-6).any()):
            raise ValueError("Q must be symmetric positive definite, got a non-symmetric matrix")
    return True


def _check_factorization(info: torch.Tensor) -> None:
    """Raise ``ValueError`` naming ``Q`` when ``cholesky_ex``'s ``info`` reports a failure."""
    if checking_values(info) and bool((info != 0).any()):
        raise ValueError("Q must be symmetric positive definite, Cholesky failed")


def check_metric(Q: torch.Tensor, b: torch.Tensor) -> None:
    """Raise ``ValueError`` naming ``Q`` unless it is a positive diagonal or an SPD matrix:
    the checks of :func:`metric_solver`, for solvers that do not factorize ``Q`` themselves."""
    if _check_metric_entries(Q, b) and checking_values(Q):
        _check_factorization(torch.linalg.cholesky_ex(Q.detach())[1])


def metric_solver(Q: torch.Tensor, b: torch.Tensor):
    """Return ``x ↦ Q⁻¹x`` for ``x: (..., nv)``; factorizes a dense ``Q`` once (Cholesky).

    Raises ``ValueError`` naming ``Q`` when it is not symmetric positive definite.
    """
    if not _check_metric_entries(Q, b):
        return lambda x: x / Q
    factor, info = torch.linalg.cholesky_ex(Q)
    _check_factorization(info)
    return lambda x: torch.cholesky_solve(x.unsqueeze(-1), factor).squeeze(-1)


def _step_batch(Q, b, jac, phi) -> tuple[torch.Size, int]:
    """Check the types, kinds and shapes of ``Q, b, jac, phi``; return their batch shape and m."""
    tensors = {"Q": Q, "b": b, "jac": jac, "phi": phi}
    for name, x in tensors.items():
        check_tensor(name, x)
    check_same_kind("b", tensors)
    check_shape("b", b, "(..., nv)", b.dim() >= 1)
    nv = b.shape[-1]
    check_shape(
        "jac", jac, f"(..., m, nv={nv}), nv that of b {tuple(b.shape)}",
        jac.dim() >= 2 and jac.shape[-1] == nv,
    )  # fmt: skip
    m = jac.shape[-2]
    check_shape("phi", phi, f"(..., m={m})", phi.dim() >= 1 and phi.shape[-1] == m)
    dense = is_dense_metric(Q, b)
    expected = f"(..., nv={nv}, nv={nv})" if dense else f"(..., nv={nv})"
    ok = Q.shape[-2:] == (nv, nv) if dense else Q.dim() >= 1 and Q.shape[-1] == nv
    check_shape("Q", Q, expected, ok)
    batches = {
        "Q": Q.shape[:-2] if dense else Q.shape[:-1],
        "b": b.shape[:-1],
        "jac": jac.shape[:-2],
        "phi": phi.shape[:-1],
    }
    try:
        return torch.broadcast_shapes(*batches.values()), m
    except RuntimeError:
        shapes = ", ".join(f"{k}{tuple(v)}" for k, v in batches.items())
        raise ValueError(
            f"batch shapes of Q, b, jac and phi must broadcast, got {shapes}"
        ) from None


def _check_step_inputs(Q, b, jac, phi, h, stiffness, damping, gamma) -> None:
    """Check a step's arguments, raising ``ValueError`` (``TypeError`` for non-tensors) naming
    the bad one. ``h``, ``stiffness`` and ``damping`` must broadcast to the batch shape of
    ``Q, b, jac, phi`` (and its rows) without enlarging it, and lie on ``b``'s device."""
    batch, m = _step_batch(Q, b, jac, phi)
    scalars = {"h": h, "stiffness": stiffness, "damping": damping}
    for name, x in {**scalars, "gamma": gamma}.items():
        number = isinstance(x, (int, float)) and not isinstance(x, bool)
        if not (number or isinstance(x, torch.Tensor) or (x is None and name != "h")):
            raise TypeError(f"{name} must be a number or a torch.Tensor, got {x!r}")
    for name, x in scalars.items():
        if isinstance(x, torch.Tensor):
            target = batch if name == "h" else (*batch, m)
            check_broadcasts_to(name, x, target, "the batch shape of Q, b, jac and phi")
    dimensioned = {k: x for k, x in scalars.items() if isinstance(x, torch.Tensor) and x.dim()}
    check_same_kind("b", {"b": b, **dimensioned}, dtype=False)
    for name, x in (("b", b), ("jac", jac), ("phi", phi)):
        check_finite(name, x)
    check_positive("h", h)
    check_nonnegative("stiffness", stiffness)
    if damping is not None:
        check_nonnegative("damping", damping)
    if gamma is not None:
        check_positive("gamma", gamma)


def _matvec(A: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    return (A @ x.unsqueeze(-1)).squeeze(-1)


def _batch_scalar(h: Scalar) -> Scalar:
    """``h`` of shape ``(...)`` as ``(..., 1)`` so it broadcasts against ``(..., n)``."""
    return h.unsqueeze(-1) if isinstance(h, torch.Tensor) and h.dim() > 0 else h


def cf_multipliers(
    Q: torch.Tensor,
    b: torch.Tensor,
    jac: torch.Tensor,
    phi: torch.Tensor,
    h: Scalar,
    stiffness: Scalar,
    damping: Scalar | None = None,
    gamma: float | None = 100.0,
) -> tuple[torch.Tensor, Callable[[torch.Tensor], torch.Tensor]]:
    """λ = softplus_γ(−K(J̃Q⁻¹b + φ̃) − D·J̃Q⁻¹b/h), shape ``(..., m)``, and the ``Q⁻¹`` solver.

    Arguments as in :func:`cf_velocity`. λ·h is the impulse along each dual-cone row.
    """
    _check_step_inputs(Q, b, jac, phi, h, stiffness, damping, gamma)
    solve = metric_solver(Q, b)
    lam = _row_multipliers(jac, phi, _batch_scalar(h), stiffness, damping, gamma, solve(b))
    return lam, solve


def _row_multipliers(jac, phi, h_rows, stiffness, damping, gamma, free_motion) -> torch.Tensor:
    """λ = softplus_γ(−K(J̃x + φ̃) − D·J̃x/h) of every row for the motion ``x = Q⁻¹b``."""
    gap_change = _matvec(jac, free_motion)  # J̃Q⁻¹b: row-distance change without contact [m]
    argument = -stiffness * (gap_change + phi)
    if damping is not None:
        argument = argument - damping * gap_change / h_rows
    return softplus(argument, gamma)


def cf_velocity(
    Q: torch.Tensor,
    b: torch.Tensor,
    jac: torch.Tensor,
    phi: torch.Tensor,
    h: Scalar,
    stiffness: Scalar,
    damping: Scalar | None = None,
    gamma: float | None = 100.0,
) -> torch.Tensor:
    """Next velocity of the complementarity-free model, ``(..., nv)``.

    v = Q⁻¹b/h + Q⁻¹J̃ᵀλ/h,  λ = softplus_γ(−K(J̃Q⁻¹b + φ̃) − D·J̃Q⁻¹b/h).

    Every row's λ answers the motion without contact, Q⁻¹b, so a row never answers another
    row's force.

    Args:
        Q: ``(..., nv)`` positive diagonal or ``(..., nv, nv)`` SPD metric
            (quasi-dynamic ``diag(εMₒ/h², Kᵣ)``, full-dynamic ``M/h²``); see
            :func:`is_dense_metric` for how the two are told apart.
        b: ``(..., nv)`` linear term (forces, ``Kᵣu``, ``Mv/h``).
        jac: ``(..., m, nv)`` dual-cone rows J̃ (``Jⁿ + μJᵈ`` per contact and facet).
        phi: ``(..., m)`` row distances φ̃ [m] (each contact distance repeated per facet).
        h: time step [s], a float or a tensor broadcastable to the batch shape ``(...)``.
        stiffness: K ≥ 0, a float or a tensor broadcastable to ``(..., m)``.
        damping: D ≥ 0 like ``stiffness``, or None for no damping.

    The batch shape ``...`` is that of ``Q``, ``b``, ``jac`` and ``phi`` broadcast together:
    ``h``, ``stiffness`` and ``damping`` may not enlarge it (a ``ValueError`` names them), and
    ``Q``, ``jac`` and ``phi`` must share ``b``'s dtype and device.
        gamma: softplus sharpness γ > 0 [1/m-ish units of λ]; None for the exact ``max(·, 0)``.

    Returns:
        v⁺: ``(..., nv)`` next generalized velocity.
    """
    lam, solve = cf_multipliers(Q, b, jac, phi, h, stiffness, damping, gamma)
    return velocity_from_multipliers(solve, b, jac, lam, h)


def velocity_from_multipliers(solve, b, jac, lam, h: Scalar) -> torch.Tensor:
    """``v = Q⁻¹(b + J̃ᵀλ)/h`` given the ``Q⁻¹`` solver of :func:`metric_solver`."""
    return solve(b + _matvec(jac.mT, lam)) / _batch_scalar(h)
