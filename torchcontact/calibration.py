"""Learnable corrections of the quasi-dynamic system, fitted jointly with K(q) and D(q).

The quasi-dynamic robot moves by exactly its command ``u`` without contact; a real position
servo covers only part of it in one step (the plants' joints move 1.23× on the TriFinger, 0.56×
on the fingertips and 0.27× on the Allegro) and no stiffness K corrects that. A
:class:`SystemCalibration` holds four positive factors, each ``exp(θ)`` with ``θ = 0`` the
uncorrected system:

- ``command_gain (n_r,)``: the robot moves by ``gain ⊙ u`` (a first-order lag of the command);
- ``robot_stiffness (n_r,)``: scales Kᵣ, how far contact forces push the robot off its command;
- ``object_metric ()``: scales the object metric εMₒ/h² (how readily the object moves);
- ``friction ()``: scales every contact's μ;
- ``object_momentum ()``, optional (:data:`OPTIONAL`): the weight m of the object's previous
  step's motion in the next, which carries m/(1 + m) of it
  (:func:`~torchcontact.systems.carry_momentum`); the quasi-dynamic step has none, so the
  factor exists only when learned, starting at m = 0.5.

A :class:`~torchcontact.model.ComplementarityFree` model holding one applies the friction
factor to its contacts itself; the MPC and the rollouts plan with :meth:`apply`'s system.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from torchcontact.contacts import Contacts
from torchcontact.systems import QuasiDynamic

PARTS = ("command_gain", "robot_stiffness", "object_metric", "friction")
"""The factors every calibration holds (``learn-k --calibrate``)."""

MOMENTUM = "object_momentum"
OPTIONAL = (MOMENTUM,)
"""Factors a calibration holds only when it learns them (no value of theirs is the
uncorrected system)."""

INITIAL_MOMENTUM = 0.5


class SystemCalibration(nn.Module):
    """Positive factors correcting a quasi-dynamic system (see the module docstring).

    Args:
        n_robot: the robot's DoF count (the size of ``command_gain`` and ``robot_stiffness``).
        learn: the factors that are learnable (a subset of :data:`PARTS` and
            :data:`OPTIONAL`); the other parts stay 1. All four parts live in ``state_dict``
            either way, the optional ones when learned, so a checkpoint and its fit's
            ``learn`` rebuild the same module.
    """

    def __init__(self, n_robot: int, learn: Sequence[str] = PARTS):
        super().__init__()
        if isinstance(n_robot, bool) or not isinstance(n_robot, int) or n_robot < 1:
            raise ValueError(f"n_robot must be a positive integer, got {n_robot!r}")
        unknown = [name for name in learn if name not in PARTS + OPTIONAL]
        if unknown:
            raise ValueError(f"learn must name factors of {PARTS + OPTIONAL}, got {list(learn)}")
        sizes = {"command_gain": n_robot, "robot_stiffness": n_robot}
        for name in PARTS:
            log = nn.Parameter(torch.zeros(sizes.get(name, 1)), requires_grad=name in learn)
            self.register_parameter(f"log_{name}", log)
        if MOMENTUM in learn:
            initial = torch.full((1,), math.log(INITIAL_MOMENTUM))
            self.log_object_momentum = nn.Parameter(initial)
        self.n_robot = n_robot

    @property
    def momentum(self) -> torch.Tensor | None:
        """The object's momentum factor m ``(1,)``, or None when the calibration has none."""
        log = getattr(self, f"log_{MOMENTUM}", None)
        return None if log is None else log.exp()

    def factor(self, name: str) -> torch.Tensor:
        """The positive factor ``name`` of :data:`PARTS`: ``(n_r,)`` or ``(1,)``."""
        if name not in PARTS:
            raise ValueError(f"name must be one of {PARTS}, got {name!r}")
        return getattr(self, f"log_{name}").exp()

    @property
    def learned(self) -> tuple[str, ...]:
        """The learnable factors."""
        logs = dict(self.named_parameters())
        names = [n for n in PARTS + OPTIONAL if f"log_{n}" in logs]
        return tuple(n for n in names if logs[f"log_{n}"].requires_grad)

    def terms(
        self, Q: torch.Tensor, b0: torch.Tensor, B: torch.Tensor, u: torch.Tensor, object_rows
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The corrected affine system, differentiable in the factors.

        Args:
            Q: ``(..., nv)`` the uncorrected diagonal metric; b0: ``(..., nv)``; B:
                ``(nv, n_r)``: the uncorrected ``b(u) = b0 + B·u``.
            u: ``(..., n_r)`` commanded displacements [m or rad].
            object_rows: the object's velocity indices in v (a long tensor).

        Returns ``Q' (..., nv)``, ``b' (..., nv)``: the object rows of Q times the metric
        factor, the robot rows times the stiffness factor, and ``b' = b0 + B·(gain ⊙ stiffness
        ⊙ u)`` (so the robot, unopposed, moves ``gain ⊙ u``).
        """
        gain, stiffness = self.factor("command_gain"), self.factor("robot_stiffness")
        scale = torch.ones(Q.shape[-1], dtype=Q.dtype, device=Q.device)
        robot = torch.ones(Q.shape[-1], dtype=torch.bool, device=Q.device)
        robot[object_rows] = False
        scale = scale.masked_scatter(robot, stiffness.to(Q.dtype))
        scale = scale.index_put((object_rows,), self.factor("object_metric").to(Q.dtype))
        b = b0 + ((gain * stiffness).to(u.dtype) * u) @ B.mT
        return Q * scale, b

    def apply(self, system: QuasiDynamic) -> QuasiDynamic:
        """``system`` with the factors applied (their current values, no gradient)."""
        with torch.no_grad():
            metric = system.object_metric * self.factor("object_metric").to(system.object_metric)
            stiffness = system.robot_stiffness * self.factor("robot_stiffness").to(metric)
            gain = self.factor("command_gain").to(metric)
            if system.command_gain is not None:
                gain = gain * system.command_gain
            return QuasiDynamic(
                metric,
                stiffness,
                system.object_force,
                object_dofs=system.object_dofs,
                command_gain=gain,
                object_momentum=None if self.momentum is None else self.momentum.to(metric),
            )

    def contacts(self, contacts: Contacts) -> Contacts:
        """``contacts`` with every μ times the friction factor."""
        mu = contacts.mu * self.factor("friction").to(contacts.mu)
        return Contacts._unchecked({**contacts._fields(), "mu": mu})

    def summary(self) -> dict[str, list[float]]:
        """The factors' values, by name (for manifests and printing)."""
        summary = {name: self.factor(name).detach().cpu().tolist() for name in PARTS}
        if self.momentum is not None:
            summary[MOMENTUM] = self.momentum.detach().cpu().tolist()
        return summary

    def extra_repr(self) -> str:
        return f"n_robot={self.n_robot}, learned={self.learned}"
