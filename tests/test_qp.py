"""The Anitescu QP baseline (OSQP): KKT conditions, SciPy agreement, and where CF equals it.

min_v ½h²vᵀQv − h vᵀb   s.t.   J̃v + φ̃/h ≥ 0,     v = Q⁻¹b/h + Q⁻¹J̃ᵀβ/h².
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
import torch

from torchcontact import AnitescuQP, ComplementarityFree, Contacts, cf_velocity, qp_solve
from torchcontact.functional import cf_multipliers
from torchcontact.qp import OSQP_SETTINGS


@pytest.fixture(autouse=True)
def _tight_osqp(monkeypatch):
    """These tests check KKT conditions to 1e-8, so OSQP runs 100× tighter than its default."""
    monkeypatch.setitem(OSQP_SETTINGS, "eps_abs", 1e-10)
    monkeypatch.setitem(OSQP_SETTINGS, "eps_rel", 1e-10)


F64 = torch.float64


def _problem(gen: torch.Generator, nv: int, m: int, dense: bool, batch=(), h: float = 0.1):
    """A feasible random QP: some rows slack, some tight at a feasible point, many binding."""
    if dense:
        A = torch.randn(*batch, nv, nv, generator=gen, dtype=F64)
        Q = A @ A.mT + 0.5 * torch.eye(nv, dtype=F64)
    else:
        Q = torch.rand(*batch, nv, generator=gen, dtype=F64) * 3 + 0.5
    b = torch.randn(*batch, nv, generator=gen, dtype=F64)
    jac = torch.randn(*batch, m, nv, generator=gen, dtype=F64)
    feasible = torch.randn(*batch, nv, generator=gen, dtype=F64)
    slack = torch.rand(*batch, m, generator=gen, dtype=F64) * (
        torch.rand(*batch, m, generator=gen, dtype=F64) > 0.5
    )
    phi = h * (slack - (jac @ feasible.unsqueeze(-1)).squeeze(-1))
    return Q, b, jac, phi, h


def _full(Q: np.ndarray) -> np.ndarray:
    return Q if Q.ndim == 2 else np.diag(Q)


def _assert_kkt(Q, b, jac, phi, h, v, beta, tol=1e-8):
    """Stationarity, primal and dual feasibility and complementarity of one problem."""
    Q, b, jac, phi, v, beta = (x.double().numpy() for x in (Q, b, jac, phi, v, beta))
    stationarity = h * h * _full(Q) @ v - h * b - jac.T @ beta
    gap = jac @ v + phi / h
    scale = 1 + np.abs(b).max() + np.abs(beta).max()
    assert np.abs(stationarity).max() < tol * scale
    assert gap.min() > -tol * scale
    assert beta.min() > -1e-9
    assert np.abs(beta * gap).max() < tol * scale


@pytest.mark.parametrize("dense", [False, True])
@pytest.mark.parametrize("nv, m", [(3, 2), (6, 10), (8, 24)])
def test_kkt_conditions(dense, nv, m):
    gen = torch.Generator().manual_seed(nv * 100 + m + dense)
    binding = 0
    for _ in range(3):
        Q, b, jac, phi, h = _problem(gen, nv, m, dense)
        v, beta = qp_solve(Q, b, jac, phi, h)
        assert v.shape == (nv,) and beta.shape == (m,)
        _assert_kkt(Q, b, jac, phi, h, v, beta)
        torch.testing.assert_close(v, _qp_velocity(Q, b, jac, beta, h), rtol=1e-8, atol=1e-8)
        binding += int((beta > 1e-6).sum())
    assert binding > 0  # some constraints really bind


def _qp_velocity(Q, b, jac, beta, h):
    """v = Q⁻¹b/h + Q⁻¹J̃ᵀβ/h², the QP's velocity in terms of its multipliers."""
    Qf = Q if Q.dim() == 2 else torch.diag(Q)
    return torch.linalg.solve(Qf, b / h + jac.mT @ beta / h**2)


@pytest.mark.parametrize("dense", [False, True])
def test_batches_equal_single_solves(dense):
    gen = torch.Generator().manual_seed(11)
    Q, b, jac, phi, _ = _problem(gen, 5, 7, dense, batch=(2, 3))
    h = torch.tensor([[0.05, 0.1, 0.2], [0.1, 0.3, 0.02]], dtype=F64)
    v, beta = qp_solve(Q, b, jac, phi, h)
    assert v.shape == (2, 3, 5) and beta.shape == (2, 3, 7)
    for i in range(2):
        for j in range(3):
            one = qp_solve(Q[i, j], b[i, j], jac[i, j], phi[i, j], float(h[i, j]))
            torch.testing.assert_close(v[i, j], one[0], rtol=1e-9, atol=1e-9)
            torch.testing.assert_close(beta[i, j], one[1], rtol=1e-9, atol=1e-9)
            _assert_kkt(Q[i, j], b[i, j], jac[i, j], phi[i, j], float(h[i, j]), v[i, j], beta[i, j])


def test_shared_metric_and_rows_broadcast_over_a_batch():
    gen = torch.Generator().manual_seed(12)
    Q, _, jac, phi, h = _problem(gen, 4, 6, dense=True)
    b = torch.randn(3, 4, generator=gen, dtype=F64) * 5
    v, beta = qp_solve(Q.unsqueeze(0), b, jac, phi, h)
    assert v.shape == (3, 4) and beta.shape == (3, 6)
    for i in range(3):
        _assert_kkt(Q, b[i], jac, phi, h, v[i], beta[i])


def test_matches_scipy():
    gen = torch.Generator().manual_seed(13)
    Q, b, jac, phi, h = _problem(gen, 4, 6, dense=True)
    v, _ = qp_solve(Q, b, jac, phi, h)
    Qn, bn, jn, pn = (x.numpy() for x in (Q, b, jac, phi))
    result = scipy.optimize.minimize(
        lambda x: 0.5 * h * h * x @ Qn @ x - h * x @ bn,
        np.zeros(4),
        jac=lambda x: h * h * Qn @ x - h * bn,
        constraints=[{"type": "ineq", "fun": lambda x: jn @ x + pn / h, "jac": lambda x: jn}],
        method="SLSQP",
        options={"ftol": 1e-14, "maxiter": 500},
    )
    assert result.success
    np.testing.assert_allclose(v.numpy(), result.x, rtol=0, atol=1e-6)
    assert (jn @ result.x + pn / h).min() < 1e-6  # the constraint binds: not a free minimum


def test_inactive_rows_are_dropped_with_zero_impulse():
    gen = torch.Generator().manual_seed(14)
    Q, b, jac, phi, h = _problem(gen, 5, 8, dense=False)
    active = torch.tensor([True, False, True, True, False, True, False, True])
    v, beta = qp_solve(Q, b, jac, phi, h, active=active)
    assert torch.all(beta[~active] == 0)
    kept = qp_solve(Q, b, jac[active], phi[active], h)
    torch.testing.assert_close(v, kept[0], rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(beta[active], kept[1], rtol=1e-9, atol=1e-9)
    _assert_kkt(Q, b, jac[active], phi[active], h, v, beta[active])
    # A dropped row may be violated: it really is ignored.
    violated = jac.clone()
    violated[1] = -torch.linalg.solve(torch.diag(Q), b)  # row 1: Jv is negative at v ≈ Q⁻¹b/h
    phi = phi.clone()
    phi[1] = -10.0
    v2, beta2 = qp_solve(Q, b, violated, phi, h, active=active)
    torch.testing.assert_close(v2, v, rtol=1e-9, atol=1e-9)
    assert float(violated[1] @ v2 + phi[1] / h) < 0
    # No row active: the unconstrained minimizer Q⁻¹b/h.
    none_v, none_beta = qp_solve(Q, b, jac, phi, h, active=torch.zeros(8, dtype=torch.bool))
    torch.testing.assert_close(none_v, b / Q / h)
    assert torch.all(none_beta == 0)


@pytest.mark.parametrize("batch", [(), (3,)])
def test_no_rows_gives_the_free_minimizer(batch):
    """Zero constraint rows (e.g. a scene with zero contact slots): v = Q⁻¹b/h, β empty."""
    gen = torch.Generator().manual_seed(20)
    Q, b, jac, phi, h = _problem(gen, 4, 0, dense=True, batch=batch)
    v, beta = qp_solve(Q, b, jac, phi, h)
    assert v.shape == (*batch, 4) and beta.shape == (*batch, 0)
    torch.testing.assert_close(v, torch.linalg.solve(Q, b) / h)


@pytest.mark.parametrize("which", ["Q", "b", "jac", "phi", "h"])
def test_tensor_requiring_grad_raises(which):
    gen = torch.Generator().manual_seed(15)
    args = dict(zip(["Q", "b", "jac", "phi", "h"], _problem(gen, 3, 2, dense=False), strict=True))
    args["h"] = torch.tensor(args["h"], dtype=F64)
    args[which] = args[which].clone().requires_grad_(True)
    with pytest.raises(ValueError, match="not differentiable"):
        qp_solve(**args)
    with torch.no_grad():
        qp_solve(**args)


def test_unsolved_problems_raise():
    Q = torch.ones(2, dtype=F64)
    b = torch.zeros(2, dtype=F64)
    jac = torch.tensor([[1.0, 0.0], [-1.0, 0.0]], dtype=F64)
    phi = torch.tensor([-1.0, -1.0], dtype=F64)  # v₀ ≥ 10 and v₀ ≤ −10: infeasible
    with pytest.raises(RuntimeError, match="OSQP"):
        qp_solve(Q, b, jac, phi, 0.1)
    gen = torch.Generator().manual_seed(16)
    with pytest.raises(RuntimeError, match="OSQP"):
        qp_solve(*_problem(gen, 6, 12, dense=True), settings={"max_iter": 1, "polishing": False})


def _contacts(gen: torch.Generator, nc: int, nv: int, active, batch=()) -> Contacts:
    active = torch.as_tensor(active).expand(*batch, nc)
    frame_rows = torch.randn(*batch, nc, 3, nv, generator=gen, dtype=F64)
    return Contacts(
        phi=torch.where(
            active, torch.rand(*batch, nc, generator=gen, dtype=F64) * 0.02 - 0.01, 1.0
        ),
        jac_normal=frame_rows[..., 0, :] * active[..., None],
        jac_tangent=frame_rows[..., 1:, :] * active[..., None, None],
        mu=torch.rand(*batch, nc, generator=gen, dtype=F64) * active,
        active=active,
    )


def test_anitescu_model_on_contacts():
    """Row impulses satisfy the KKT conditions of the dual-cone rows; forces lie in the cone."""
    gen = torch.Generator().manual_seed(17)
    nv, h = 6, 0.05
    contacts = _contacts(gen, 4, nv, [True, True, True, False], batch=(2,))
    A = torch.randn(2, nv, nv, generator=gen, dtype=F64)
    Q = A @ A.mT + torch.eye(nv, dtype=F64)
    b = torch.randn(2, nv, generator=gen, dtype=F64) * 3
    model = AnitescuQP(facets=4)
    v, beta = model.row_impulses(Q, b, contacts, h)
    assert v.shape == (2, nv) and beta.shape == (2, 16)
    assert torch.all(beta[:, 12:] == 0)  # the padding slot's rows
    jac, phi, _ = contacts.dual_rows(4)
    for i in range(2):
        _assert_kkt(Q[i], b[i], jac[i], phi[i], h, v[i], beta[i])
    normal, friction = model.impulses(Q, b, contacts, h)
    assert float(normal.sum()) > 0
    assert torch.all(friction.norm(dim=-1) <= contacts.mu * normal + 1e-9)
    torch.testing.assert_close(model(Q, b, contacts, h), v)


@pytest.mark.parametrize("dense", [False, True])
@pytest.mark.parametrize("gap", [-0.02, 0.003, 0.5])
def test_exact_cf_equals_qp_on_one_row(dense, gap):
    """One row j: the QP's β = max(−h(φ + jQ⁻¹b)/(jQ⁻¹jᵀ), 0); exact CF gives
    hλ = h·max(−K(jQ⁻¹b + φ), 0), the same when K = 1/(jQ⁻¹jᵀ)."""
    gen = torch.Generator().manual_seed(18)
    Q, b, jac, _, h = _problem(gen, 5, 1, dense)
    phi = torch.tensor([gap], dtype=F64)
    Qf = Q if dense else torch.diag(Q)
    effective = float(jac[0] @ torch.linalg.solve(Qf, jac[0]))  # jQ⁻¹jᵀ
    free_gap = float(jac[0] @ torch.linalg.solve(Qf, b)) + gap  # jQ⁻¹b + φ
    v_qp, beta_qp = qp_solve(Q, b, jac, phi, h)
    assert float(beta_qp[0]) == pytest.approx(max(-h * free_gap / effective, 0), abs=1e-9)
    lam, _ = cf_multipliers(Q, b, jac, phi, h, 1 / effective, gamma=None)
    v_cf = cf_velocity(Q, b, jac, phi, h, 1 / effective, gamma=None)
    torch.testing.assert_close(h * lam, beta_qp, rtol=1e-8, atol=1e-10)
    torch.testing.assert_close(v_cf, v_qp, rtol=1e-8, atol=1e-9)
    # Any other K changes a binding contact's answer.
    if free_gap < 0:
        stiffer = cf_velocity(Q, b, jac, phi, h, 2 / effective, gamma=None)
        assert float((stiffer - v_qp).abs().max()) > 1e-3


def _frictionless_contact(jac_normal: torch.Tensor, phi: float) -> Contacts:
    nv = jac_normal.shape[-1]
    return Contacts(
        phi=torch.tensor([phi], dtype=F64),
        jac_normal=jac_normal.reshape(1, nv),
        jac_tangent=torch.randn(1, 2, nv, dtype=F64),  # irrelevant with μ = 0
        mu=torch.zeros(1, dtype=F64),
        active=torch.ones(1, dtype=torch.bool),
    )


@pytest.mark.parametrize("facets", [3, 4, 8])
def test_frictionless_contact_models_agree(facets):
    """μ = 0: the n_d rows coincide; CF with K = 1/(n_d·jQ⁻¹jᵀ) matches the QP's velocity and
    total normal impulse, and a far contact leaves both at the free ``Q⁻¹b/h`` for any K."""
    gen = torch.Generator().manual_seed(19)
    Q, b, jac, _, h = _problem(gen, 6, 1, dense=True)
    effective = float(jac[0] @ torch.linalg.solve(Q, jac[0]))
    free_gap = float(jac[0] @ torch.linalg.solve(Q, b))
    penetrating = _frictionless_contact(jac[0], -free_gap - 0.01)
    qp = AnitescuQP(facets=facets)
    cf = ComplementarityFree(stiffness=1 / (facets * effective), gamma=None, facets=facets)
    v_qp = qp(Q, b, penetrating, h)
    v_cf = cf(Q, b, penetrating, h).detach()
    torch.testing.assert_close(v_cf, v_qp, rtol=1e-8, atol=1e-9)
    n_qp = qp.impulses(Q, b, penetrating, h)[0]
    n_cf = cf.impulses(Q, b, penetrating, h)[0].detach()
    assert float(n_qp) > 1e-4
    torch.testing.assert_close(n_cf, n_qp, rtol=1e-8, atol=1e-10)

    far = _frictionless_contact(jac[0], abs(free_gap) + 0.5)
    free = torch.linalg.solve(Q, b) / h
    stiff = ComplementarityFree(stiffness=1e6, gamma=None, facets=facets)
    torch.testing.assert_close(stiff(Q, b, far, h).detach(), free, rtol=1e-12, atol=1e-12)
    v_far, beta_far = qp.row_impulses(Q, b, far, h)
    torch.testing.assert_close(v_far, free, rtol=1e-9, atol=1e-9)
    assert float(beta_far.abs().max()) < 1e-9


# Bad input: the QP raises the ValueError the complementarity-free step raises for it.
def _eye(nv=3):
    return torch.eye(nv, dtype=F64)


BAD_QP_INPUTS = [
    ("Q", lambda Q: Q.index_fill(-1, torch.tensor([1]), 0.0), r"^Q \(diagonal\) must be positive"),
    ("Q", lambda Q: Q.index_fill(-1, torch.tensor([1]), -1.0), r"^Q \(diagonal\) must be positive"),
    ("Q", lambda Q: Q.index_fill(-1, torch.tensor([0]), np.nan), r"^Q \(diagonal\) must be finite"),
    ("Q", lambda Q: torch.diag_embed(Q) - 5 * _eye(), "^Q must be symmetric positive definite"),
    ("Q", lambda Q: torch.diag_embed(Q) + torch.triu(torch.ones(3, 3, dtype=F64), 1), "^Q must"),
    ("Q", lambda Q: torch.diag_embed(Q).index_fill(-1, torch.tensor([0]), np.nan), "^Q must be"),
    ("b", lambda b: b.index_fill(-1, torch.tensor([0]), np.nan), "^b must be finite"),
    ("h", -0.1, "^h must be positive"),
    ("h", lambda h: torch.full((2, 1), 0.1, dtype=F64), "^h must broadcast"),
    ("jac", lambda J: J.float(), "^jac must have the dtype of b"),
]


def _qp_args(name, value, m=2):
    gen = torch.Generator().manual_seed(18)
    Q, b, jac, phi, h = _problem(gen, 3, m, dense=False, batch=(2,))
    args = dict(Q=Q, b=b, jac=jac, phi=phi, h=h)
    args[name] = value(args[name]) if callable(value) else value
    return args


@pytest.mark.parametrize("m", [0, 2])
@pytest.mark.parametrize("name, value, match", BAD_QP_INPUTS)
def test_bad_input_raises_as_the_complementarity_free_step_does(name, value, match, m):
    args = _qp_args(name, value, m)
    with pytest.raises(ValueError, match=match) as cf_error:
        cf_velocity(**args, stiffness=1.0)
    with pytest.raises(ValueError, match=match) as qp_error:
        qp_solve(**args)
    assert str(qp_error.value) == str(cf_error.value)


def test_the_qp_model_checks_its_metric():
    gen = torch.Generator().manual_seed(19)
    contacts = _contacts(gen, 2, 3, [True, False])
    model = AnitescuQP()
    with pytest.raises(ValueError, match=r"^Q \(diagonal\) must be positive"):
        model(torch.tensor([1.0, 0.0, 1.0], dtype=F64), torch.ones(3, dtype=F64), contacts, 0.1)
    singular = torch.tensor([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]], dtype=F64)
    with pytest.raises(ValueError, match="^Q must be symmetric positive definite"):
        model(singular, torch.ones(3, dtype=F64), Contacts.empty(2, 3, dtype=F64), 0.1)
