"""A contact model's step with its contact data frozen: what an MPC rolls out over its horizon.

``model.freeze(contacts, h, q)`` evaluates everything that depends on the real state once (the
dual-cone rows J̃, φ̃ and, for the complementarity-free model, K(q) and D(q)); the frozen step
then maps any number of ``(Q, b)`` to velocities. Frozen steps are named tuples of tensors, so
they pass into ``torch.compile``d functions and ``torch.func`` transforms as ordinary inputs.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from torchcontact.functional import cf_velocity
from torchcontact.relaxed_qp import RelaxedQPSolution, relaxed_qp_solve, relaxed_qp_velocity


class FrozenComplementarityFree(NamedTuple):
    """The complementarity-free step at frozen rows.

    Attributes:
        jac: J̃ ``(m, nv)`` dual-cone rows (zero on padding).
        phi: φ̃ ``(m,)`` [m] row distances.
        stiffness: K ``(m,)``; damping: D ``(m,)`` or None.
        normal: Jⁿ ``(m, nv)``, each row's contact normal row (zero on padding), which
            :meth:`advance_gaps` moves φ̃ along.
        h: the model's time step [s]; gamma: softplus γ (None: exact ``max``).
    """

    jac: torch.Tensor
    phi: torch.Tensor
    stiffness: torch.Tensor
    damping: torch.Tensor | None
    normal: torch.Tensor
    h: float
    gamma: float | None

    traceable = True
    """Its velocity is plain tensor algebra: ``torch.compile`` may trace it into a solver."""

    def linearized(self, Q: torch.Tensor, b: torch.Tensor) -> FrozenComplementarityFree:
        """Itself: the closed form needs no solve before it is differentiated."""
        return self

    def velocity(self, Q: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """Next velocity ``(..., nv)`` for ``Q (..., nv)`` or ``(..., nv, nv)``, ``b (..., nv)``."""
        return cf_velocity(
            Q, b, self.jac, self.phi, self.h, self.stiffness, self.damping, self.gamma
        )

    def advance_gaps(self, v: torch.Tensor) -> FrozenComplementarityFree:
        """The step with φ̃ moved by the velocity ``v (..., nv)`` to first order along the
        frozen normal rows, ``φ̃ + h Jⁿ v`` (J̃, K and D stay frozen)."""
        phi = self.phi + self.h * (self.normal @ v.unsqueeze(-1)).squeeze(-1)
        return self._replace(phi=phi)


class FrozenRelaxedQP(NamedTuple):
    """The relaxed-complementarity QP step at frozen rows.

    Attributes:
        jac: J̃ ``(m, nv)``; phi: φ̃ ``(m,)`` [m]; active: ``(m,)`` bool, the real rows.
        h: the model's time step [s]; relaxation: κ [N·m]; iterations: a fixed
            interior-point iteration count or None (to tolerance).
        compile_steps: ``torch.compile`` each interior-point iteration.
        solution: the interior-point solution :meth:`linearized` attached (None before).
    """

    jac: torch.Tensor
    phi: torch.Tensor
    active: torch.Tensor
    h: float
    relaxation: float
    iterations: int | None
    compile_steps: bool = False
    solution: RelaxedQPSolution | None = None

    traceable = False
    """Its solve is a loop with a convergence test, which a compiled graph cannot hold."""

    def linearized(self, Q: torch.Tensor, b: torch.Tensor) -> FrozenRelaxedQP:
        """The step with the interior-point solution at ``(Q, b)`` attached, solved outside any
        gradient transform; :meth:`velocity` then differentiates one Newton step from it."""
        solution = relaxed_qp_solve(Q, b, *self._problem, compile_steps=self.compile_steps)
        return self._replace(solution=solution)

    def velocity(self, Q: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """Next velocity ``(..., nv)``, from the attached solution when there is one."""
        v, _ = relaxed_qp_velocity(Q, b, *self._problem, solution=self.solution)
        return v

    @property
    def _problem(self) -> tuple:
        """The QP's frozen data in the solver's argument order, after ``Q`` and ``b``."""
        return self.jac, self.phi, self.h, self.active, self.relaxation, self.iterations

    def advance_gaps(self, v: torch.Tensor) -> FrozenRelaxedQP:
        """Not defined for the QP: its MPC plans with frozen gaps (the paper's)."""
        raise ValueError("gaps='propagated' needs the complementarity-free model, not a QP")
