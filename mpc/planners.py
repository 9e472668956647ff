"""Planners by name: each turns a batched objective and a box into a plan.

A planner minimizes B independent problems ``f_b(x_b)`` over ``lower ≤ x ≤ upper`` from a start
``x0 (B, n)``. The MPC composes a contact model, a cost and a planner; a new planner is one
class with a :meth:`Planner.plan` method and one :func:`register_planner` call::

    planner("lbfgs", max_iter=15, memory=8, compile=True).plan(objective, x0, (lower, upper))
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


PLANNERS: dict[str, Callable[..., Planner]] = {"lbfgs": LBFGS}
"""Planner factories by name; each takes ``max_iter``, ``memory`` and ``compile``."""


def register_planner(name: str, factory: Callable[..., Planner]) -> None:
    """Make ``planner(name, **kw)`` call ``factory(**kw)``; ``name`` must be new."""
    register(PLANNERS, name, factory, "planner")


def planner(name: str, **options) -> Planner:
    """The planner registered as ``name`` (one of :data:`PLANNERS`), built with ``options``."""
    if name not in PLANNERS:
        raise ValueError(f"planner must be one of {sorted(PLANNERS)}, got {name!r}")
    return PLANNERS[name](**options)
