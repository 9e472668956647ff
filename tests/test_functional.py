"""The closed-form contact step as pure tensor functions: cf_velocity, cf_multipliers, softplus."""

import itertools
import math
import re

import pytest
import torch
import torch.nn.functional as F

from torchcontact import cf_multipliers, cf_velocity, softplus
from torchcontact.functional import is_dense_metric

F64 = torch.float64


def random_spd(nv: int, batch: tuple[int, ...] = (), dtype=F64) -> torch.Tensor:
    """A well-conditioned dense SPD matrix ``(..., nv, nv)``."""
    A = torch.randn(*batch, nv, nv, dtype=dtype)
    return A @ A.mT / nv + torch.eye(nv, dtype=dtype)


def random_step(nv=5, m=7, batch=(), dense=False, dtype=F64):
    """Random ``(Q, b, jac, phi)`` of one step."""
    Q = random_spd(nv, batch, dtype) if dense else 0.5 + torch.rand(*batch, nv, dtype=dtype)
    b = torch.randn(*batch, nv, dtype=dtype)
    jac = torch.randn(*batch, m, nv, dtype=dtype)
    phi = 0.3 * torch.randn(*batch, m, dtype=dtype)
    return Q, b, jac, phi


def dense_reference(Q, b, jac, phi, h, K, D, gamma):
    """The step re-derived with explicit inverses, one unbatched problem."""
    Qm = Q if Q.dim() == 2 else torch.diag(Q)
    Qinv = torch.linalg.inv(Qm)
    gap = jac @ Qinv @ b
    x = -K * (gap + phi)
    if D is not None:
        x = x - D * gap / h
    if gamma is None:
        lam = torch.clamp(x, min=0)
    else:
        lam = torch.log(1 + torch.exp(gamma * x)) / gamma
    return Qinv @ b / h + Qinv @ jac.T @ lam / h


@pytest.mark.parametrize("gamma", [3.0, None])
@pytest.mark.parametrize("dense", [False, True])
@pytest.mark.parametrize("damped", [False, True])
def test_cf_velocity_matches_dense_rederivation(gamma, dense, damped):
    for _ in range(5):
        nv, m = torch.randint(1, 8, ()).item(), torch.randint(1, 12, ()).item()
        Q, b, jac, phi = random_step(nv, m, dense=dense)
        h = 0.01 + torch.rand(()).item()
        K = 0.5 + 2 * torch.rand(m, dtype=F64)
        D = 0.3 * torch.rand(m, dtype=F64) if damped else None
        v = cf_velocity(Q, b, jac, phi, h, K, D, gamma)
        expected = dense_reference(Q, b, jac, phi, h, K, D, gamma)
        torch.testing.assert_close(v, expected, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("dense", [False, True])
def test_exact_mode_is_lemma_2_dual(dense):
    for _ in range(5):
        Q, b, jac, phi = random_step(6, 9, dense=dense)
        h, K = 0.05, 3.0
        Qinv = torch.linalg.inv(Q if dense else torch.diag(Q))
        beta = torch.clamp(-h * K * (jac @ Qinv @ b + phi), min=0)
        assert 0 < int((beta > 0).sum()) < 9, "want a mix of active and inactive rows"
        expected = Qinv @ b / h + Qinv @ jac.T @ beta / h**2
        v = cf_velocity(Q, b, jac, phi, h, K, gamma=None)
        torch.testing.assert_close(v, expected, rtol=1e-12, atol=1e-12)
        lam, _ = cf_multipliers(Q, b, jac, phi, h, K, gamma=None)
        torch.testing.assert_close(lam * h, beta, rtol=1e-12, atol=1e-12)


def receding_jacobian(Q, b, m):
    """Rows with J̃Q⁻¹b ≥ 0: contacts that are not approaching."""
    jac = torch.randn(m, b.shape[-1], dtype=b.dtype)
    gap = jac @ (b / Q)
    return jac * torch.where(gap < 0, -1.0, 1.0).to(b.dtype)[:, None]


@pytest.mark.parametrize("gamma", [100.0, None])
@pytest.mark.parametrize("damping", [None, 0.5])
def test_no_impulse_when_far_and_not_approaching(gamma, damping):
    Q, b, _, _ = random_step(5, 6)
    jac = receding_jacobian(Q, b, 6)
    phi = 1.0 + torch.rand(6, dtype=F64)
    lam, _ = cf_multipliers(Q, b, jac, phi, 0.1, 2.0, damping, gamma)
    v = cf_velocity(Q, b, jac, phi, 0.1, 2.0, damping, gamma)
    free = b / Q / 0.1
    if gamma is None:
        assert torch.count_nonzero(lam) == 0
        assert torch.equal(v, free)
    else:
        assert bool((lam <= 1e-12 * b.abs().max()).all())
        torch.testing.assert_close(v, free, rtol=1e-12, atol=0)


def test_smooth_mode_converges_to_exact():
    Q, b, jac, _ = random_step(6, 8, dense=True)
    h, K, D = 0.1, 4.0, 0.2
    # Choose φ̃ so the softplus arguments straddle the kink at every scale of γ.
    x = torch.tensor([0.0, 1e-6, -1e-6, 1e-3, -1e-3, 0.1, -0.1, 2.0], dtype=F64)
    gap = jac @ torch.linalg.solve(Q, b)
    phi = -(x + D * gap / h) / K - gap
    args = (Q, b, jac, phi, h, K, D)
    lam_exact, _ = cf_multipliers(*args, gamma=None)
    v_exact = cf_velocity(*args, gamma=None)
    lam_err, v_err = [], []
    for gamma in (10.0, 1e2, 1e3, 1e4, 1e5):
        lam_err.append((cf_multipliers(*args, gamma=gamma)[0] - lam_exact).abs().max().item())
        v_err.append((cf_velocity(*args, gamma=gamma) - v_exact).abs().max().item())
        assert lam_err[-1] <= math.log(2) / gamma + 1e-15
    assert all(a > b for a, b in itertools.pairwise(lam_err))
    assert all(a > b for a, b in itertools.pairwise(v_err))
    assert v_err[-1] < 1e-4 * v_exact.abs().max().item()


def _gradcheck(fn, *inputs):
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("dense", [False, True])
def test_gradcheck_wrt_every_input(dense):
    nv, m, h, gamma = 4, 6, 0.1, 5.0
    Q, b, jac, phi = random_step(nv, m, dense=dense)
    K = 1.0 + torch.rand(m, dtype=F64)
    D = 0.2 + 0.1 * torch.rand(m, dtype=F64)
    A = torch.linalg.cholesky(Q) if dense else Q.sqrt()

    def step(A, b, jac, phi, K, D):
        Q = A @ A.mT + 1e-3 * torch.eye(nv, dtype=F64) if dense else A * A
        return cf_velocity(Q, b, jac, phi, h, K, D, gamma)

    _gradcheck(step, *(x.clone().requires_grad_() for x in (A, b, jac, phi, K, D)))


def test_gradcheck_with_batched_time_step():
    Q, b, jac, phi = random_step(3, 4, batch=(2,))
    h = torch.tensor([0.05, 0.2], dtype=F64, requires_grad=True)
    _gradcheck(lambda b, h: cf_velocity(Q, b, jac, phi, h, 2.0, 0.3, 8.0), b.requires_grad_(), h)


EXTREMES = list(
    itertools.product(
        [1e-6, 1e6],  # stiffness
        [1.0, 1e6],  # gamma
        [1e-4, 1.0],  # h
        [-1.0, 1e3],  # phi
        [torch.float32, torch.float64],
    )
)


@pytest.mark.parametrize("K, gamma, h, phi0, dtype", EXTREMES)
def test_extreme_inputs_give_finite_values_and_gradients(K, gamma, h, phi0, dtype):
    Q, b, jac, phi = random_step(4, 8, dense=True, dtype=dtype)
    phi = torch.full_like(phi, phi0)
    K = torch.tensor(K, dtype=dtype)
    leaves = [x.requires_grad_() for x in (b, jac, phi, K)]
    v = cf_velocity(Q, b, jac, phi, h, K, 0.1 * K, gamma)
    v.sum().backward()
    assert torch.isfinite(v).all()
    for x in leaves:
        assert torch.isfinite(x.grad).all()


@pytest.mark.parametrize("m", [0, 1000])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("gamma", [1e6, None])
def test_no_and_many_rows(m, dtype, gamma):
    Q, b, jac, phi = random_step(6, m, dtype=dtype)
    K = torch.tensor(100.0, dtype=dtype)
    leaves = [x.requires_grad_() for x in (Q, b, jac, phi, K)]
    v = cf_velocity(Q, b, jac, phi, 0.01, K, 0.1 * K, gamma=gamma)
    v.sum().backward()
    assert v.shape == (6,) and torch.isfinite(v).all()
    assert all(torch.isfinite(x.grad).all() for x in leaves)
    if m == 0:
        torch.testing.assert_close(v, b / Q / 0.01)


@pytest.mark.parametrize("gamma", [1.0, 1e6, 1e100, 1e300])
def test_softplus_never_overflows(gamma):
    x = torch.tensor([-1e30, -1e5, -1.0, -1e-300, 0.0, 1e-300, 1.0, 1e5, 1e30], dtype=F64)
    x.requires_grad_()
    y = softplus(x, gamma)
    (grad,) = torch.autograd.grad(y.sum(), x)
    assert torch.isfinite(y).all() and torch.isfinite(grad).all()
    assert bool((y >= 0).all()) and bool((y >= x).all())
    assert bool(((grad >= 0) & (grad <= 1)).all())
    # Within log(2)/γ of max(x, 0) everywhere.
    assert bool(((y - torch.relu(x)) <= math.log(2) / gamma * (1 + 1e-12)).all())


@pytest.mark.parametrize("gamma", [0.5, 10.0, 1e4, 1e200])
def test_softplus_equals_relu_past_the_threshold(gamma):
    x = torch.logspace(-3, 3, 50, dtype=F64) * 20 / gamma
    y = softplus(torch.cat([x, -x]), gamma)
    big, small = x * gamma > 20, x * gamma > 30
    torch.testing.assert_close(y[:50][big], x[big], rtol=1e-9, atol=0)
    assert bool((y[50:][small] <= 1e-12 / gamma).all())


def test_softplus_exact_mode_is_relu():
    x = torch.randn(100, dtype=F64)
    assert torch.equal(softplus(x, None), torch.relu(x))
    torch.testing.assert_close(softplus(x, 7.0), F.softplus(x, beta=7.0))


def _loop(fn, batch, *args):
    """Apply ``fn`` element by element over ``batch``; each arg is (tensor, has_batch)."""
    results = []
    for idx in itertools.product(*map(range, batch)):
        results.append(fn(*(x[idx] if batched else x for x, batched in args)))
    out = torch.stack(results)
    return out.reshape(*batch, *out.shape[1:])


@pytest.mark.parametrize("batch", [(), (3,), (2, 3)])
@pytest.mark.parametrize("q_kind", ["batched_diag", "shared_diag", "batched_dense", "shared_dense"])
@pytest.mark.parametrize("gamma", [20.0, None])
def test_batches_agree_with_loops(batch, q_kind, gamma):
    nv, m = 4, 6
    dense = q_kind.endswith("dense")
    _, b, jac, phi = random_step(nv, m, batch)
    if q_kind == "batched_diag":
        Q = 0.5 + torch.rand(*batch, nv, dtype=F64)
    elif q_kind == "shared_diag":
        Q = 0.5 + torch.rand(nv, dtype=F64)
    elif q_kind == "batched_dense":
        Q = random_spd(nv, batch)
    else:
        Q = random_spd(nv, (1,) * len(batch))
    h = 0.05 + torch.rand(batch, dtype=F64)
    K = 1.0 + torch.rand(*batch, m, dtype=F64)
    assert is_dense_metric(Q, b) == dense
    v = cf_velocity(Q, b, jac, phi, h, K, 0.1 * K, gamma)
    assert v.shape == (*batch, nv)
    shared = q_kind.startswith("shared")
    Q_one = Q.reshape(nv, nv) if q_kind == "shared_dense" else Q

    def one(Q, b, jac, phi, h, K):
        return dense_reference(Q, b, jac, phi, h, K, 0.1 * K, gamma)

    expected = _loop(
        one, batch, (Q_one, not shared), (b, True), (jac, True), (phi, True), (h, True), (K, True)
    )
    torch.testing.assert_close(v, expected)


def test_shared_dense_metric_over_long_batch():
    Q = random_spd(3, (1,))
    _, b, jac, phi = random_step(3, 5, (4, 2))
    v = cf_velocity(Q, b, jac, phi, 0.1, 2.0)
    expected = cf_velocity(Q.expand(4, 2, 3, 3), b, jac, phi, 0.1, 2.0)
    torch.testing.assert_close(v, expected)


def test_is_dense_metric_rules():
    nv = 3
    b = torch.zeros(nv)
    assert not is_dense_metric(torch.ones(nv), b)
    assert is_dense_metric(torch.eye(nv), b)
    batch = torch.zeros(5, nv)
    assert not is_dense_metric(torch.ones(5, nv), batch)
    assert not is_dense_metric(torch.ones(nv), batch)
    assert is_dense_metric(torch.eye(nv), batch)
    assert is_dense_metric(torch.eye(nv).expand(5, nv, nv), batch)
    # A batch of nv diagonals shaped like b stays diagonal; a singleton dim makes it dense.
    square_batch = torch.zeros(nv, nv)
    assert not is_dense_metric(torch.ones(nv, nv), square_batch)
    assert is_dense_metric(torch.eye(nv)[None], square_batch)
    assert is_dense_metric(torch.eye(nv), torch.zeros(2, 5, nv))
    assert not is_dense_metric(torch.ones(5, 1, nv), torch.zeros(5, 4, nv))


def test_diagonal_and_dense_metric_agree():
    Q, b, jac, phi = random_step(5, 8)
    args = (b, jac, phi, 0.1, 3.0, 0.3, 10.0)
    torch.testing.assert_close(cf_velocity(Q, *args), cf_velocity(torch.diag(Q), *args))


# Bad input: each case corrupts one argument of a valid call and names it in the message.
def _corrupt(name, value):
    Q, b, jac, phi = random_step(3, 4, batch=(2,))
    kwargs = dict(Q=Q, b=b, jac=jac, phi=phi, h=0.1, stiffness=1.0, damping=0.1, gamma=10.0)
    kwargs[name] = value(kwargs[name]) if callable(value) else value
    return kwargs


def _with(index, bad):
    def fn(x):
        x = x.clone()
        x.view(-1)[index] = bad
        return x

    return fn


BAD_INPUTS = [
    ("b", _with(2, math.nan), "^b must be finite"),
    ("b", _with(0, math.inf), "^b must be finite"),
    ("jac", _with(5, math.nan), "^jac must be finite"),
    ("jac", _with(1, -math.inf), "^jac must be finite"),
    ("phi", _with(3, math.nan), "^phi must be finite"),
    ("phi", _with(0, math.inf), "^phi must be finite"),
    ("Q", _with(1, math.nan), r"^Q \(diagonal\) must be finite"),
    ("Q", _with(1, math.inf), r"^Q \(diagonal\) must be finite"),
    ("Q", _with(0, 0.0), r"^Q \(diagonal\) must be positive"),
    ("Q", _with(4, -1.0), r"^Q \(diagonal\) must be positive"),
    ("Q", lambda Q: Q[..., :2], r"^Q must have shape \(\.\.\., nv=3\)"),
    ("Q", lambda Q: torch.eye(4, dtype=F64)[None], r"^Q must have shape \(\.\.\., nv=3, nv=3\)"),
    ("Q", lambda Q: torch.ones(1, 3, 4, dtype=F64), "^Q must have shape"),
    ("Q", lambda Q: torch.diag_embed(Q).index_fill(-1, torch.tensor([0]), math.nan), "^Q must"),
    ("Q", lambda Q: torch.diag_embed(Q) - 2 * torch.eye(3, dtype=F64), "^Q must be symmetric"),
    ("Q", lambda Q: torch.diag_embed(Q) + torch.triu(torch.ones(3, 3, dtype=F64), 1), "^Q must"),
    ("jac", lambda J: J[..., :2], r"^jac must have shape \(\.\.\., m, nv=3\)"),
    ("jac", lambda J: J[0, 0], "^jac must have shape"),
    ("phi", lambda p: p[..., :3], r"^phi must have shape \(\.\.\., m=4\)"),
    ("b", lambda b: b[0, 0], "^b must have shape"),
    ("phi", lambda p: torch.zeros(3, 4, dtype=F64), "^batch shapes of Q, b, jac"),
    ("jac", lambda J: torch.zeros(3, 4, 3, dtype=F64), "^batch shapes of Q, b, jac"),
    ("Q", lambda Q: torch.ones(5, 3, dtype=F64), "^batch shapes of Q, b, jac"),
    ("stiffness", -1.0, "^stiffness must be non-negative"),
    ("stiffness", torch.tensor([1.0, 2.0, -1e-9, 1.0]), "^stiffness must be non-negative"),
    ("stiffness", math.nan, "^stiffness must be finite"),
    ("damping", -0.1, "^damping must be non-negative"),
    ("damping", torch.tensor([0.1, math.inf, 0.1, 0.1]), "^damping must be finite"),
    ("h", 0.0, "^h must be positive"),
    ("h", -0.01, "^h must be positive"),
    ("h", torch.tensor([0.1, 0.0]), "^h must be positive"),
    ("h", math.inf, "^h must be finite"),
    ("gamma", 0.0, "^gamma must be positive"),
    ("gamma", -5.0, "^gamma must be positive"),
    ("gamma", math.inf, "^gamma must be finite"),
    ("gamma", math.nan, "^gamma must be finite"),
]


@pytest.mark.parametrize("name, value, match", BAD_INPUTS)
def test_bad_input_names_the_argument(name, value, match):
    kwargs = _corrupt(name, value)
    with pytest.raises(ValueError, match=match):
        cf_velocity(**kwargs)


def test_non_tensor_inputs_raise_type_error():
    kwargs = _corrupt("b", [0.0, 1.0, 2.0])
    with pytest.raises(TypeError, match="^b must be a torch.Tensor"):
        cf_velocity(**kwargs)
    kwargs = _corrupt("phi", lambda p: p.long())
    with pytest.raises(TypeError, match="^phi must be a floating-point"):
        cf_velocity(**kwargs)


@pytest.mark.parametrize(
    "name, value",
    [
        ("h", torch.tensor([0.1, 0.2, 0.3], dtype=F64)),
        ("stiffness", torch.ones(5, dtype=F64)),
        ("damping", torch.ones(2, 3, dtype=F64)),
    ],
)
def test_scalar_arguments_of_the_wrong_shape_name_the_argument(name, value):
    # Batch (2,), m = 4: h must broadcast with (2,), stiffness and damping with (2, 4).
    kwargs = _corrupt(name, value)
    with pytest.raises(ValueError, match=f"^{name}"):
        cf_velocity(**kwargs)


# The batch shape is that of Q, b, jac and phi; h, stiffness and damping broadcast to it.
@pytest.mark.parametrize(
    "name, value, batch",
    [
        ("h", lambda B: torch.full((B, 1), 0.1, dtype=F64), (4,)),  # would give (B, B, nv)
        ("h", lambda B: torch.full((3,), 0.1, dtype=F64), ()),  # adds a batch dimension
        ("h", lambda B: torch.full((1,), 0.1, dtype=F64), ()),
        ("stiffness", lambda B: torch.ones(5, 8, dtype=F64), ()),
        ("stiffness", lambda B: torch.ones(2, B, 8, dtype=F64), (4,)),
        ("damping", lambda B: torch.ones(3, 1, 8, dtype=F64), (4,)),
    ],
)
def test_scalar_arguments_may_not_enlarge_the_batch(name, value, batch):
    Q, b, jac, phi = random_step(3, 8, batch=batch)
    kwargs = dict(Q=Q, b=b, jac=jac, phi=phi, h=0.1, stiffness=1.0, damping=0.1, gamma=10.0)
    kwargs[name] = value(batch[0] if batch else 1)
    expected = tuple(batch) if name == "h" else (*batch, 8)
    got = re.escape(str(tuple(kwargs[name].shape)))
    match = rf"^{name} must broadcast to {re.escape(str(expected))}.*got {got}"
    with pytest.raises(ValueError, match=match):
        cf_velocity(**kwargs)
    with pytest.raises(ValueError, match=f"^{name}"):
        cf_multipliers(**kwargs)


def test_scalar_arguments_of_the_batch_shape_or_smaller_still_broadcast():
    Q, b, jac, phi = random_step(3, 8, batch=(4,))
    h, K = torch.full((4,), 0.1, dtype=F64), torch.ones(4, 1, dtype=F64)
    v = cf_velocity(Q, b, jac, phi, h, K, torch.ones(8, dtype=F64), 10.0)
    assert v.shape == (4, 3)
    torch.testing.assert_close(v, cf_velocity(Q, b, jac, phi, 0.1, 1.0, 1.0, 10.0))


@pytest.mark.parametrize("name", ["Q", "jac", "phi"])
def test_mixed_dtypes_name_the_argument_and_the_dtypes(name):
    kwargs = _corrupt(name, lambda x: x.float())
    match = rf"^{name} must have the dtype of b \(torch.float64\), got torch.float32"
    with pytest.raises(ValueError, match=match):
        cf_velocity(**kwargs)
    kwargs = _corrupt("b", lambda x: x.float())
    with pytest.raises(ValueError, match=r"^Q must have the dtype of b \(torch.float32\)"):
        cf_velocity(**kwargs)


@pytest.mark.parametrize("name", ["Q", "jac", "phi", "stiffness"])
def test_mixed_devices_name_the_argument_and_the_devices(name):
    meta = torch.ones(4, dtype=F64, device="meta")
    kwargs = _corrupt(name, lambda x: meta if name == "stiffness" else x.to("meta"))
    with pytest.raises(ValueError, match=rf"^{name} must be on the device of b \(cpu\), got meta"):
        cf_velocity(**kwargs)


@pytest.mark.parametrize("dense", [False, True])
def test_meta_tensors_skip_the_value_checks(dense):
    Q, b, jac, phi = (x.to("meta") for x in random_step(3, 4, batch=(2,), dense=dense))
    h = torch.full((2,), 0.1, dtype=F64, device="meta")
    v = cf_velocity(Q, b, jac, phi, h, torch.ones(4, dtype=F64, device="meta"), 0.1, 10.0)
    assert v.is_meta and v.shape == (2, 3)


def test_vmap_over_cf_velocity_with_value_checks_on():
    from torchcontact import validate_args

    Q, b, jac, phi = random_step(3, 4, batch=(5,), dense=True)
    with validate_args(True):
        mapped = torch.func.vmap(cf_velocity, in_dims=(0, 0, 0, 0, None, None))(
            Q, b, jac, phi, 0.1, 2.0
        )
        torch.testing.assert_close(mapped, cf_velocity(Q, b, jac, phi, 0.1, 2.0))
