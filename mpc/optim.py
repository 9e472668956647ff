"""Batched, box-projected L-BFGS in pure torch: the MPC's inner solver.

Minimises B independent problems ``f_b(x_b)`` over boxes ``lower_b ≤ x_b ≤ upper_b`` at once::

    fun = value_and_grad(cost)          # cost: (N, n) -> (N,) with rows independent
    result = lbfgs_box(fun, u0, lower=-0.005, upper=0.005)      # u0: (B, n)

The algorithm is projected-gradient L-BFGS in the style of L-BFGS-B "lite" (Bertsekas' projected
Newton step with a quasi-Newton matrix; Kim, Sra & Dhillon 2010). Each round:

1. **Fixed set.** A variable at a bound whose gradient pushes it outward is held fixed, the
   others are free. The projected gradient ``P(x − g) − x`` is zero exactly on the fixed
   variables (and where g = 0); its ∞-norm is the convergence measure, as in L-BFGS-B.
2. **Direction.** ``d = −H_F Z g``: ``Z`` zeroes the fixed variables and ``H_F`` is the L-BFGS
   inverse Hessian built from the stored pairs restricted to the free variables,
   ``(Z s_i, Z y_i)``, so that bound-held variables do not distort the curvature of the free
   ones. Pairs whose restricted curvature ``(Z s)ᵀ(Z y) ≤ ε‖Z s‖‖Z y‖`` are left out, which
   keeps ``H_F`` positive definite, so ``d`` is a descent direction, and free variables at a
   bound that ``d`` pushes outward (clipped by ``P``) only make the projected path steeper.
   ``H_F Z g`` is evaluated in the compact form (Byrd, Nocedal & Schnabel 1994): a few small
   dense products instead of the two-loop recursion's 4·m tiny operations. Should rounding still
   break descent, ``d`` is projected steepest descent ``−γ Z g``.
3. **Line search on the projected path.** The trial points ``P(x + α d)`` for the K step sizes
   ``α`` of ``trial_steps`` are evaluated in ONE call of ``fun``. Of those meeting the Armijo
   condition on the projected step, ``f(x_α) ≤ f(x) + c₁ gᵀ(x_α − x)`` with
   ``gᵀ(x_α − x) < 0``, the one with the lowest f is taken (all K are paid for), so f never
   increases. If none meets it, the next round backtracks along the same direction with the
   step sizes shrunk by ``STEP_SHRINK``; once they are below ``RESTART_SCALE`` the memory is
   cleared instead (as L-BFGS-B restarts) and steepest descent tried, and a problem whose
   steepest-descent steps shrink below ``MIN_STEP_SCALE`` stops unconverged.
4. **Memory.** The pair ``s = Δx, y = Δg`` of an accepted step enters the memory (dropping the
   oldest) when ``sᵀy > ε‖s‖‖y‖`` (ε: machine epsilon), and sets H₀ = γI with γ = sᵀy / yᵀy.

Every point handed to ``fun`` or returned lies in the box exactly: the projection
``P(z) = clamp(z, lower, upper)`` is part of the algorithm, and ``x0`` is projected before the
first evaluation, as L-BFGS-B does. Problems converge independently and stop changing; the loop
ends when none is running or after ``max_iter`` rounds. Each round syncs with the host once
(whether ``fun`` returned finite numbers and whether any problem runs; serial trials add one
per trial).

Cost: a round's bookkeeping is one pure function of tensors, :func:`_step`, about 170 small
torch calls for any B, dispatch-bound on one CPU thread, which ``compile_steps=True`` compiles
into one graph (``benchmarks/lbfgs_overhead.py`` times both); a round calls ``fun`` once.
With ``compile_fun=True`` as well, a traceable ``fun`` is compiled into the same graph as the
bookkeeping, :data:`ROUNDS_PER_CALL` rounds per call, which is how the MPC runs: for small
problems a compiled call's fixed cost outweighs its kernels.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import torch

from torchcontact.validation import (
    check_finite,
    check_nonnegative,
    check_shape,
    check_tensor,
    checking_values,
)

ARMIJO_C1 = 1e-4
"""Sufficient-decrease constant c₁ of the Armijo condition."""

STEP_SHRINK = 0.05
"""Factor on the trial step sizes after a round in which none met the Armijo condition."""

RESTART_SCALE = 0.01
"""A quasi-Newton direction whose step sizes have shrunk below this and still fail is given up:
the memory is cleared and the next round restarts from steepest descent."""

MIN_STEP_SCALE = 1e-6
"""A problem stops, unconverged, once steepest descent's step sizes have shrunk below this."""

Fun = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
"""``fun(x: (N, n)) -> (f: (N,), grad: (N, n))``, rows independent; see :func:`lbfgs_box`."""


class LbfgsResult(NamedTuple):
    """What :func:`lbfgs_box` returns for B problems of n variables."""

    x: torch.Tensor
    """(B, n) the last accepted iterates, inside the box."""
    f: torch.Tensor
    """(B,) objective at ``x``."""
    grad: torch.Tensor
    """(B, n) gradient at ``x``."""
    converged: torch.Tensor
    """(B,) bool: the projected-gradient or objective-change tolerance was met."""
    projected_grad_norm: torch.Tensor
    """(B,) ‖P(x − grad) − x‖∞, zero at a box-constrained stationary point."""
    n_iter: torch.Tensor
    """(B,) int64 line-search rounds each problem ran (one call of ``fun`` each when batched)."""
    n_evals: torch.Tensor
    """(B,) int64 points at which each problem's objective was evaluated, the start included."""


class _State(NamedTuple):
    """The optimizer's per-problem state between rounds (B problems, n variables, memory m)."""

    x: torch.Tensor  # (B, n) iterate, inside the box
    f: torch.Tensor  # (B,)
    grad: torch.Tensor  # (B, n)
    free: torch.Tensor  # (B, n) bool: projected gradient ≠ 0
    pg_norm: torch.Tensor  # (B,) ‖P(x − g) − x‖∞
    pairs: torch.Tensor  # (B, m, 2, n) (s_i, y_i), oldest first, zero in empty slots
    gamma: torch.Tensor  # (B,) H₀ = γI
    step_scale: torch.Tensor  # (B,) factor on trial_steps, < 1 after failed rounds
    empty: torch.Tensor  # (B,) bool: no pair in the memory
    running: torch.Tensor  # (B,) bool
    converged: torch.Tensor  # (B,) bool
    n_iter: torch.Tensor  # (B,) int64
    n_evals: torch.Tensor  # (B,) int64


class _Settings(NamedTuple):
    """What stays fixed during a solve."""

    lower: torch.Tensor | None  # broadcastable to (B, n); None when unbounded
    upper: torch.Tensor | None
    steps: torch.Tensor  # (K, 1, 1) trial step sizes
    tol_grad: float
    tol_change: float
    curvature_eps: float
    problem_index: torch.Tensor  # (B,) 0 … B−1


def value_and_grad(objective: Callable[[torch.Tensor], torch.Tensor]) -> Fun:
    """Turn a differentiable ``objective(x: (N, n)) -> (N,)`` whose rows do not interact into
    a ``fun`` for :func:`lbfgs_box`, the gradient from autograd."""

    def fun(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        with torch.enable_grad():
            x = x.detach().requires_grad_(True)
            f = objective(x)
            (grad,) = torch.autograd.grad(f.sum(), x)
        return f.detach(), grad

    return fun


def lbfgs_box(
    fun: Fun,
    x0: torch.Tensor,
    lower: torch.Tensor | float | None = None,
    upper: torch.Tensor | float | None = None,
    *,
    memory: int = 10,
    max_iter: int = 50,
    tol_grad: float = 1e-6,
    tol_change: float = 1e-9,
    trial_steps: Sequence[float] = (1.0, 0.5, 0.25, 0.1),
    batched_trials: bool = True,
    compile_steps: bool = False,
    args: tuple = (),
    compile_fun: bool = False,
    callback: Callable[[torch.Tensor, torch.Tensor], None] | None = None,
    prepare: Callable[..., tuple] | None = None,
) -> LbfgsResult:
    """Minimise B independent box-constrained problems with projected L-BFGS.

    Args:
        fun: ``fun(x: (N, n), *args) -> (f: (N,), grad: (N, n))``, each row evaluated on its
            own. It is called with N = B for the start and, when ``batched_trials``, with
            N = K·B for a round's K trial steps, row ``k·B + b`` being trial k of problem b
            (so ``x.view(-1, B, n)`` puts problem b in column b); with
            ``batched_trials=False``, N = B always. Problems that have stopped are still
            passed (frozen), to keep shapes fixed.
        x0: (B, n) start; projected onto the box first.
        lower, upper: bounds broadcastable to (B, n), scalars, or None (unbounded on that side);
            ``lower = upper`` fixes a variable.
        memory: m, the number of (s, y) pairs kept per problem.
        max_iter: the most line-search rounds.
        tol_grad: a problem converges when ‖P(x − g) − x‖∞ ≤ ``tol_grad`` ...
        tol_change: ... or when an accepted step lowers f by at most ``tol_change · max(|f|, 1)``.
        trial_steps: the K step sizes α tried per round, strictly decreasing. The first round
            steps along ``−min(1, 1/‖Z g‖)·Z g``, as L-BFGS-B does.
        batched_trials: evaluate a round's trial steps in one call of ``fun`` and take the
            best Armijo point; else evaluate them in order and stop at the first step every
            running problem accepts (the best of those evaluated is taken).
        compile_steps: ``torch.compile`` the optimizer's own per-round bookkeeping (seconds to
            compile once per shape and dtype; worth it in a loop such as MPC).
        args: extra arguments of ``fun``, passed after ``x`` (tensors, or tuples of them):
            the data a compiled ``fun`` takes as graph inputs rather than capturing them.
        compile_fun: with ``compile_steps`` and ``batched_trials``, trace ``fun`` into the
            same compiled graph as the bookkeeping: one compiled call runs
            :data:`ROUNDS_PER_CALL` whole rounds (the start's evaluation is a call of its
            own), with the same iterates as without. ``fun`` must then be traceable by
            ``torch.compile`` without graph breaks (no host syncs, no control flow on values)
            and be the same function object from solve to solve (a method of a long-lived
            object, not a fresh closure), or each solve compiles anew.
        callback: called after every round (with ``compile_fun``: every compiled call) with
            the current ``x: (B, n)`` and ``f: (B,)`` (read only), e.g. to record the
            objective's history.
        prepare: ``prepare(*args) -> tuple``, or None: the arguments ``fun`` takes after
            ``x``, worked out from ``args`` once per solve, before the start's evaluation
            (with ``compile_fun``, inside the start's compiled call, so that work such as an
            MPC's contact-model freeze costs no compiled call of its own). Like ``fun``, it
            must then be traceable and the same function object from solve to solve.

    Returns:
        :class:`LbfgsResult`.

    Raises:
        TypeError: when ``x0`` or a tensor bound is not a floating-point tensor.
        ValueError: for a malformed argument (named), or when ``fun`` returns NaN/Inf or
            tensors of the wrong shape.
    """
    x0, lower, upper = _check_inputs(x0, lower, upper, memory, max_iter, tol_grad, tol_change)
    settings = _Settings(
        lower=lower,
        upper=upper,
        steps=_check_trial_steps(tuple(trial_steps), x0.dtype, x0.device),
        tol_grad=float(tol_grad),
        tol_change=float(tol_change),
        curvature_eps=torch.finfo(x0.dtype).eps,
        problem_index=_problem_index(x0.shape[0], x0.device),
    )
    if compile_fun and not (compile_steps and batched_trials):
        raise ValueError("compile_fun needs compile_steps=True and batched_trials=True")
    step = _compiled_step() if compile_steps else _step
    start = _compiled_start() if compile_fun else _start
    state, trials, predicted, finite, args = start(fun, tuple(args), prepare, x0, memory, settings)
    fun = _Bound(fun, args)
    if not bool(finite):
        raise ValueError("fun returned NaN or Inf at x0 (f and grad must be finite in the box)")

    per_call = ROUNDS_PER_CALL if compile_fun else 1
    for done in range(0, max_iter if bool(state.running.any()) else 0, per_call):
        if compile_fun:
            budget = torch.tensor(max_iter - done, device=x0.device)  # a tensor: one graph
            state, trials, predicted, flags = _compiled_rounds()(
                fun.fun, fun.args, state, trials, predicted, settings, budget
            )
        else:
            if batched_trials:
                trial_f, trial_grad = _call(fun, trials)
                n_evaluated = len(settings.steps)
            else:
                trials, predicted, trial_f, trial_grad, n_evaluated = _evaluate_serially(
                    fun, trials, predicted, state
                )
            state, trials, predicted, flags = step(
                state, trials, predicted, trial_f, trial_grad, n_evaluated, settings
            )
        finite, keep_going = flags.tolist()
        if not finite:
            raise ValueError("fun returned NaN or Inf (f and grad must be finite in the box)")
        if callback is not None:
            callback(state.x, state.f)
        if not keep_going:
            break

    return LbfgsResult(
        state.x, state.f, state.grad, state.converged, state.pg_norm, state.n_iter, state.n_evals
    )


class _Bound(NamedTuple):
    """``fun`` with its extra ``args`` bound: ``x -> fun(x, *args)``."""

    fun: Callable
    args: tuple

    def __call__(self, x: torch.Tensor):
        return self.fun(x, *self.args)


ROUNDS_PER_CALL = 4
"""Rounds one compiled call runs with ``compile_fun``. A traced objective's tensors are tiny,
so a call costs mostly its fixed overhead (guards, argument flattening, the host sync of
the flags), which several rounds share; 4 chosen by measurement, at a longer compile time
(see docs/experiments.md, "Speed").
A problem that stops within a call stays frozen for the call's remaining rounds (the iterates
are those of one round per call); the call's ``budget`` stops every problem after ``max_iter``
rounds."""


def _rounds(
    fun: Callable,
    args: tuple,
    state: _State,
    trials: torch.Tensor,
    predicted: torch.Tensor,
    settings: _Settings,
    budget: torch.Tensor,
) -> tuple[_State, torch.Tensor, torch.Tensor, torch.Tensor]:
    """:data:`ROUNDS_PER_CALL` rounds for ``compile_fun``, each ``fun`` at the trials then
    :func:`_step`; ``budget`` (0-d int): rounds left of ``max_iter``, after which the
    problems stop running. Returns what :func:`_step` does, the flags of all rounds."""
    finite = torch.ones((), dtype=torch.bool, device=budget.device)
    for k in range(ROUNDS_PER_CALL):
        state = state._replace(running=state.running & (budget > k))
        f, grad = _call(_Bound(fun, args), trials)
        state, trials, predicted, flags = _step(
            state, trials, predicted, f, grad, len(settings.steps), settings
        )
        finite = finite & flags[0]
    return state, trials, predicted, torch.stack([finite, flags[1]])


TRACED_FUN_OPTIONS = {"cpp_wrapper": True, "post_grad_fusion_options": {"decompose_mm_pass": {}}}
"""Inductor options of the graphs that trace ``fun`` (``compile_fun``). A traced objective's
graph is large but its tensors tiny, so a call costs more in the generated Python wrapper
(buffer allocation and views) than in its kernels; a C++ wrapper makes the round cheaper
(measured, see docs/experiments.md, "Speed"), at a longer first compilation (cached
on disk like the rest). Inductor's ``decompose_mm_pass`` writes small matrix products as
pointwise products and sums, which fuse with their neighbours, instead of external BLAS calls
of a few µs each, such as pytorch-kinematics' 4×4 transforms (:data:`SMALL_PRODUCTS`)."""

SMALL_PRODUCTS = {
    "cpu_max_first_dimension_decomposition": 4096,
    "cpu_max_other_dimension_decomposition": 64,
}
"""Which CPU products ``decompose_mm_pass`` rewrites: batched products of at most 4096
matrices, and 2-D ones whose sides are all at most 64 (Inductor's defaults, 1 and 2048, leave
batched products alone). Set when the first traced graph compiles; other graphs do not run
the pass."""


TRACED_GRAPHS = 64
"""The most graphs of the traced rounds one process keeps (Dynamo's recompile limit)."""

GLOBAL_IDENTITY_GUARDS = frozenset(
    {"ID_MATCH", "TYPE_MATCH", "CLOSURE_MATCH", "BUILTIN_MATCH", "MODULE_MATCH", "CLASS_MATCH",
     "FUNCTION_MATCH"}
)  # fmt: skip
"""Kinds of Dynamo guard left out of the traced graphs when they check a module global:
that a global name (``torch.cat``, a module, a function this module or the objective calls)
still refers to the object traced. A traced round calls hundreds of such names, and checking
them cost 6–8 % of a TriFinger solve (docs/experiments.md, "Speed"). Left out, a graph
outlives a reassignment of those names at run time (monkeypatching, ``importlib.reload``);
guards on global *values* (``ROUNDS_PER_CALL``, ``ARMIJO_C1``), on the arguments and on
everything reached from them (the objective's own code and attributes) stay."""


def _keep_guard(entries) -> list[bool]:
    """Dynamo's ``guard_filter_fn`` of the traced graphs: all but
    :data:`GLOBAL_IDENTITY_GUARDS` on globals."""
    return [not (e.is_global and e.guard_type in GLOBAL_IDENTITY_GUARDS) for e in entries]


def _traced(function: Callable) -> Callable:
    """``function`` through ``torch.compile`` for ``compile_fun``.

    Each problem size, dtype and objective compiles a graph of its own, and a process that
    sweeps MPC settings needs more than Dynamo's default 8 per function, after which it would
    silently run eagerly: the limit is raised to :data:`TRACED_GRAPHS`. Guards on globals'
    identity are left out (:data:`GLOBAL_IDENTITY_GUARDS`)."""
    config = torch._dynamo.config
    config.recompile_limit = max(config.recompile_limit, TRACED_GRAPHS)
    _decompose_small_products()
    options = {**TRACED_FUN_OPTIONS, "guard_filter_fn": _keep_guard}  # popped by torch.compile
    return torch.compile(function, dynamic=False, fullgraph=True, options=options)


@functools.cache
def _decompose_small_products() -> None:
    """Apply :data:`SMALL_PRODUCTS`: the pass reads its CPU thresholds from module globals
    (set from Inductor's config when it is imported), so they are set there."""
    from torch._inductor.fx_passes import decompose_mem_bound_mm as decompose

    for name, value in SMALL_PRODUCTS.items():
        if not hasattr(decompose, name):  # a torch whose pass changed: keep its defaults
            return
        setattr(decompose, name, value)


@functools.cache
def _compiled_rounds() -> Callable:
    """:func:`_rounds` compiled (``fun`` traced into the rounds' graph)."""
    return _traced(_rounds)


@functools.cache
def _compiled_start() -> Callable:
    """:func:`_start` compiled, ``fun`` traced into it: with ``compile_fun`` the start, its
    bookkeeping and the first round's trials are one call, not a call followed by the
    bookkeeping's small eager operations (0.2–0.3 ms a TriFinger solve, docs/experiments.md,
    "Speed")."""
    return _traced(_start)


def _start(
    fun: Callable,
    args: tuple,
    prepare: Callable[..., tuple] | None,
    x0: torch.Tensor,
    memory: int,
    settings: _Settings,
) -> tuple[_State, torch.Tensor, torch.Tensor, torch.Tensor, tuple]:
    """Work out ``fun``'s arguments (``prepare(*args)``, or ``args`` when None), evaluate
    ``fun`` at the projected start and set up an empty memory. Returns the state, the first
    round's trials and predicted decrease (:func:`_propose`), a 0-d bool: whether ``fun``'s
    outputs were finite (checked by the caller, after the one host sync), and ``fun``'s
    arguments."""
    if prepare is not None:
        args = tuple(prepare(*args))
    lower, upper = settings.lower, settings.upper
    x = _project(x0, lower, upper)
    f, grad = _call(_Bound(fun, args), x)
    projected_grad = _project(x - grad, lower, upper) - x
    free = projected_grad != 0
    pg_norm = projected_grad.abs().amax(-1)
    converged = pg_norm <= settings.tol_grad
    n_problems, n_vars = x.shape
    counts = torch.zeros(n_problems, dtype=torch.int64, device=x.device)
    state = _State(
        x=x,
        f=f,
        grad=grad,
        free=free,
        pg_norm=pg_norm,
        pairs=x.new_zeros(n_problems, memory, 2, n_vars),
        gamma=torch.linalg.vector_norm(grad * free, dim=-1).reciprocal().clamp_max(1),
        step_scale=x.new_ones(n_problems),
        empty=torch.ones_like(converged),
        running=~converged,
        converged=converged,
        n_iter=counts,
        n_evals=counts + 1,
    )
    return (state, *_propose(state, settings), _finite(f, grad), args)


def _step(
    state: _State,
    trials: torch.Tensor,
    predicted: torch.Tensor,
    trial_f: torch.Tensor,
    trial_grad: torch.Tensor,
    n_evaluated: int,
    settings: _Settings,
) -> tuple[_State, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The bookkeeping of one round once ``fun`` has been evaluated at the trials: the new state,
    the next round's trials and predicted decrease, and the flags for the host sync."""
    state, flags = _advance(state, trials, predicted, trial_f, trial_grad, n_evaluated, settings)
    return (state, *_propose(state, settings), flags)


def _propose(state: _State, settings: _Settings) -> tuple[torch.Tensor, torch.Tensor]:
    """The round's trial points ``P(x + α d): (K, B, n)`` and ``gᵀ(x_α − x): (K, B)``."""
    direction = _direction(state.pairs, state.gamma, state.grad, state.free, settings.curvature_eps)
    step = settings.steps * state.step_scale[:, None]  # (K, B, 1)
    trials = _project(state.x + step * direction, settings.lower, settings.upper)
    return trials, torch.linalg.vecdot(trials - state.x, state.grad)


def _direction(
    pairs: torch.Tensor,
    gamma: torch.Tensor,
    grad: torch.Tensor,
    free: torch.Tensor,
    curvature_eps: float,
) -> torch.Tensor:
    """(B, n) search direction −H_F Z g, or −γ Z g where that fails to descend.

    H_F = γI + [S γY] M [S γY]ᵀ is the compact L-BFGS inverse Hessian of the pairs restricted
    to the ``free: (B, n)`` variables (rows of S and Y: Z s_i and Z y_i, oldest first); M is
    built from R = triu(SᵀY), D = diag(SᵀY) and YᵀY (Byrd, Nocedal & Schnabel 1994, thm 2.2).
    A left-out pair (empty slot or too little curvature) has zero rows and R_ii = 1, and then
    contributes nothing. ``pairs: (B, m, 2, n)``, ``gamma: (B,)``.
    """
    n_problems, m = pairs.shape[:2]
    free = free.to(grad.dtype)
    free_grad = grad * free
    rows = pairs * free[:, None, None, :]  # (B, m, 2, n)
    squares = (rows * rows).sum(-1)  # (B, m, 2): ‖Z s_i‖², ‖Z y_i‖²
    s_dot_y = (rows[:, :, 0] * rows[:, :, 1]).sum(-1)
    valid = _curved(s_dot_y, squares[..., 0], squares[..., 1], curvature_eps).to(grad.dtype)
    rows = (rows * valid[:, :, None, None]).flatten(1, 2)  # (B, 2m, n): s_0, y_0, s_1, y_1, …
    gram = torch.bmm(rows, rows.mT)
    r_upper = gram[:, ::2, 1::2].triu()
    r_upper.diagonal(dim1=1, dim2=2).add_(1 - valid)
    projections = torch.bmm(rows, free_grad[:, :, None])  # (B, 2m, 1): s_0ᵀv, y_0ᵀv, …
    gamma_ = gamma[:, None, None]
    c = torch.linalg.solve_triangular(r_upper, projections[:, ::2], upper=True)
    w = (s_dot_y * valid)[:, :, None] * c + gamma_ * (
        torch.bmm(gram[:, 1::2, 1::2], c) - projections[:, 1::2]
    )
    p = torch.linalg.solve_triangular(r_upper.mT, w, upper=False)
    coefficients = torch.stack([p, -gamma_ * c], dim=2).view(n_problems, 2 * m, 1)
    steepest = -gamma[:, None] * free_grad
    direction = steepest - torch.bmm(rows.mT, coefficients)[:, :, 0]
    descent = (direction * free_grad).sum(-1) < 0
    return torch.where(descent[:, None], direction, steepest)


def _curved(
    s_dot_y: torch.Tensor, s_squared: torch.Tensor, y_squared: torch.Tensor, eps: float
) -> torch.Tensor:
    """Whether a pair (s, y) may enter the memory: sᵀy > eps·‖s‖‖y‖, with sᵀy, ‖s‖² and ‖y‖²
    normal numbers. Near convergence in float32 a tiny accepted step can give a y whose ‖y‖²
    underflows to 0 while sᵀy does not (about 1e-23 per element), and such a pair would make
    γ = sᵀy/‖y‖² infinite and the next direction NaN."""
    tiny = torch.finfo(s_dot_y.dtype).tiny
    normal = (s_dot_y >= tiny) & (s_squared >= tiny) & (y_squared >= tiny)
    return normal & (s_dot_y > eps * s_squared.sqrt() * y_squared.sqrt())


def _advance(
    state: _State,
    trials: torch.Tensor,
    predicted: torch.Tensor,
    trial_f: torch.Tensor,
    trial_grad: torch.Tensor,
    n_evaluated: int,
    settings: _Settings,
) -> tuple[_State, torch.Tensor]:
    """Take each running problem's best Armijo step (lowest f), update the memory and the
    stopping flags. Returns the new state and ``[fun's output finite, any problem running]``.

    ``trials: (K, B, n)``, ``predicted: (K, B) = gᵀ(x_α − x)``, ``trial_f: (K, B)``,
    ``trial_grad: (K, B, n)``.
    """
    x, f, grad, running = state.x, state.f, state.grad, state.running
    armijo = (trial_f <= f + ARMIJO_C1 * predicted) & (predicted < 0) & running
    accepted = armijo.any(0)
    best = torch.where(armijo, trial_f, math.inf).argmin(0)  # only used where accepted
    x_new = torch.where(accepted[:, None], trials[best, settings.problem_index], x)
    grad_new = torch.where(accepted[:, None], trial_grad[best, settings.problem_index], grad)
    f_new = torch.where(accepted, trial_f[best, settings.problem_index], f)

    pair = torch.stack([x_new - x, grad_new - grad], dim=1)  # (B, 2, n): s, y
    products = torch.bmm(pair, pair.mT)
    s_dot_y, y_dot_y = products[:, 0, 1], products[:, 1, 1]
    curvature = accepted & _curved(s_dot_y, products[:, 0, 0], y_dot_y, settings.curvature_eps)
    failed = running & ~accepted
    restart = failed & ~state.empty & (state.step_scale < RESTART_SCALE)
    pairs = torch.where(
        curvature[:, None, None, None],
        torch.cat([state.pairs[:, 1:], pair[:, None]], dim=1),
        state.pairs.masked_fill(restart[:, None, None, None], 0),
    )
    gamma = torch.where(curvature, s_dot_y / y_dot_y, state.gamma)
    step_scale = torch.where(failed & ~restart, STEP_SHRINK * state.step_scale, 1.0)

    projected_grad = _project(x_new - grad_new, settings.lower, settings.upper) - x_new
    pg_norm = projected_grad.abs().amax(-1)
    small_decrease = accepted & (f - f_new <= settings.tol_change * f.abs().clamp_min(1))
    newly_converged = running & ((pg_norm <= settings.tol_grad) | small_decrease)
    still_running = running & ~newly_converged & (step_scale >= MIN_STEP_SCALE)
    new_state = _State(
        x=x_new,
        f=f_new,
        grad=grad_new,
        free=projected_grad != 0,
        pg_norm=pg_norm,
        pairs=pairs,
        gamma=gamma,
        step_scale=step_scale,
        empty=(state.empty & ~curvature) | restart,
        running=still_running,
        converged=state.converged | newly_converged,
        n_iter=state.n_iter + running,
        n_evals=state.n_evals + n_evaluated * running,
    )
    return new_state, torch.stack([_finite(trial_f, trial_grad), still_running.any()])


@functools.cache
def _compiled_step() -> Callable:
    """:func:`_step` through ``torch.compile`` (one graph per round; built once, specialised
    per shape and dtype)."""
    return torch.compile(_step, dynamic=False, fullgraph=True)


def _project(
    z: torch.Tensor, lower: torch.Tensor | None, upper: torch.Tensor | None
) -> torch.Tensor:
    """P(z): the nearest point of the box, elementwise (z itself when unbounded)."""
    return z if lower is None else torch.clamp(z, lower, upper)


def _call(fun: Fun, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``fun`` on ``points: (*, B, n)`` flattened to rows; outputs checked, detached, reshaped."""
    x = points.reshape(-1, points.shape[-1])
    out = fun(x)
    if not (isinstance(out, tuple) and len(out) == 2 and all(torch.is_tensor(t) for t in out)):
        raise ValueError("fun must return a pair of tensors (f, grad)")
    f, grad = out
    if f.shape != x.shape[:1]:
        check_shape("fun's f", f, f"({x.shape[0]},)", False)
    if grad.shape != x.shape:
        check_shape("fun's grad", grad, str(tuple(x.shape)), False)
    return f.detach().view(points.shape[:-1]), grad.detach().view(points.shape)


def _finite(f: torch.Tensor, grad: torch.Tensor) -> torch.Tensor:
    """0-d bool: f and grad hold no NaN/Inf (one reduction: a sum is finite iff its terms are,
    barring overflow)."""
    total = f.sum() + grad.sum()
    return (total - total) == 0


def _evaluate_serially(
    fun: Fun, trials: torch.Tensor, predicted: torch.Tensor, state: _State
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """Evaluate the trial steps one call each until every running problem meets Armijo. The
    trials left unevaluated become the current point with ``predicted = 0`` (never accepted).
    Returns trials, predicted, f (K, B), grad (K, B, n) and the number evaluated."""
    trials, predicted = trials.clone(), predicted.clone()
    trial_f = state.f.expand(predicted.shape).clone()
    trial_grad = state.grad.expand(trials.shape).clone()
    done = ~state.running
    for k in range(len(trials)):
        trial_f[k], trial_grad[k] = _call(fun, trials[k])
        done = done | ((trial_f[k] <= state.f + ARMIJO_C1 * predicted[k]) & (predicted[k] < 0))
        if bool(done.all()):
            break
    trials[k + 1 :], predicted[k + 1 :] = state.x, 0
    return trials, predicted, trial_f, trial_grad, k + 1


def _check_inputs(
    x0: torch.Tensor,
    lower: torch.Tensor | float | None,
    upper: torch.Tensor | float | None,
    memory: int,
    max_iter: int,
    tol_grad: float,
    tol_change: float,
) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
    """Validate the arguments; return x0 detached and the bounds as tensors of x0's dtype and
    device (both None when unbounded, ±inf for a missing side)."""
    x0 = check_tensor("x0", x0)
    check_shape("x0", x0, "(B, n) with B, n ≥ 1", x0.ndim == 2 and x0.numel() > 0)
    check_finite("x0", x0)
    for name, value in (("memory", memory), ("max_iter", max_iter)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    check_nonnegative("tol_grad", tol_grad)
    check_nonnegative("tol_change", tol_change)
    x0 = x0.detach().clone()
    if lower is None and upper is None:
        return x0, None, None
    bounds = []
    for name, value, missing in (("lower", lower, -math.inf), ("upper", upper, math.inf)):
        if isinstance(value, torch.Tensor):
            bound = check_tensor(name, value).detach().to(x0)
        else:
            bound = torch.tensor(
                missing if value is None else float(value), dtype=x0.dtype, device=x0.device
            )
        broadcastable = _broadcasts_to(bound.shape, x0.shape)
        check_shape(name, bound, f"broadcastable to x0's {tuple(x0.shape)}", broadcastable)
        if checking_values() and bool((torch.isnan(bound) | (bound == -missing)).any()):
            raise ValueError(f"{name} must not be NaN or {-missing}")
        bounds.append(bound)
    if checking_values() and bool((bounds[0] > bounds[1]).any()):
        raise ValueError("lower must not exceed upper")
    return x0, bounds[0], bounds[1]


def _broadcasts_to(shape: torch.Size, target: torch.Size) -> bool:
    """Whether ``shape`` broadcasts to ``target`` without enlarging it (``torch.broadcast_shapes``
    takes tens of µs, a solve's budget in an MPC)."""
    extra = len(target) - len(shape)
    return extra >= 0 and all(size in (1, target[extra + i]) for i, size in enumerate(shape))


@functools.lru_cache(maxsize=64)
def _check_trial_steps(
    trial_steps: tuple, dtype: torch.dtype, device: torch.device
) -> torch.Tensor:
    """The trial step sizes as a (K, 1, 1) tensor, after checking they are positive and
    decreasing; made once per steps, dtype and device (never written to)."""
    steps = [float(step) for step in trial_steps]
    if not steps or any(not 0 < step < math.inf for step in steps):
        raise ValueError(f"trial_steps must be positive and finite, got {trial_steps!r}")
    if any(later >= earlier for earlier, later in zip(steps, steps[1:], strict=False)):
        raise ValueError(f"trial_steps must be strictly decreasing, got {trial_steps!r}")
    return torch.tensor(steps, dtype=dtype, device=device)[:, None, None]


@functools.lru_cache(maxsize=64)
def _problem_index(n_problems: int, device: torch.device) -> torch.Tensor:
    """``arange(n_problems)``, made once per size and device (never written to)."""
    return torch.arange(n_problems, device=device)
