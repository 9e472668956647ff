"""Planners by name: each turns a batched objective and a box into a plan.

A planner minimizes B independent problems ``f_b(x_b)`` over ``lower ≤ x ≤ upper`` from a start
``x0 (B, n)``. The MPC composes a contact model, a cost and a planner; a new planner is one
class with a :meth:`Planner.plan` method and one :func:`register_planner` call::

    planner("lbfgs", max_iter=15, memory=8, compile=True).plan(objective, x0, (lower, upper))

Two are built in: ``lbfgs`` (:class:`LBFGS`, the paper's) and ``hybrid`` (:class:`Hybrid`),
sampling to choose the basin and L-BFGS to polish in it. A local planner warm-started from its
previous plan stays in that plan's basin: a stall (a grasp from which the model predicts no
turn) or a plan heading for a fall is improved only where the gradient points. The closed-form
model evaluates many plans in one batched call, so the hybrid plans in three stages:

1. **Sampling** (cross-entropy method, seeded): ``samples`` plans around the warm start, spread
   ``spread`` × the box's half-width; the ``elites`` lowest-cost refit the mean and spread,
   ``rounds`` times. The first round's samples include the warm start and zero (no motion).
2. **Multi-start L-BFGS**: box-projected L-BFGS from the warm start and from the ``starts − 1``
   best other samples, all in one batched solve (rows independent).
3. The plan of lowest model cost is returned. Since the warm start's row is plain L-BFGS from
   the warm start, the result never costs more than plain L-BFGS's (up to rounding).

The objective must accept any number of rows with its arguments shared by all of them, as the
MPC's does; each problem of a batch ``x0 (B, n)`` is planned on its own.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import torch

from torchcontact.mpc.optim import lbfgs_box
from torchcontact.validation import register


@dataclass(frozen=True)
class Objective:
    """A batched objective with its gradient.

    Attributes:
        value_and_grad: ``(x (N, n), *args) -> (f (N,), grad (N, n))``, rows independent.
        traceable: the same function in a form ``torch.compile`` may trace into a planner's
            own compiled graph (no graph breaks, the same function object from call to call),
            or None where there is none.
        value: ``(x (N, n), *args) -> f (N,)`` alone, for planners that need no gradient
            (sampling), or None: :meth:`values` then drops the gradient of ``value_and_grad``.
        prepare: ``(*planner_args) -> args``: the arguments the functions above take after
            ``x``, worked out once per plan from those the planner was given (the MPC's
            contact-model freeze), or None: the planner's arguments themselves. Where
            ``traceable`` is set, it is traceable too, and a compiled planner traces it into
            its first call.
    """

    value_and_grad: Callable[..., tuple[torch.Tensor, torch.Tensor]]
    traceable: Callable[..., tuple[torch.Tensor, torch.Tensor]] | None = None
    value: Callable[..., torch.Tensor] | None = None
    prepare: Callable[..., tuple] | None = None

    def prepared(self, args: tuple) -> tuple[Objective, tuple]:
        """The objective without :attr:`prepare` and the arguments it takes, ``prepare``
        applied to ``args`` eagerly (for planners that call the objective themselves)."""
        if self.prepare is None:
            return self, args
        return dataclasses.replace(self, prepare=None), tuple(self.prepare(*args))

    def values(self, x: torch.Tensor, *args) -> torch.Tensor:
        """``f (N,)`` at ``x (N, n)``, without computing a gradient where :attr:`value` is set."""
        if self.value is not None:
            return self.value(x, *args)
        return self.value_and_grad(x, *args)[0]


class PlannerResult(NamedTuple):
    """What a planner found: ``x (B, n)``, ``f (B,)``, rounds and objective evaluations."""

    x: torch.Tensor
    f: torch.Tensor
    iterations: int
    evaluations: int


class Planner(Protocol):
    """The planner interface; see the module docstring. A planner that applies an
    objective's :attr:`Objective.prepare` says so with a class attribute
    ``applies_prepare = True``; others are given objectives without one."""

    def plan(
        self,
        objective: Objective,
        x0: torch.Tensor,
        box: tuple[torch.Tensor, torch.Tensor],
        args: tuple = (),
    ) -> PlannerResult:
        """Minimize ``objective`` from ``x0 (B, n)`` within ``box = (lower, upper)``, each
        broadcastable to ``(B, n)``; ``args`` go to the objective after ``x``."""
        ...


class LBFGS:
    """Box-projected L-BFGS (:func:`~torchcontact.mpc.optim.lbfgs_box`), the paper's planner.

    Args:
        max_iter: line-search rounds at most; memory: (s, y) pairs kept.
        compile: ``torch.compile`` the rounds, with a traceable objective traced into them.
    """

    applies_prepare = True

    def __init__(self, max_iter: int = 30, memory: int = 8, compile: bool = False):
        self.max_iter, self.memory, self.compile = max_iter, memory, compile

    def eager(self) -> LBFGS:
        """The same planner, not compiled: the same iterates up to rounding."""
        return LBFGS(self.max_iter, self.memory, compile=False)

    def plan(self, objective: Objective, x0, box, args: tuple = ()) -> PlannerResult:
        lower, upper = box
        traced = self.compile and objective.traceable is not None
        result = lbfgs_box(
            objective.traceable if traced else objective.value_and_grad,
            x0,
            lower,
            upper,
            memory=self.memory,
            max_iter=self.max_iter,
            compile_steps=self.compile,
            args=args,
            compile_fun=traced,
            prepare=objective.prepare,
        )
        # the most rounds any problem ran; the points evaluated over all problems
        return PlannerResult(
            result.x, result.f, int(result.n_iter.max()), int(result.n_evals.sum())
        )


# --- hybrid: sampling to choose the basin, L-BFGS to polish in it ---------------------------


class Hybrid:
    """Cross-entropy sampling seeding a batched multi-start L-BFGS (see the module docstring).

    Args:
        max_iter, memory, compile: of the L-BFGS stage (:class:`LBFGS`).
        samples: plans per sampling round (≥ 2); rounds: sampling rounds (0: no sampling, the
            starts are the warm start and zero); elites: samples that refit the
            distribution (1 ≤ elites ≤ samples); starts: L-BFGS starts (≥ 1: the warm start,
            then the best other samples; without sampling, zero); spread: the first round's
            standard deviation as a fraction of the box's half-width (> 0); seed: of the
            sampling, the same every call, so a plan depends only on its inputs.
    """

    applies_prepare = True

    def __init__(
        self,
        max_iter: int = 30,
        memory: int = 8,
        compile: bool = False,
        samples: int = 32,
        rounds: int = 2,
        elites: int = 4,
        starts: int = 2,
        spread: float = 0.5,
        seed: int = 0,
    ):
        for name, value, least in (("samples", samples, 2), ("rounds", rounds, 0)):
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ValueError(f"{name} must be an integer ≥ {least}, got {value!r}")
        if isinstance(elites, bool) or not isinstance(elites, int) or not 1 <= elites <= samples:
            raise ValueError(f"elites must be an integer in [1, samples={samples}], got {elites!r}")
        if isinstance(starts, bool) or not isinstance(starts, int) or starts < 1:
            raise ValueError(f"starts must be a positive integer, got {starts!r}")
        if not spread > 0:
            raise ValueError(f"spread must be positive, got {spread!r}")
        self.max_iter, self.memory, self.compile = max_iter, memory, compile
        self.samples, self.rounds, self.elites = samples, rounds, elites
        self.starts, self.spread, self.seed = starts, float(spread), int(seed)
        self.polish = LBFGS(max_iter, memory, compile)

    def eager(self) -> Hybrid:
        """The same planner, not compiled."""
        return Hybrid(
            self.max_iter, self.memory, False, self.samples, self.rounds, self.elites,
            self.starts, self.spread, self.seed,
        )  # fmt: skip

    def plan(self, objective: Objective, x0, box, args: tuple = ()) -> PlannerResult:
        objective, args = objective.prepared(args)
        lower, upper = (bound.expand_as(x0) for bound in box)
        x0 = torch.clamp(x0, lower, upper)
        problems, n = x0.shape
        if self.rounds:
            best, evaluations = self._sample(objective, x0, lower, upper, args)
            others = best.transpose(0, 1).reshape(-1, n)  # (S·B, n) start-major
        else:
            others, evaluations = torch.clamp(torch.zeros_like(x0), lower, upper), 0
        starts = torch.cat([x0, others])[: self.starts * problems]  # row s·B + b: start s of b
        count = starts.shape[0] // problems
        bounds = (lower.repeat(count, 1), upper.repeat(count, 1))
        result = self.polish.plan(objective, starts, bounds, args)
        f = result.f.view(count, problems)
        choice = f.argmin(0)
        index = torch.arange(problems, device=x0.device)
        x = result.x.view(count, problems, n)[choice, index]
        total = evaluations + result.evaluations
        return PlannerResult(x, f[choice, index], result.iterations, total)

    def _sample(self, objective: Objective, x0, lower, upper, args):
        """The ``starts − 1`` lowest-cost plans ``(B, starts − 1, n)`` of the sampling rounds
        (the warm start left out: it is a start already), and the number of objective
        evaluations. The first round's samples include the warm start and zero."""
        problems, n = x0.shape
        generator = torch.Generator(device=x0.device).manual_seed(self.seed)
        mean, std = x0, self.spread * (upper - lower) / 2
        kept_x = x0.new_empty(problems, 0, n)
        kept_f = x0.new_empty(problems, 0)
        for step in range(self.rounds):
            # one draw shared by the problems: each is planned as it would be alone
            noise = torch.randn(
                (1, self.samples, n), generator=generator, dtype=x0.dtype, device=x0.device
            )
            x = torch.clamp(mean[:, None] + std[:, None] * noise, lower[:, None], upper[:, None])
            if step == 0:  # the warm start and zero (no motion) compete with the samples
                x[:, 0], x[:, 1] = x0, torch.clamp(torch.zeros_like(x0), lower, upper)
            f = objective.values(x.reshape(-1, n), *args).view(problems, self.samples)
            order = f.argsort(dim=1)[:, : self.elites]
            elites = torch.gather(x, 1, order[..., None].expand(-1, -1, n))
            mean, std = elites.mean(1), elites.std(1, unbiased=False)
            kept_x, kept_f = torch.cat([kept_x, x], 1), torch.cat([kept_f, f], 1)
        kept_f[:, 0] = torch.inf  # the warm start: a start already
        best = kept_f.argsort(dim=1)[:, : self.starts - 1]
        chosen = torch.gather(kept_x, 1, best[..., None].expand(-1, -1, n))
        return chosen, self.rounds * self.samples * problems


PLANNERS: dict[str, Callable[..., Planner]] = {"lbfgs": LBFGS, "hybrid": Hybrid}
"""Planner factories by name; each takes ``max_iter``, ``memory`` and ``compile``."""


def register_planner(name: str, factory: Callable[..., Planner]) -> None:
    """Make ``planner(name, **kw)`` call ``factory(**kw)``; ``name`` must be new."""
    register(PLANNERS, name, factory, "planner")


def planner(name: str, **options) -> Planner:
    """The planner registered as ``name`` (one of :data:`PLANNERS`), built with ``options``."""
    if name not in PLANNERS:
        raise ValueError(f"planner must be one of {sorted(PLANNERS)}, got {name!r}")
    return PLANNERS[name](**options)
