"""ComplementarityFree as a module: impulses, physics of K, batching, devices, errors, registry."""

import dataclasses
import itertools
import math

import pytest
import torch
from conftest import cuda_or_skip
from hypothesis import given, settings
from hypothesis import strategies as st
from test_contacts import random_contacts

from torchcontact import (
    AnitescuQP,
    ComplementarityFree,
    ContactNetwork,
    Contacts,
    QuasiDynamic,
    Relative,
    RelaxedQP,
    StateNetwork,
    contact_model,
)

F64 = torch.float64


def random_metric(nv, dense, batch=(), generator=None, dtype=F64):
    """A positive diagonal ``(..., nv)`` or a dense SPD ``(..., nv, nv)`` metric."""
    if not dense:
        return 0.5 + torch.rand(*batch, nv, dtype=dtype, generator=generator)
    A = torch.randn(*batch, nv, nv, dtype=dtype, generator=generator)
    return A @ A.mT / nv + torch.eye(nv, dtype=dtype)


def solve(Q, x):
    return torch.linalg.solve(Q, x) if Q.dim() == x.dim() + 1 else x / Q


def index_contacts(c: Contacts, idx) -> Contacts:
    """The contacts of one batch element."""
    return Contacts(
        **{
            f.name: None if getattr(c, f.name) is None else getattr(c, f.name)[idx]
            for f in dataclasses.fields(c)
        }
    )


@pytest.mark.parametrize("dense", [False, True])
@pytest.mark.parametrize("facets", [4, 8])
def test_exact_row_impulses_are_lemma_2_dual(dense, facets):
    c = random_contacts(4, 6, inactive=1)
    Q, b, h, K = random_metric(6, dense), torch.randn(6, dtype=F64), 0.05, 3.0
    model = ComplementarityFree(stiffness=K, gamma=None, facets=facets).to(F64)
    v, beta = model.row_impulses(Q, b, c, h)
    jac, phi, active = c.dual_rows(facets)
    K = model.stiffness(c, facets)  # 3 as stored: a float32 log rounds it by ~2e-8
    expected = torch.clamp(-h * K * (jac @ solve(Q, b) + phi), min=0) * active
    assert bool((expected > 0).any()) and bool((expected[: 3 * facets] == 0).any())
    torch.testing.assert_close(beta, expected, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(v, solve(Q, b) / h + solve(Q, jac.T @ beta) / h**2)
    torch.testing.assert_close(model(Q, b, c, h), v, rtol=0, atol=0)


def test_padding_slots_never_push():
    c = random_contacts(3, 5, inactive=2)
    c = dataclasses.replace(c, phi=torch.full((3,), -1.0, dtype=F64))  # deep, yet padding
    Q, b = random_metric(5, True), torch.randn(5, dtype=F64)
    model = ComplementarityFree(stiffness=10.0, damping=Relative(0.1), gamma=10.0).to(F64)
    v, beta = model.row_impulses(Q, b, c, 0.1)
    assert torch.count_nonzero(beta[4:]) == 0 and bool((beta[:4] > 0).all())
    only_active = index_contacts(c, (slice(0, 1),))
    torch.testing.assert_close(model(Q, b, only_active, 0.1), v)


@settings(max_examples=50, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    nc=st.integers(1, 5),
    nv=st.integers(1, 7),
    facets=st.sampled_from([4, 8]),
    dense=st.booleans(),
    log_gamma=st.one_of(st.none(), st.floats(-1.0, 6.0)),
    log_k=st.floats(-3.0, 4.0),
    mu=st.floats(0.0, 2.0),
    damped=st.booleans(),
)
def test_every_impulse_lies_in_its_friction_cone(
    seed, nc, nv, facets, dense, log_gamma, log_k, mu, damped
):
    g = torch.Generator().manual_seed(seed)
    c = random_contacts(nc, nv, mu=mu, inactive=int(nc > 2), generator=g)
    Q = random_metric(nv, dense, generator=g)
    b = 10 * torch.randn(nv, dtype=F64, generator=g)
    gamma = None if log_gamma is None else 10.0**log_gamma
    model = ComplementarityFree(
        stiffness=10.0**log_k, damping=0.1 if damped else None, gamma=gamma, facets=facets
    ).to(F64)
    normal, friction = model.impulses(Q, b, c, 0.01)
    assert normal.shape == (nc,) and friction.shape == (nc, 2)
    assert torch.isfinite(normal).all() and torch.isfinite(friction).all()
    assert bool((normal >= 0).all())
    # hypot, not norm: squaring a tiny friction component would lose it to subnormals, where
    # round-off is absolute (≈5e-324), hence the absolute tolerance.
    magnitude = torch.hypot(friction[..., 0], friction[..., 1])
    assert bool((magnitude <= mu * normal * (1 + 1e-12) + 1e-300).all())
    assert torch.count_nonzero(normal[~c.active]) == 0


@pytest.mark.parametrize("gamma", [100.0, None])
@pytest.mark.parametrize("dense", [False, True])
def test_no_impulse_when_far_apart_and_not_approaching(gamma, dense):
    nc, nv, mu = 4, 6, 0.8
    c = random_contacts(nc, nv, mu=mu)
    Q, b = random_metric(nv, dense), torch.randn(nv, dtype=F64)
    free = solve(Q, b)
    # Lift Jⁿ along Q⁻¹b so that every facet row has J̃Q⁻¹b > 0 (receding).
    tangent = (c.jac_tangent @ free).abs().sum(-1)
    lift = (mu * tangent + (c.jac_normal @ free).abs() + 0.1)[:, None] * free / free.dot(free)
    c = dataclasses.replace(c, jac_normal=c.jac_normal + lift, phi=1.0 + torch.rand(nc, dtype=F64))
    jac, _, _ = c.dual_rows(4)
    assert bool((jac @ free > 0).all())
    model = ComplementarityFree(stiffness=5.0, damping=Relative(0.1), gamma=gamma).to(F64)
    v, beta = model.row_impulses(Q, b, c, 0.02)
    if gamma is None:
        assert torch.count_nonzero(beta) == 0
    else:
        assert bool((beta <= 1e-12 * 0.02 * b.abs().max()).all())
    torch.testing.assert_close(v, free / 0.02, rtol=1e-12, atol=0)


def pushed_sphere(u: float = 0.002):
    """A sphere on the ground (v = x, y, z) and a fingertip (v = x_f) pushing it along +x.

    Returns the quasi-dynamic ``(Q, b)`` for the fingertip command ``u`` and the two contacts:
    ground (normal +z, tangents x, y) and finger (normal +x, tangents y, z), both touching.
    """
    system = QuasiDynamic([1e4, 1e4, 1e4], 1e4, [0.0, 0.0, -9.81], n_robot=1).to(F64)
    Q, b = system(torch.tensor([u], dtype=F64))
    contacts = Contacts(
        phi=torch.zeros(2, dtype=F64),
        jac_normal=torch.tensor([[0.0, 0, 1, 0], [1, 0, 0, -1]], dtype=F64),
        jac_tangent=torch.tensor(
            [[[1.0, 0, 0, 0], [0, 1, 0, 0]], [[0, 1, 0, 0], [0, 0, 1, 0]]], dtype=F64
        ),
        mu=torch.full((2,), 0.5, dtype=F64),
        active=torch.ones(2, dtype=torch.bool),
    )
    return Q, b, contacts


@pytest.mark.parametrize("gamma", [1e4, None])
def test_stiffer_contacts_penetrate_less(gamma):
    Q, b, c = pushed_sphere()
    h = 0.1
    free_gap = c.phi + c.jac_normal @ solve(Q, b)
    assert bool((free_gap < -5e-4).all()), "without contact both contacts would penetrate"
    penetration = []
    for K in (0.1, 1.0, 10.0, 100.0, 1000.0):
        v = ComplementarityFree(stiffness=K, gamma=gamma).to(F64)(Q, b, c, h)
        next_phi = c.phi + h * (c.jac_normal @ v)
        penetration.append(torch.clamp(-next_phi, min=0))
    penetration = torch.stack(penetration)
    assert bool((penetration[1:] < penetration[:-1]).all())
    assert bool((penetration[-1] < 0.6 * penetration[0]).all())


def test_gradcheck_through_quasi_dynamic_command():
    c = random_contacts(3, 5, inactive=1)
    system = QuasiDynamic([2.0, 3.0, 4.0], [5.0, 6.0], [0.0, 0.0, -1.0]).to(F64)
    model = ComplementarityFree(stiffness=2.0, damping=Relative(0.1), gamma=5.0).to(F64)
    u = 0.1 * torch.randn(4, 2, dtype=F64)

    def step(u):
        Q, b = system(u)
        return model(Q, b, c, 0.1)

    assert torch.autograd.gradcheck(step, (u.requires_grad_(),), eps=1e-6, atol=1e-6)


def test_gradcheck_through_contact_geometry():
    c = random_contacts(3, 4)
    Q, b = random_metric(4, True), torch.randn(4, dtype=F64)
    model = ComplementarityFree(stiffness=3.0, gamma=5.0, facets=8).to(F64)

    def step(phi, jac_normal, jac_tangent, mu):
        contacts = dataclasses.replace(
            c, phi=phi, jac_normal=jac_normal, jac_tangent=jac_tangent, mu=mu
        )
        return model(Q, b, contacts, 0.1)

    inputs = (c.phi, c.jac_normal, c.jac_tangent, c.mu.clamp_min(0.1))
    assert torch.autograd.gradcheck(step, tuple(x.clone().requires_grad_() for x in inputs))


STIFFNESS = {
    "constant": lambda nc, nq: 3.0,
    "contact_network": lambda nc, nq: ContactNetwork(hidden=8, value=3.0),
    "state_network": lambda nc, nq: StateNetwork(nq, 4 * nc, hidden=8, value=3.0),
}


@pytest.mark.parametrize("batch", [(), (3,), (2, 3)])
@pytest.mark.parametrize("q_kind", ["batched", "shared_diag", "shared_dense"])
@pytest.mark.parametrize("stiffness", sorted(STIFFNESS))
def test_module_batches_agree_with_loops(batch, q_kind, stiffness):
    nc, nv, nq = 3, 5, 6
    c = random_contacts(nc, nv, batch, inactive=1)
    if q_kind == "batched":
        Q = random_metric(nv, True, batch)
    elif q_kind == "shared_diag":
        Q = random_metric(nv, False)
    else:
        Q = random_metric(nv, True, (1,) * len(batch))
    b = torch.randn(*batch, nv, dtype=F64)
    q = torch.randn(*batch, nq, dtype=F64)
    h = 0.05 + torch.rand(batch, dtype=F64)
    model = ComplementarityFree(
        stiffness=STIFFNESS[stiffness](nc, nq), damping=Relative(0.1), gamma=20.0
    ).to(F64)
    v, beta = model.row_impulses(Q, b, c, h, q)
    assert v.shape == (*batch, nv) and beta.shape == (*batch, 4 * nc)
    Q_one = Q.reshape(nv, nv) if q_kind == "shared_dense" else Q
    for idx in itertools.product(*map(range, batch)):
        Q_i = Q_one[idx] if q_kind == "batched" else Q_one
        v_i, beta_i = model.row_impulses(Q_i, b[idx], index_contacts(c, idx), h[idx], q[idx])
        torch.testing.assert_close(v[idx], v_i)
        torch.testing.assert_close(beta[idx], beta_i)


@pytest.mark.parametrize("dtype", [torch.float32, F64])
@pytest.mark.parametrize("gamma", [1e6, None])
def test_no_contacts_and_a_thousand_contacts(dtype, gamma):
    nv = 6
    model = ComplementarityFree(stiffness=1e3, damping=Relative(0.1), gamma=gamma).to(dtype)
    Q, b = random_metric(nv, False, dtype=dtype), torch.randn(nv, dtype=dtype)
    none = Contacts.empty(0, nv, dtype=dtype)
    v, beta = model.row_impulses(Q, b, none, 0.01)
    assert beta.shape == (0,)
    torch.testing.assert_close(v, b / Q / 0.01)
    normal, friction = model.impulses(Q, b, none, 0.01)
    assert normal.shape == (0,) and friction.shape == (0, 2)

    many = random_contacts(1000, nv, inactive=100).to(dtype)
    phi = many.phi.clone().requires_grad_()
    jac_normal = many.jac_normal.clone().requires_grad_()
    b.requires_grad_()
    many = dataclasses.replace(many, phi=phi, jac_normal=jac_normal)
    v = model(Q, b, many, 0.01)
    v.sum().backward()
    assert v.dtype == dtype and torch.isfinite(v).all()
    assert all(torch.isfinite(x.grad).all() for x in (phi, jac_normal, b))


@pytest.mark.parametrize("device", cuda_or_skip())
@pytest.mark.parametrize("dense", [False, True])
def test_cuda_matches_cpu(device, dense):
    c = random_contacts(5, 6, (4,), inactive=1)
    Q, b = random_metric(6, dense, (4,)), torch.randn(4, 6, dtype=F64)
    q = torch.randn(4, 3, dtype=F64)
    model = ComplementarityFree(
        stiffness=StateNetwork(3, 20, hidden=8, value=2.0), damping=Relative(0.1), gamma=50.0
    ).to(F64)
    v_cpu, beta_cpu = model.row_impulses(Q, b, c, 0.05, q)
    model.to(device)
    v, beta = model.row_impulses(Q.to(device), b.to(device), c.to(device), 0.05, q.to(device))
    assert v.device.type == device and beta.device.type == device
    torch.testing.assert_close(v.cpu(), v_cpu)
    torch.testing.assert_close(beta.cpu(), beta_cpu)


@pytest.mark.parametrize("gamma", [0, 0.0, -1.0, math.nan, "100", [1.0]])
def test_bad_gamma_raises(gamma):
    with pytest.raises(ValueError, match="gamma"):
        ComplementarityFree(gamma=gamma)


def test_infinite_gamma_is_refused_when_built():
    with pytest.raises(ValueError, match="gamma"):
        ComplementarityFree(gamma=math.inf)


@pytest.mark.parametrize("facets", [2, 0, 4.0, "8", None])
@pytest.mark.parametrize("name", ["complementarity_free", "qp", "relaxed_qp"])
def test_bad_facets_raise(facets, name):
    with pytest.raises(ValueError, match="facets"):
        contact_model(name, facets=facets)


def test_negative_stiffness_raises():
    with pytest.raises(ValueError, match="positive"):
        ComplementarityFree(stiffness=-1.0)
    with pytest.raises(ValueError, match="positive"):
        ComplementarityFree(damping=0.0)


def test_models_are_built_by_name():
    cf = contact_model("complementarity_free", stiffness=2.0, gamma=None, facets=8)
    assert isinstance(cf, ComplementarityFree) and cf.gamma is None and cf.facets == 8
    qp = contact_model("qp", facets=8)
    assert isinstance(qp, AnitescuQP) and qp.facets == 8
    Q, b, c = pushed_sphere()
    v, beta = qp.row_impulses(Q, b, c, 0.1)
    jac, phi, _ = c.dual_rows(8)
    assert bool((beta >= -1e-9).all()) and bool((jac @ v + phi / 0.1 >= -1e-7).all())
    relaxed = contact_model("relaxed_qp", relaxation=1e-9, facets=8)
    assert isinstance(relaxed, RelaxedQP) and relaxed.relaxation == 1e-9
    v_relaxed, beta_relaxed = relaxed.row_impulses(Q, b, c, 0.1)
    torch.testing.assert_close(v_relaxed, v, rtol=1e-5, atol=1e-9)  # β is not unique, J̃ᵀβ is:
    torch.testing.assert_close(jac.T @ beta_relaxed, jac.T @ beta, rtol=1e-5, atol=1e-9)
    for name in ("QP", "anitescu", ""):
        with pytest.raises(ValueError, match="name"):
            contact_model(name)


def test_module_refuses_scalars_that_enlarge_the_batch():
    """``h`` of shape ``(B, 1)`` would give a ``(B, B, nv)`` velocity; a batched K(q) over
    unbatched contacts would add a batch dimension."""
    nc, nv, nq, B = 2, 4, 5, 3
    c = random_contacts(nc, nv, (B,))
    Q, b = random_metric(nv, False, (B,)), torch.randn(B, nv, dtype=F64)
    model = ComplementarityFree(stiffness=3.0, damping=Relative(0.1)).to(F64)
    with pytest.raises(ValueError, match=rf"^h must broadcast to \({B},\).*got \({B}, 1\)"):
        model(Q, b, c, torch.full((B, 1), 0.1, dtype=F64))
    with pytest.raises(ValueError, match=r"^h must broadcast to \(\).*got \(3,\)"):
        model(Q[0], b[0], index_contacts(c, 0), torch.full((3,), 0.1, dtype=F64))
    state = ComplementarityFree(stiffness=StateNetwork(nq, 4 * nc, hidden=4)).to(F64)
    q = torch.randn(5, nq, dtype=F64)
    with pytest.raises(ValueError, match=r"^stiffness must broadcast to \(8,\).*got \(5, 8\)"):
        state(Q[0], b[0], index_contacts(c, 0), 0.1, q)


def test_nan_in_the_state_of_a_state_dependent_stiffness_names_q():
    nc, nv, nq = 2, 4, 5
    c = random_contacts(nc, nv)
    model = ComplementarityFree(stiffness=StateNetwork(nq, 4 * nc, hidden=4)).to(F64)
    q = torch.randn(nq, dtype=F64)
    q[1] = math.nan
    Q, b = random_metric(nv, False), torch.randn(nv, dtype=F64)
    with pytest.raises(ValueError, match="^q must be finite"):
        model(Q, b, c, 0.1, q)
    with pytest.raises(ValueError, match="^q must be finite"):
        model.freeze(c, 0.1, q)
