"""The Anitescu QP contact model, the baseline the closed form replaces, solved by OSQP.

    min_v ½h²vᵀQv − h vᵀb   s.t.   J̃v + φ̃/h ≥ 0

Its multipliers β ≥ 0 are the row impulses, ``v = Q⁻¹b/h + Q⁻¹J̃ᵀβ/h²``. Solved one problem at
a time on the CPU in float64 with tight tolerances; not differentiable (yet).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import osqp
import scipy.sparse as sparse
import torch

from torchcontact.functional import Scalar, _check_step_inputs, check_metric, is_dense_metric
from torchcontact.validation import check_shape

OSQP_SETTINGS = {
    "verbose": False,
    "eps_abs": 1e-8,
    "eps_rel": 1e-8,
    "max_iter": 200_000,
    "polishing": False,  # the tolerances are tight already; polishing also prints to stdout
}


def _solve_one(Q, b, jac, phi, h, settings) -> tuple[np.ndarray, np.ndarray]:
    m = phi.shape[0]
    metric = Q if Q.ndim == 2 else np.diag(Q)
    P = sparse.csc_matrix(np.triu(h * h * metric))
    if m == 0:  # no constraint: the unconstrained minimizer
        return np.linalg.solve(metric, b) / h, np.zeros(0)
    solver = osqp.OSQP()
    solver.setup(P, -h * b, sparse.csc_matrix(jac), -phi / h, np.full(m, np.inf), **settings)
    result = solver.solve(raise_error=False)
    if result.info.status_val != osqp.SolverStatus.OSQP_SOLVED:
        raise RuntimeError(f"OSQP did not solve the contact QP: status {result.info.status!r}")
    return result.x, -result.y  # OSQP's y ≤ 0 on active lower bounds; β = −y


def qp_solve(
    Q: torch.Tensor,
    b: torch.Tensor,
    jac: torch.Tensor,
    phi: torch.Tensor,
    h: Scalar,
    active: torch.Tensor | None = None,
    settings: dict | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Solve the Anitescu QP for each batch element.

    Args: as :func:`torchcontact.functional.cf_velocity`, plus ``active: (..., m)`` bool rows to
    keep (the rest are dropped, their β is 0) and OSQP ``settings`` overriding
    :data:`OSQP_SETTINGS`.

    Returns:
        v: ``(..., nv)`` next velocity; beta: ``(..., m)`` row impulses β ≥ 0.

    Raises ``ValueError`` naming the bad argument, as the complementarity-free step does for
    the same inputs (a ``Q`` that is not a positive diagonal nor SPD among them).
    """
    _check_step_inputs(Q, b, jac, phi, h, 1.0, None, None)
    check_metric(Q, b)
    if torch.is_grad_enabled() and any(
        isinstance(x, torch.Tensor) and x.requires_grad for x in (Q, b, jac, phi, h)
    ):
        raise ValueError(
            "the QP model is not differentiable: call it on tensors without requires_grad "
            "(or under torch.no_grad())"
        )
    nv, m = b.shape[-1], jac.shape[-2]
    dense = is_dense_metric(Q, b)
    q_batch = Q.shape[:-2] if dense else Q.shape[:-1]
    h_t = torch.as_tensor(h, dtype=torch.float64)
    if active is None:
        active = torch.ones(phi.shape, dtype=torch.bool)
    if not isinstance(active, torch.Tensor) or active.dtype != torch.bool:
        found = active.dtype if isinstance(active, torch.Tensor) else type(active).__name__
        raise ValueError(f"active must be a bool tensor of shape (..., {m}), got {found}")
    check_shape("active", active, f"(..., {m})", active.dim() >= 1 and active.shape[-1] == m)
    batch = torch.broadcast_shapes(
        q_batch, b.shape[:-1], jac.shape[:-2], phi.shape[:-1], active.shape[:-1], h_t.shape
    )

    def flat(x, tail):
        return (
            x.detach()
            .to("cpu", torch.float64)
            .expand(*batch, *tail)
            .reshape(math.prod(batch), *tail)
            .numpy()
        )

    Qs = flat(Q, (nv, nv) if dense else (nv,))
    bs, js, ps = flat(b, (nv,)), flat(jac, (m, nv)), flat(phi, (m,))
    keep = active.to("cpu").expand(*batch, m).reshape(math.prod(batch), m).numpy()
    hs = h_t.expand(batch).reshape(-1).numpy()
    v = np.zeros((bs.shape[0], nv))
    beta = np.zeros((bs.shape[0], m))
    if settings is not None and not isinstance(settings, Mapping):
        raise TypeError(
            f"settings must be a mapping of OSQP settings, got {type(settings).__name__}"
        )
    options = {**OSQP_SETTINGS, **(settings or {})}
    for i in range(bs.shape[0]):
        rows = keep[i]
        v[i], beta[i, rows] = _solve_one(Qs[i], bs[i], js[i][rows], ps[i][rows], hs[i], options)
    out = {"dtype": b.dtype, "device": b.device}
    return torch.from_numpy(v).reshape(*batch, nv).to(**out), torch.from_numpy(beta).reshape(
        *batch, m
    ).to(**out)
