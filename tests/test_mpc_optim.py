"""Tests for torchcontact.mpc.optim: box-projected, batched L-BFGS against SciPy's L-BFGS-B."""

import numpy as np
import pytest
import torch
from conftest import DEVICES
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize

from torchcontact.mpc.optim import lbfgs_box, value_and_grad

TIGHT = {"tol_grad": 1e-10, "tol_change": 1e-15, "max_iter": 1000}
SCIPY_TIGHT = {"maxiter": 1000, "gtol": 1e-10, "ftol": 1e-15}


def rosenbrock(x: torch.Tensor) -> torch.Tensor:
    """(N, n) -> (N,), minimum 0 at x = 1."""
    return (100 * (x[:, 1:] - x[:, :-1] ** 2) ** 2 + (1 - x[:, :-1]) ** 2).sum(-1)


def styblinski_tang(x: torch.Tensor) -> torch.Tensor:
    """(N, n) -> (N,), nonconvex: two basins per coordinate, weakly coupled."""
    coupling = 0.5 * ((x[:, 1:] - x[:, :-1]) ** 2).sum(-1)
    return 0.5 * (x**4 - 16 * x**2 + 5 * x).sum(-1) + coupling


def quadratic_fun(matrix: torch.Tensor, linear: torch.Tensor):
    """``fun`` of the B quadratics 0.5 xᵀA_b x + b_bᵀx, ``matrix: (B, n, n)``, ``linear:
    (B, n)``; row k·B + b of x belongs to problem b."""
    n_problems, n = linear.shape

    def fun(x):
        rows = x.view(-1, n_problems, n)
        grad = torch.einsum("kbi,bij->kbj", rows, matrix) + linear
        f = (rows * (0.5 * (grad - linear) + linear)).sum(-1)
        return f.reshape(-1), grad.reshape(x.shape)

    return fun


def random_quadratics(n_problems: int, n: int, seed: int):
    """B random convex quadratics with eigenvalues 1…100: ``fun``, A (B, n, n), b (B, n)."""
    generator = torch.Generator().manual_seed(seed)
    q, _ = torch.linalg.qr(torch.randn(n_problems, n, n, generator=generator, dtype=torch.float64))
    eigenvalues = torch.logspace(0, 2, n, dtype=torch.float64)
    matrix = q @ torch.diag_embed(eigenvalues.expand(n_problems, n)) @ q.mT
    linear = torch.randn(n_problems, n, generator=generator, dtype=torch.float64) * 2
    return quadratic_fun(matrix, linear), matrix, linear


def scipy_solve(fun, x0: np.ndarray, bounds=None) -> np.ndarray:
    """SciPy's L-BFGS-B on one problem given by a torch ``fun``."""

    def value_grad(x):
        f, grad = fun(torch.as_tensor(x)[None])
        return float(f[0]), grad[0].numpy()

    return minimize(
        value_grad, x0, jac=True, method="L-BFGS-B", bounds=bounds, options=SCIPY_TIGHT
    ).x


# --- agreement with SciPy -----------------------------------------------------------------


@pytest.mark.parametrize("n", [2, 10])
@pytest.mark.parametrize("box", [None, (-0.5, 0.8)])
def test_rosenbrock_matches_scipy(n, box):
    x0 = np.where(np.arange(n) % 2 == 0, -1.2, 1.0)
    fun = value_and_grad(rosenbrock)
    lower, upper = box if box else (None, None)
    result = lbfgs_box(fun, torch.tensor(x0)[None], lower, upper, **TIGHT)
    expected = scipy_solve(fun, x0, None if box is None else [box] * n)
    assert bool(result.converged.all())
    np.testing.assert_allclose(result.x[0].numpy(), expected, atol=1e-6)


@pytest.mark.parametrize("box", [20.0, 0.05], ids=["bounds-inactive", "bounds-active"])
def test_quadratic_n36_matches_scipy(box):
    fun, *_ = random_quadratics(1, 36, seed=1)
    result = lbfgs_box(fun, torch.zeros(1, 36, dtype=torch.float64), -box, box, **TIGHT)
    expected = scipy_solve(fun, np.zeros(36), [(-box, box)] * 36)
    at_bound = np.isclose(np.abs(expected), box).sum()
    assert (at_bound == 0) if box == 20.0 else (at_bound > 10)
    assert bool(result.converged.all())
    np.testing.assert_allclose(result.x[0].numpy(), expected, atol=1e-6)


def test_nonconvex_box_matches_scipy():
    x0 = np.linspace(-1.0, 1.5, 8)
    fun = value_and_grad(styblinski_tang)
    result = lbfgs_box(fun, torch.tensor(x0)[None], -4.0, 2.5, **TIGHT)
    expected = scipy_solve(fun, x0, [(-4.0, 2.5)] * 8)
    np.testing.assert_allclose(result.x[0].numpy(), expected, atol=1e-6)
    assert (expected == 2.5).any() and (expected > -4.0).all()  # one bound active
    assert (expected < 0).any() and (expected > 0).any()  # both basins


# --- batching -------------------------------------------------------------------------------


def test_batched_problems_equal_each_solved_alone():
    n_problems, n = 5, 36
    fun, matrix, linear = random_quadratics(n_problems, n, seed=2)
    upper = torch.linspace(0.02, 2.0, n_problems, dtype=torch.float64)[:, None].expand(-1, n)
    x0 = torch.randn(n_problems, n, dtype=torch.float64) * 0.01
    together = lbfgs_box(fun, x0, -upper, upper)
    for b in range(n_problems):
        fun_b = quadratic_fun(matrix[b : b + 1], linear[b : b + 1])
        alone = lbfgs_box(fun_b, x0[b : b + 1], -upper[b], upper[b])
        torch.testing.assert_close(together.x[b], alone.x[0], rtol=0, atol=1e-10)
        assert together.n_iter[b] == alone.n_iter[0]
        assert together.converged[b] == alone.converged[0]
    assert len(set(together.n_iter.tolist())) > 1  # problems stopped at different rounds


def test_serial_trials_reach_the_same_optimum_with_fewer_points():
    fun, *_ = random_quadratics(3, 36, seed=3)
    x0 = torch.zeros(3, 36, dtype=torch.float64)
    batched = lbfgs_box(fun, x0, -0.1, 0.1, **TIGHT)
    serial = lbfgs_box(fun, x0, -0.1, 0.1, batched_trials=False, **TIGHT)
    torch.testing.assert_close(serial.x, batched.x, rtol=0, atol=1e-8)
    assert (serial.n_evals < batched.n_evals).all()


# --- invariants -----------------------------------------------------------------------------


@st.composite
def boxed_problems(draw):
    """Random bounds (some variables fixed, some sides open) and a random quadratic + quartic
    objective per problem, possibly nonconvex, with a start partly outside the box."""
    n_problems = draw(st.integers(1, 3))
    n = draw(st.integers(1, 8))
    seed = draw(st.integers(0, 2**31 - 1))
    generator = torch.Generator().manual_seed(seed)

    def randn(*shape):
        return torch.randn(*shape, generator=generator, dtype=torch.float64)

    lower = randn(n_problems, n)
    upper = lower + randn(n_problems, n).abs() * draw(st.sampled_from([0.0, 0.01, 1.0, 10.0]))
    open_side = torch.rand(n_problems, n, generator=generator) < 0.2
    lower = lower.masked_fill(open_side, -torch.inf)
    factor = randn(n_problems, n, n)
    matrix = factor @ factor.mT - draw(st.sampled_from([0.0, 2.0])) * torch.eye(n)
    linear = randn(n_problems, n) * 3
    quartic = torch.rand(n_problems, 1, generator=generator, dtype=torch.float64) + 0.1
    x0 = randn(n_problems, n) * 3
    return lower, upper, matrix, linear, quartic, x0


@settings(max_examples=40, deadline=None)
@given(boxed_problems())
def test_iterates_stay_in_the_box_and_f_never_increases(problem):
    lower, upper, matrix, linear, quartic, x0 = problem
    n_problems, n = x0.shape
    evaluated = []

    def objective(x):
        rows = x.view(-1, n_problems, n)
        quad = 0.5 * torch.einsum("kbi,bij,kbj->kb", rows, matrix, rows) + (rows * linear).sum(-1)
        f = quad + (quartic * rows**4).sum(-1)
        evaluated.append((rows.detach().clone(), f.detach().clone()))
        return f.reshape(-1)

    history = []
    result = lbfgs_box(
        value_and_grad(objective),
        x0,
        lower,
        upper,
        memory=5,
        max_iter=30,
        callback=lambda x, f: history.append((x.clone(), f.clone())),
    )
    points = [rows for rows, _ in evaluated] + [x[None] for x, _ in history] + [result.x[None]]
    for rows in points:
        assert bool(((rows >= lower) & (rows <= upper)).all())
    fixed = lower == upper
    assert bool((result.x[fixed] == lower[fixed]).all())
    f_history = torch.stack([evaluated[0][1][0]] + [f for _, f in history])
    assert bool((f_history[1:] <= f_history[:-1]).all())


def test_wrong_gradient_stops_unconverged_without_raising_f():
    def fun(x):
        f, grad = value_and_grad(rosenbrock)(x)
        return f, -grad  # an ascent "gradient": no trial can meet Armijo

    x0 = torch.tensor([[-1.2, 1.0]], dtype=torch.float64)
    result = lbfgs_box(fun, x0, -2.0, 2.0, max_iter=100)
    assert not bool(result.converged[0])
    assert int(result.n_iter[0]) < 100  # it gave up: step sizes shrank below MIN_STEP_SCALE
    torch.testing.assert_close(result.x, x0)


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
def test_compiled_bookkeeping_matches_eager():
    fun = value_and_grad(rosenbrock)
    x0 = torch.tensor([[-1.2, 1.0, -1.2, 1.0]], dtype=torch.float64)
    eager = lbfgs_box(fun, x0, -0.5, 0.8, max_iter=60)
    compiled = lbfgs_box(fun, x0, -0.5, 0.8, max_iter=60, compile_steps=True)
    torch.testing.assert_close(compiled.x, eager.x, rtol=0, atol=1e-12)
    assert compiled.n_iter.tolist() == eager.n_iter.tolist()


def _shifted_rosenbrock(x, shift, scale):
    """``fun`` of the Rosenbrock function of ``scale·(x − shift)``, data passed as args."""

    def total(z):
        f = rosenbrock(scale * (z - shift))
        return f.sum(), f

    grad, f = torch.func.grad(total, has_aux=True)(x)
    return f, grad


def test_args_reach_fun():
    x0 = torch.zeros(1, 4, dtype=torch.float64)
    shift, scale = torch.full((4,), 0.25, dtype=torch.float64), torch.tensor(2.0).double()
    result = lbfgs_box(_shifted_rosenbrock, x0, args=(shift, scale), **TIGHT)
    torch.testing.assert_close(result.x, (1 / scale + shift).expand(1, 4))


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
@pytest.mark.parametrize("max_iter", [7, 60])  # stopped by the cap inside a call; converged
def test_traced_fun_matches_eager(max_iter):
    """compile_fun traces fun into the rounds' compiled graph: the same iterates."""
    x0 = torch.tensor([[-1.2, 1.0, -1.2, 1.0], [0.3, 0.2, 0.1, 0.0]], dtype=torch.float64)
    args = (torch.full((4,), 0.1, dtype=torch.float64), torch.tensor(1.5, dtype=torch.float64))
    eager = lbfgs_box(_shifted_rosenbrock, x0, -0.5, 0.8, max_iter=max_iter, args=args)
    traced = lbfgs_box(
        _shifted_rosenbrock,
        x0,
        -0.5,
        0.8,
        max_iter=max_iter,
        args=args,
        compile_steps=True,
        compile_fun=True,
    )
    torch.testing.assert_close(traced.x, eager.x, rtol=0, atol=1e-12)
    assert traced.n_iter.tolist() == eager.n_iter.tolist()
    assert traced.n_evals.tolist() == eager.n_evals.tolist()
    assert traced.converged.tolist() == eager.converged.tolist()
    if max_iter == 7:  # the cap stops the rounds inside the second call
        assert eager.n_iter.max() == 7
    else:  # both converge, in different rounds: one stays frozen while the other runs
        assert bool(eager.converged.all()) and len(set(eager.n_iter.tolist())) == 2


def _shift_and_scale(centre, scale):
    """A ``prepare``: the shift of :func:`_shifted_rosenbrock` from its ``centre`` ``(n,)``."""
    return centre - 1 / scale, scale


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
@pytest.mark.parametrize("traced", [False, True])
def test_prepare_works_out_funs_arguments_once(traced):
    """``prepare`` turns ``args`` into fun's arguments before the start (inside the start's
    compiled call when traced): the iterates of fun given the prepared arguments directly."""
    x0 = torch.tensor([[-1.2, 1.0, -1.2, 1.0], [0.3, 0.2, 0.1, 0.0]], dtype=torch.float64)
    centre, scale = torch.full((4,), 0.6, dtype=torch.float64), torch.tensor(1.5).double()
    options = dict(max_iter=40, compile_steps=traced, compile_fun=traced)
    direct = lbfgs_box(
        _shifted_rosenbrock, x0, -0.5, 0.8, args=_shift_and_scale(centre, scale), **options
    )
    prepared = lbfgs_box(
        _shifted_rosenbrock, x0, -0.5, 0.8, args=(centre, scale), prepare=_shift_and_scale,
        **options,
    )  # fmt: skip
    torch.testing.assert_close(prepared.x, direct.x, rtol=0, atol=1e-12)
    assert prepared.n_iter.tolist() == direct.n_iter.tolist()
    assert bool(prepared.converged.all())
    torch.testing.assert_close(prepared.x[0], centre, rtol=0, atol=1e-5)  # the minimum


def test_only_guards_on_globals_identity_are_left_out():
    """The traced graphs' guard filter keeps guards on arguments and on globals' values."""
    from types import SimpleNamespace

    from torchcontact.mpc.optim import GLOBAL_IDENTITY_GUARDS, _keep_guard

    entries = [
        SimpleNamespace(is_global=True, guard_type="ID_MATCH"),  # e.g. G['torch'].cat
        SimpleNamespace(is_global=True, guard_type="CLOSURE_MATCH"),  # a global function's code
        SimpleNamespace(is_global=True, guard_type="CONSTANT_MATCH"),  # ROUNDS_PER_CALL == 4
        SimpleNamespace(is_global=False, guard_type="ID_MATCH"),  # the objective's own code
        SimpleNamespace(is_global=False, guard_type="TENSOR_MATCH"),
    ]
    assert _keep_guard(entries) == [False, False, True, True, True]
    assert "CONSTANT_MATCH" not in GLOBAL_IDENTITY_GUARDS
    assert "TENSOR_MATCH" not in GLOBAL_IDENTITY_GUARDS


def _rotated_rosenbrock(x, rotations):
    """``fun`` of the Rosenbrock function of ``x`` turned by batched 3×3 ``rotations``: the
    small batched products pytorch-kinematics' transforms make."""

    def total(z):
        turned = torch.bmm(rotations.expand(z.shape[0], -1, -1), z.unsqueeze(-1)).squeeze(-1)
        f = rosenbrock(turned)
        return f.sum(), f

    grad, f = torch.func.grad(total, has_aux=True)(x)
    return f, grad


def _products(run) -> list:
    """Input shapes of the ``aten::bmm`` calls ``run()`` makes."""
    with torch.profiler.profile(
        activities=[torch.profiler.ProfilerActivity.CPU], record_shapes=True
    ) as profile:
        run()
    return [event.input_shapes for event in profile.events() if event.name == "aten::bmm"]


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
def test_traced_rounds_fuse_small_batched_products():
    """The traced graph writes the objective's bmm (its 4 trial points' 3×3 turns) as fused
    pointwise products: the eager rounds call it, the traced ones do not."""
    x0 = torch.tensor([[0.5, 0.2, -0.3]], dtype=torch.float64)
    angle = torch.tensor(0.3, dtype=torch.float64)
    c, s = torch.cos(angle), torch.sin(angle)
    rotations = torch.stack([torch.stack([c, -s, 0 * c]), torch.stack([s, c, 0 * c])])
    rotations = torch.cat([rotations, torch.tensor([[0.0, 0.0, 1.0]]).double()])[None]
    options = dict(max_iter=20, args=(rotations,), compile_steps=True)
    trials = [[4, 3, 3], [4, 3, 1]]  # the objective's product over the 4 trial points

    def solve(traced):
        return lbfgs_box(_rotated_rosenbrock, x0, -2.0, 2.0, compile_fun=traced, **options)

    eager, traced = solve(False), solve(True)  # the second compiles
    assert trials in _products(lambda: solve(False))
    assert trials not in _products(lambda: solve(True))
    torch.testing.assert_close(traced.x, eager.x, rtol=0, atol=1e-9)  # summed in another order


@pytest.mark.parametrize("options", [{}, {"compile_steps": True, "batched_trials": False}])
def test_traced_fun_needs_compiled_batched_rounds(options):
    with pytest.raises(ValueError, match="compile_fun needs compile_steps=True"):
        lbfgs_box(_fun, torch.zeros(1, 2), compile_fun=True, **options)


def test_start_at_the_optimum_takes_no_round():
    fun = value_and_grad(rosenbrock)
    result = lbfgs_box(fun, torch.ones(2, 4, dtype=torch.float64))
    assert result.n_iter.tolist() == [0, 0] and result.n_evals.tolist() == [1, 1]
    assert bool(result.converged.all())


def test_float32():
    fun = value_and_grad(rosenbrock)
    x0 = torch.tensor([[-1.2, 1.0, -1.2, 1.0]])
    result = lbfgs_box(fun, x0, -0.5, 0.8, max_iter=200, tol_grad=1e-4)
    reference = lbfgs_box(fun, x0.double(), -0.5, 0.8, **TIGHT)
    assert result.x.dtype == result.f.dtype == torch.float32
    torch.testing.assert_close(result.x.double(), reference.x, rtol=0, atol=1e-3)


@pytest.mark.parametrize("device", DEVICES)
def test_runs_on_device(device):
    fun, *_ = random_quadratics(2, 36, seed=4)
    x0 = torch.zeros(2, 36, dtype=torch.float64)
    expected = lbfgs_box(fun, x0, -0.1, 0.1)

    def fun_on_device(x):
        f, grad = fun(x.cpu())
        return f.to(device), grad.to(device)

    lower = torch.tensor(-0.1, dtype=torch.float64, device=device)
    result = lbfgs_box(fun_on_device, x0.to(device), lower, 0.1)
    assert result.x.device.type == device
    torch.testing.assert_close(result.x.cpu(), expected.x, rtol=0, atol=1e-10)


# --- bad input ------------------------------------------------------------------------------


def _fun(x):
    return (x**2).sum(-1), 2 * x


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"x0": torch.zeros(3)}, "x0 must have shape"),
        ({"x0": torch.zeros(1, 2, 3)}, "x0 must have shape"),
        ({"x0": torch.zeros(0, 3)}, "x0 must have shape"),
        ({"x0": torch.tensor([[0.0, float("nan")]])}, "x0 must be finite"),
        ({"lower": 1.0, "upper": 0.0}, "lower must not exceed upper"),
        ({"lower": torch.zeros(3)}, "lower must have shape"),
        ({"upper": torch.zeros(2, 2, 2)}, "upper must have shape"),
        ({"lower": float("nan")}, "lower must not be NaN"),
        ({"upper": -float("inf")}, "upper must not be NaN or -inf"),
        ({"memory": 0}, "memory must be a positive integer"),
        ({"memory": True}, "memory must be a positive integer"),
        ({"max_iter": 0}, "max_iter must be a positive integer"),
        ({"tol_grad": -1.0}, "tol_grad must be non-negative"),
        ({"trial_steps": ()}, "trial_steps must be positive"),
        ({"trial_steps": (1.0, 0.0)}, "trial_steps must be positive"),
        ({"trial_steps": (0.5, 1.0)}, "trial_steps must be strictly decreasing"),
    ],
)
def test_bad_input_names_the_argument(kwargs, message):
    arguments = {"x0": torch.zeros(2, 2), **kwargs}
    with pytest.raises(ValueError, match=message):
        lbfgs_box(_fun, **arguments)


def test_integer_x0_is_a_type_error():
    with pytest.raises(TypeError, match="x0 must be a floating-point tensor"):
        lbfgs_box(_fun, torch.zeros(2, 2, dtype=torch.int64))


@pytest.mark.parametrize("compile_steps", [False, True])
def test_float32_pair_whose_y_underflows_stays_finite(compile_steps):
    """f = ½·a·‖x‖² (a = 1e-6) from x = (1e-12, 0) in float32: the first step s ≈ −1e-18 gives
    y = a·s ≈ 1e-24, whose ‖y‖² underflows to 0 while sᵀy ≈ 1e-42 does not. Such a pair must
    not enter the memory: it made γ = sᵀy/‖y‖² infinite and −γ·g NaN on x₁, whose gradient is
    0 (an Allegro MPC step near convergence raised "fun returned NaN" so)."""
    curvature = 1e-6

    def fun(x):
        return 0.5 * curvature * x.square().sum(-1), curvature * x

    x0 = torch.tensor([[1e-12, 0.0]])
    result = lbfgs_box(
        fun,
        x0,
        -torch.ones(1, 2),
        torch.ones(1, 2),
        max_iter=5,
        tol_grad=0.0,
        tol_change=0.0,
        compile_steps=compile_steps,
    )
    assert torch.isfinite(result.x).all() and torch.isfinite(result.f).all()
    assert result.n_iter.item() >= 1 and result.f.item() < 0.5 * curvature * 1e-24


@pytest.mark.parametrize("batched_trials", [True, False])
def test_non_finite_objective_raises(batched_trials):
    def fun(x):
        f, grad = _fun(x)
        return torch.where((x[:, 0] > 0.5) & (x[:, 0] < 1.5), torch.nan, f), grad

    with pytest.raises(ValueError, match="fun returned NaN or Inf"):
        lbfgs_box(fun, torch.full((1, 2), 2.0), batched_trials=batched_trials)
    with pytest.raises(ValueError, match="fun returned NaN or Inf at x0"):
        lbfgs_box(fun, torch.full((1, 2), 0.7))


@pytest.mark.parametrize(
    ("fun", "message"),
    [
        (lambda x: ((x**2).sum(), 2 * x), r"fun's f must have shape \(2,\)"),
        (lambda x: ((x**2).sum(-1), 2 * x[:, :1]), "fun's grad must have shape"),
        (lambda x: (x**2).sum(-1), "fun must return a pair of tensors"),
    ],
)
def test_malformed_fun_output_raises(fun, message):
    with pytest.raises(ValueError, match=message):
        lbfgs_box(fun, torch.zeros(2, 3))
