"""The relaxed QP: agreement with OSQP as κ → 0, the relaxed KKT conditions, IFT gradients
against finite differences of OSQP and gradcheck, batching, padding, dtypes and errors.

min_v ½h²vᵀQv − h vᵀb − κ Σ log(J̃v + φ̃/h),   i.e. the Anitescu QP with β∘s = κ.
"""

from __future__ import annotations

import itertools
import math

import pytest
import torch
from conftest import cuda_or_skip
from hypothesis import given, settings
from hypothesis import strategies as st
from test_contacts import random_contacts

from torchcontact import QuasiDynamic, RelaxedQP, contact_model, qp_solve, relaxed_qp_velocity
from torchcontact.qp import OSQP_SETTINGS
from torchcontact.relaxed_qp import (
    PAPER_RELAXATION,
    RELAXATION,
    paper_relaxation,
    relaxed_qp_solve,
)

F64 = torch.float64


@pytest.fixture(autouse=True)
def _tight_osqp(monkeypatch):
    """OSQP is the reference here: 100× tighter than the library's default tolerance."""
    monkeypatch.setitem(OSQP_SETTINGS, "eps_abs", 1e-10)
    monkeypatch.setitem(OSQP_SETTINGS, "eps_rel", 1e-10)


def _problem(gen, nv, m, dense, batch=(), h=0.1, scale=1.0, dtype=F64):
    """A random QP with a strictly feasible point (every row slack there, by 0.05–1.05·scale)."""

    def draw(*shape, fn=torch.randn):
        return fn(*batch, *shape, generator=gen, dtype=F64)

    if dense:
        A = draw(nv, nv)
        Q = A @ A.mT + 0.5 * torch.eye(nv, dtype=F64)
    else:
        Q = 0.5 + 3 * draw(nv, fn=torch.rand)
    b, jac = scale * draw(nv), draw(m, nv)
    interior, slack = scale * draw(nv), scale * (0.05 + draw(m, fn=torch.rand))
    phi = h * (slack - (jac @ interior.unsqueeze(-1)).squeeze(-1))
    return tuple(x.to(dtype) for x in (Q, b, jac, phi)) + (h,)


def _metric_times(Q, v):
    return (Q @ v.unsqueeze(-1)).squeeze(-1) if Q.dim() > v.dim() else Q * v


def _relaxed_kkt(Q, b, jac, phi, h, v, beta, kappa):
    """Relative stationarity residual, slacks s = J̃v + φ̃/h and ``|β∘s − κ|`` over its bound.

    s is a difference of terms up to |J̃v| + |φ̃/h| in size, so it carries a rounding error
    proportional to them: the bound on ``|β∘s − κ|`` is 1e-6·κ plus β times that error.
    """
    stationarity = h * h * _metric_times(Q, v) - h * b - (jac.mT @ beta.unsqueeze(-1)).squeeze(-1)
    scale = (h * b).abs().amax() + (h * h * _metric_times(Q, v)).abs().amax()
    Jv = (jac @ v.unsqueeze(-1)).squeeze(-1)
    s = Jv + phi / h
    rounding = 1e-13 * ((jac.abs() @ v.abs().unsqueeze(-1)).squeeze(-1) + (phi / h).abs())
    bound = 1e-6 * kappa + beta * rounding
    return stationarity.abs().amax() / scale, s, (beta * s - kappa).abs() / bound


@pytest.mark.parametrize("dense", [False, True])
def test_matches_osqp_as_the_relaxation_vanishes(dense):
    gen = torch.Generator().manual_seed(1)
    Q, b, jac, phi, h = _problem(gen, 6, 10, dense, batch=(4,))
    v_qp, beta_qp = qp_solve(Q, b, jac, phi, h)
    assert int((beta_qp > 1e-3).sum()) >= 4  # rows really bind
    v, beta = relaxed_qp_velocity(Q, b, jac, phi, h, relaxation=1e-10)
    torch.testing.assert_close(v, v_qp, rtol=0, atol=1e-6)
    torch.testing.assert_close(beta, beta_qp, rtol=0, atol=1e-6)
    # The error shrinks with κ; at the default κ it is within 10% of |v| on unit-scale problems.
    errors = [
        float((relaxed_qp_velocity(Q, b, jac, phi, h, relaxation=k)[0] - v_qp).abs().max())
        for k in (RELAXATION, 1e-4, 1e-6, 1e-8)
    ]
    assert errors[1] > 10 * errors[2] > 100 * errors[3]
    assert errors[0] < 0.1 * float(v_qp.abs().max())


def test_paper_relaxation_is_the_papers_complementarity_in_its_scaling():
    """The paper's code writes the QP as min ½vᵀQv − vᵀb/h, g = J̃v + φ̃/h ≥ 0, λ∘g = κ: with
    κ converted by paper_relaxation, λ = β/h² meets its relaxed KKT conditions."""
    gen = torch.Generator().manual_seed(5)
    for h in (0.1, 0.02):
        Q, b, jac, phi, _ = _problem(gen, 5, 8, False, h=h)
        v, beta = relaxed_qp_velocity(Q, b, jac, phi, h, relaxation=paper_relaxation(h))
        lam, g = beta / h**2, jac @ v + phi / h
        torch.testing.assert_close(lam * g, torch.full_like(g, PAPER_RELAXATION), rtol=1e-6, atol=0)
        stationarity = Q * v - b / h - jac.mT @ lam
        assert float(stationarity.abs().max()) < 1e-8 * float((b / h).abs().max())
    assert paper_relaxation(0.1) == pytest.approx(RELAXATION)
    with pytest.raises(ValueError, match="relaxation"):
        paper_relaxation(0.1, -1.0)


@settings(max_examples=100, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    nv=st.integers(1, 7),
    m=st.integers(1, 12),
    dense=st.booleans(),
    log_kappa=st.floats(-9.0, -1.0),
    log_scale=st.floats(-2.0, 2.0),
    log_h=st.floats(-3.0, -0.5),
)
def test_solution_satisfies_the_relaxed_kkt_conditions(
    seed, nv, m, dense, log_kappa, log_scale, log_h
):
    gen = torch.Generator().manual_seed(seed)
    kappa, h = 10.0**log_kappa, 10.0**log_h
    Q, b, jac, phi, _ = _problem(gen, nv, m, dense, h=h, scale=10.0**log_scale)
    v, beta = relaxed_qp_velocity(Q, b, jac, phi, h, relaxation=kappa)
    stationarity, s, centrality = _relaxed_kkt(Q, b, jac, phi, h, v, beta, kappa)
    assert bool((beta > 0).all()) and bool((s > 0).all())
    assert float(stationarity) < 1e-8
    assert float(centrality.max()) <= 1


def _nondegenerate_problem(seed, nv=5, m=8, dense=False):
    """A problem whose QP solution is strictly complementary: every row β or s ≥ 1e-2."""
    gen = torch.Generator().manual_seed(seed)
    for _ in range(50):
        Q, b, jac, phi, h = _problem(gen, nv, m, dense)
        v, beta = qp_solve(Q, b, jac, phi, h)
        s = jac @ v + phi / h
        if bool((torch.maximum(beta, s) > 1e-2).all()) and bool((beta > 1e-2).any()):
            return Q, b, jac, phi, h
    raise AssertionError("no non-degenerate problem drawn")


def _osqp_jacobian(fn, x, eps=1e-6):
    """Central differences of the OSQP velocity ``fn(x)`` w.r.t. every element of ``x``."""
    columns = []
    for i in range(x.numel()):
        step = torch.zeros_like(x).flatten()
        step[i] = eps
        step = step.view_as(x)
        columns.append((fn(x + step) - fn(x - step)) / (2 * eps))
    return torch.stack(columns, dim=-1).reshape(-1, *x.shape)


@pytest.mark.parametrize("dense", [False, True])
def test_gradients_match_finite_differences_of_osqp(dense):
    Q, b, jac, phi, h = _nondegenerate_problem(3, dense=dense)

    def relaxed(b, phi):
        return relaxed_qp_velocity(Q, b, jac, phi, h, relaxation=1e-10)[0]

    d_b, d_phi = torch.autograd.functional.jacobian(relaxed, (b, phi))
    fd_b = _osqp_jacobian(lambda x: qp_solve(Q, x, jac, phi, h)[0], b)
    fd_phi = _osqp_jacobian(lambda x: qp_solve(Q, b, jac, x, h)[0], phi)
    assert float(d_phi.abs().max()) > 0.1  # the rows that bind steer v
    torch.testing.assert_close(d_b, fd_b, rtol=0, atol=1e-4 * float(fd_b.abs().max()))
    torch.testing.assert_close(d_phi, fd_phi, rtol=0, atol=1e-4 * float(fd_phi.abs().max()))


def test_control_gradient_through_a_quasi_dynamic_system_matches_osqp():
    gen = torch.Generator().manual_seed(5)
    system = QuasiDynamic([2.0, 3.0, 4.0], [5.0, 6.0], [0.0, 0.0, -1.0]).to(F64)
    jac = torch.randn(6, 5, generator=gen, dtype=F64)
    phi = 0.1 * (0.05 + torch.rand(6, generator=gen, dtype=F64))  # v = 0 is strictly feasible
    u = torch.tensor([0.3, -0.2], dtype=F64)

    def osqp(u):
        return qp_solve(*system(u), jac, phi, 0.1)[0]

    v, beta = qp_solve(*system(u), jac, phi, 0.1)
    assert bool((torch.maximum(beta, jac @ v + phi / 0.1) > 1e-3).all())  # non-degenerate
    assert bool((beta > 1e-3).any())
    relaxed = torch.autograd.functional.jacobian(
        lambda u: relaxed_qp_velocity(*system(u), jac, phi, 0.1, relaxation=1e-10)[0], u
    )
    fd = _osqp_jacobian(osqp, u)
    torch.testing.assert_close(relaxed, fd, rtol=0, atol=1e-4 * float(fd.abs().max()))


@pytest.mark.parametrize("dense", [False, True])
def test_gradcheck_of_the_relaxed_solution(dense):
    gen = torch.Generator().manual_seed(6)
    Q, b, jac, phi, _ = _problem(gen, 4, 6, dense)
    h = torch.tensor(0.1, dtype=F64)
    inputs = tuple(x.clone().requires_grad_() for x in (Q, b, jac, phi, h))

    def relaxed(Q, b, jac, phi, h):
        if dense:
            Q = (Q + Q.mT) / 2  # gradcheck perturbs one entry at a time: keep Q symmetric
        return relaxed_qp_velocity(Q, b, jac, phi, h, relaxation=1e-3)

    assert torch.autograd.gradcheck(relaxed, inputs)


def test_fixed_iterations_func_grad_and_a_given_solution_agree():
    gen = torch.Generator().manual_seed(7)
    Q, b, jac, phi, h = _problem(gen, 5, 8, dense=False, batch=(3,))
    v, beta = relaxed_qp_velocity(Q, b, jac, phi, h)
    torch.testing.assert_close(relaxed_qp_velocity(Q, b, jac, phi, h, iterations=40), (v, beta))
    solution = relaxed_qp_solve(Q, b, jac, phi, h)
    torch.testing.assert_close(solution.v, v, rtol=1e-9, atol=1e-12)

    def total(b, solution=None):
        return relaxed_qp_velocity(Q, b, jac, phi, h, solution=solution)[0].square().sum()

    leaf = b.clone().requires_grad_()
    (expected,) = torch.autograd.grad(total(leaf), leaf)
    torch.testing.assert_close(torch.func.grad(total)(b), expected)
    torch.testing.assert_close(torch.func.grad(total)(b, solution), expected)


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
def test_compiled_iterations_match_eager():
    gen = torch.Generator().manual_seed(13)
    Q, b, jac, phi, h = _problem(gen, 4, 6, dense=False, batch=(2,))
    compiled = relaxed_qp_solve(Q, b, jac, phi, h, compile_steps=True)
    torch.testing.assert_close(compiled, relaxed_qp_solve(Q, b, jac, phi, h), rtol=1e-12, atol=0)


@pytest.mark.parametrize("batch", [(), (3,), (2, 3)])
@pytest.mark.parametrize("dense", [False, True])
def test_batches_equal_single_solves(batch, dense):
    gen = torch.Generator().manual_seed(8)
    Q, b, jac, phi, _ = _problem(gen, 4, 6, dense, batch=batch)
    h = 0.05 + 0.1 * torch.rand(batch, generator=gen, dtype=F64)
    v, beta = relaxed_qp_velocity(Q, b, jac, phi, h)
    assert v.shape == (*batch, 4) and beta.shape == (*batch, 6)
    for i in itertools.product(*map(range, batch)):
        one = relaxed_qp_velocity(Q[i], b[i], jac[i], phi[i], float(h[i]))
        torch.testing.assert_close((v[i], beta[i]), one, rtol=1e-9, atol=1e-12)


def test_float32_agrees_with_float64():
    gen = torch.Generator().manual_seed(9)
    problem = _problem(gen, 6, 10, dense=True, batch=(3,))
    v64, beta64 = relaxed_qp_velocity(*problem)
    single = tuple(x.float() for x in problem[:4]) + (problem[4],)
    v32, beta32 = relaxed_qp_velocity(*single)
    assert v32.dtype == beta32.dtype == torch.float32
    torch.testing.assert_close(v32.double(), v64, rtol=1e-3, atol=1e-4)
    torch.testing.assert_close(beta32.double(), beta64, rtol=1e-3, atol=1e-4)


def test_inactive_rows_carry_no_force_and_act_on_nothing():
    gen = torch.Generator().manual_seed(10)
    Q, b, jac, phi, h = _problem(gen, 5, 8, dense=False)
    active = torch.tensor([True, False, True, True, False, True, False, True])
    phi = torch.where(active, phi, -10.0)  # dropped rows would be badly violated
    v, beta = relaxed_qp_velocity(Q, b, jac, phi, h, active)
    assert torch.count_nonzero(beta[~active]) == 0
    kept = relaxed_qp_velocity(Q, b, jac[active], phi[active], h)
    torch.testing.assert_close(v, kept[0], rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(beta[active], kept[1], rtol=1e-9, atol=1e-12)
    none = relaxed_qp_velocity(Q, b, jac, phi, h, torch.zeros(8, dtype=torch.bool))
    torch.testing.assert_close(none[0], b / Q / h)
    empty = relaxed_qp_velocity(Q, b, jac[:0], phi[:0], h)
    torch.testing.assert_close(empty[0], b / Q / h)
    assert empty[1].shape == (0,)


def test_model_is_built_by_name_and_its_impulses_lie_in_their_cones():
    c = random_contacts(4, 6, inactive=1, mu=0.6)
    model = contact_model("relaxed_qp", relaxation=1e-4, facets=8)
    assert isinstance(model, RelaxedQP) and model.facets == 8 and model.relaxation == 1e-4
    Q, b = 1.0 + torch.rand(6, dtype=F64), torch.randn(6, dtype=F64)
    v, beta = model.row_impulses(Q, b, c, 0.1)
    jac, phi, active = c.dual_rows(8)
    torch.testing.assert_close(v, relaxed_qp_velocity(Q, b, jac, phi, 0.1, active, 1e-4)[0])
    normal, friction = model.impulses(Q, b, c, 0.1)
    assert bool((normal[:3] > 0).all()) and torch.count_nonzero(normal[3]) == 0
    assert bool((torch.linalg.vector_norm(friction, dim=-1) <= 0.6 * normal + 1e-12).all())


@pytest.mark.parametrize("device", cuda_or_skip())
def test_cuda_matches_cpu(device):
    gen = torch.Generator().manual_seed(11)
    problem = _problem(gen, 5, 8, dense=True, batch=(2,))
    on_device = tuple(x.to(device) for x in problem[:4]) + (problem[4],)
    v, beta = relaxed_qp_velocity(*on_device)
    torch.testing.assert_close((v.cpu(), beta.cpu()), relaxed_qp_velocity(*problem))


@pytest.mark.parametrize(
    "change, name",
    [
        ({"relaxation": 0.0}, "relaxation"),
        ({"relaxation": -1e-3}, "relaxation"),
        ({"relaxation": math.inf}, "relaxation"),
        ({"relaxation": math.nan}, "relaxation"),
        ({"relaxation": True}, "relaxation"),
        ({"iterations": 0}, "iterations"),
        ({"iterations": 2.5}, "iterations"),
        ({"max_iter": 0}, "max_iter"),
        ({"max_iter": None}, "max_iter"),
        ({"active": torch.ones(3, dtype=torch.bool)}, "active"),
        ({"active": torch.ones(6)}, "active"),
        ({"Q": -torch.ones(4, dtype=F64)}, "Q"),
        ({"Q": torch.ones(4, 4, dtype=F64) - 2 * torch.eye(4, dtype=F64)}, "Q"),
        ({"jac": torch.ones(6, 3, dtype=F64)}, "jac"),
        ({"phi": torch.full((6,), math.nan, dtype=F64)}, "phi"),
        ({"b": torch.ones(5, dtype=F64)}, "jac"),
        ({"h": 0.0}, "h"),
    ],
)
def test_bad_inputs_raise_naming_the_argument(change, name):
    gen = torch.Generator().manual_seed(12)
    Q, b, jac, phi, h = _problem(gen, 4, 6, dense=False)
    arguments = {"Q": Q, "b": b, "jac": jac, "phi": phi, "h": h, **change}
    with pytest.raises(ValueError, match=name):
        relaxed_qp_velocity(**arguments)
    if name in ("relaxation", "iterations"):
        with pytest.raises(ValueError, match=name):
            RelaxedQP(**{name: change[name]})
