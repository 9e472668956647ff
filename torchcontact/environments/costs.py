"""The paper's MPC cost terms, batched over any leading dimensions.

Poses are an object position ``p (..., 3)`` [m] and quaternion ``quat (..., 4)`` (w, x, y, z);
fingertips are world positions ``tips (..., n_tips, 3)`` [m], from forward kinematics.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import torch

from torchcontact.rotations import (
    quaternion_error,
    quaternion_to_matrix,
    up_axis,
)
from torchcontact.validation import register


def position_cost(p: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``‖p − p*‖²`` [m²], shape ``(...)``."""
    return (p - target).square().sum(-1)


def contact_cost(p: torch.Tensor, tips: torch.Tensor) -> torch.Tensor:
    """``Σᵢ ‖p − tipᵢ‖²`` [m²]: pulls every fingertip toward the object."""
    return (tips - p.unsqueeze(-2)).square().sum((-1, -2))


def raised(p: torch.Tensor, floor: float) -> torch.Tensor:
    """Positions ``p (..., 3)`` [m] with their height raised to at least ``floor`` [m]."""
    return torch.cat([p[..., :2], p[..., 2:].clamp_min(floor)], -1)


def grasp_cost(p: torch.Tensor, quat: torch.Tensor, tips: torch.Tensor) -> torch.Tensor:
    """``‖Σᵢ Rᵀ(tipᵢ − p)/‖tipᵢ − p‖‖²``: zero when the tip directions balance (force closure)."""
    offsets = tips - p.unsqueeze(-2)
    directions = offsets / offsets.square().sum(-1, keepdim=True).clamp_min(1e-12).sqrt()
    in_object_frame = directions @ quaternion_to_matrix(quat)  # rows dᵢᵀR = (Rᵀdᵢ)ᵀ
    return in_object_frame.sum(-2).square().sum(-1)


def tilt_cost(quat: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``1 − ⟨R(q)ẑ, R(q*)ẑ⟩`` in [0, 2], shape ``(...)``: how far the body's z axis leans away
    from the target's, blind to turns about it (0 at any yaw of an upright target)."""
    return 1.0 - (up_axis(quat) * up_axis(target)).sum(-1)


def height_bound_cost(tips: torch.Tensor, low: float, high: float) -> torch.Tensor:
    """``Σᵢ (max(0, low − zᵢ)² + max(0, zᵢ − high)²)`` [m²] of tip heights outside
    ``[low, high]``, shape ``(...)`` for ``tips (..., n_tips, 3)``."""
    z = tips[..., 2]
    return ((low - z).clamp_min(0).square() + (z - high).clamp_min(0).square()).sum(-1)


HOLDING_DISTANCE = 0.005
"""[m] A contact of the object with a moving body (a fingertip) this close holds it, for
:meth:`HoldFirst.observe`: the hands' detection margin."""


def holding_contacts(contacts, term: str) -> int:
    """How many of ``contacts`` (unbatched, with ``static`` marked, as a
    :class:`~torchcontact.sim.detect.ContactDetector` gives them) are with a moving body (a
    fingertip) and within :data:`HOLDING_DISTANCE`; ``term`` names the cost term asking."""
    if contacts.static is None:
        raise ValueError(f"contacts.static is None: {term} needs it marked")
    holding = contacts.active & ~contacts.static & (contacts.phi <= HOLDING_DISTANCE)
    return int(holding.sum())


class HoldFirst:
    """Keep a lone object where it stands until fingers hold it (ours).

    A push by one fingertip tips over an object whose base is narrow for its height before
    it slides it, and the quasi-static model, which carries no momentum, predicts a fraction
    of that tilt, so a plan pulled toward the target pushes with the first tip to arrive.
    While fewer than ``grip`` contacts with moving bodies lie within
    :data:`HOLDING_DISTANCE` of the object (:meth:`observe`, at the start of each plan), the
    cost's terms toward the target (the final pose, the tilt) aim at the object's pose at the
    plan's start instead, so the tips close on it first and move it held between them.

    ``approach`` (ours; 1: off) multiplies the cost's contact term while the object is not
    held. Aimed at where it stands, the object asks nothing of the tips, so only that term
    draws them in, and at the paper's weight it moves them a few milliradians a step: a
    larger weight closes the grip sooner, and the weight returns to 1 once it holds.

    ``applies`` (False: an object that slides before it tips, which a lone push moves safely)
    switches the hold off: the target terms then aim at the target throughout, as without it.

    ``held`` and ``applies`` (0-d tensors, 1 or 0) are inputs of a compiled plan, and the repr
    names the settings only, so one graph serves every object.
    """

    def __init__(self, grip: int = 2, approach: float = 1.0, applies: bool = True):
        if isinstance(grip, bool) or not isinstance(grip, int) or grip < 1:
            raise ValueError(f"grip must be a whole number of contacts >= 1, got {grip!r}")
        if not (math.isfinite(approach) and approach > 0):
            raise ValueError(f"approach must be a positive finite weight, got {approach!r}")
        if not isinstance(applies, bool):
            raise ValueError(f"applies must be True or False, got {applies!r}")
        self.grip, self.approach = grip, float(approach)
        self.held = torch.zeros((), dtype=torch.float64)
        self.applies = torch.tensor(float(applies), dtype=torch.float64)

    def observe(self, contacts) -> None:
        """Set :attr:`held` from ``contacts``: 1 when at least :attr:`grip` contacts with
        moving bodies lie within :data:`HOLDING_DISTANCE`, else 0."""
        self.held.fill_(float(holding_contacts(contacts, "the hold-first term") >= self.grip))

    def contact_weight(self, like: torch.Tensor) -> torch.Tensor:
        """The contact term's multiplier (0-d, ``like``'s dtype and device): :attr:`approach`
        while the object is not held (where the hold applies), 1 once it is."""
        return 1 + (self.approach - 1) * (1 - self.held.to(like)) * self.applies.to(like)

    def aims(
        self,
        positions: torch.Tensor,
        quats: torch.Tensor,
        target_position: torch.Tensor,
        target_quat: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The pose ``(..., 3), (..., 4)`` the plan aims at: the target when held (or where
        the hold does not apply), else the start ``positions[..., 0, :]``, ``quats[..., 0, :]``
        of the rollout."""
        go = 1 - self.applies.to(positions) * (1 - self.held.to(positions))
        position = go * target_position + (1 - go) * positions[..., 0, :]
        return position, go * target_quat + (1 - go) * quats[..., 0, :]

    def __repr__(self) -> str:
        return f"HoldFirst(grip={self.grip!r}, distance={HOLDING_DISTANCE!r}" + (
            f", approach={self.approach!r})" if self.approach != 1 else ")"
        )


@dataclass(frozen=True)
class ManipulationCost:
    """Σₜ c(qₜ, uₜ) + V(q_T) with the paper's weights.

    c = contact·Σ‖p − tip‖² + grasp·‖Σ Rᵀd̂ᵢ‖² + control·‖u‖² (+ tilt·(1 − ⟨R(q)ẑ, R(q*)ẑ⟩));
    V = final·(position·‖p − p*‖² + orientation·(1 − ⟨q, q*⟩²)).

    ``tilt`` (ours, default off) charges every planned state q₁…q_T for leaning its z axis away
    from the target's: the MPC then avoids pushes that its model predicts tip the object over,
    while turning it about that axis stays free.
    ``tilt_applies`` (a 0-d tensor, 1 or 0; None: 1) switches it per object, an input of a
    compiled plan rather than a setting, so one graph serves objects with and without it.

    ``tip_height = (low, high)`` [m] bounds the fingertips' planned heights q₁…q_T, as the
    paper's fingertip MPC does with hard state bounds (z ≥ 0, and z ≤ 0.1 m for the foam brick
    and stick): here a quadratic penalty of weight ``tip_height_weight`` [1/m²] on the excess,
    since the L-BFGS box holds the controls only. The model has no tip–ground contact, so
    without it a plan may push a tip through the floor to lift the object from below.

    ``contact_floor`` [m] is the lowest height of the point the contact and grasp terms draw
    the tips toward and around: the object's centre raised to it. At the height of a tip's
    centre resting on the support, a plate thinner than the tips' diameter draws them to its
    rim, where they push it sideways, instead of pressing them into the support, whose
    friction then holds them (the model has no tip–support contact to tell it so). None: the
    object's centre, the paper's.

    ``hold`` (:class:`HoldFirst`) aims every target term at the object's pose at the plan's
    start until enough fingers hold it, and meanwhile weighs the contact term by its
    :attr:`~HoldFirst.approach`. None: at the target throughout, the paper's.

    """

    contact: float = 1.0
    grasp: float = 0.05
    control: float = 50.0
    position: float = 500.0
    orientation: float = 5.0
    final: float = 10.0
    tip_height: tuple[float, float] | None = None
    tip_height_weight: float = 1e5
    tilt: float = 0.0
    tilt_applies: torch.Tensor | None = field(default=None, repr=False, compare=False)
    contact_floor: float | None = None
    hold: HoldFirst | None = None

    @property
    def tilt_weight(self) -> float:
        """The tilt term's weight on this object: :attr:`tilt`, or 0 where
        :attr:`tilt_applies` switches it off."""
        gate = 1.0 if self.tilt_applies is None else float(self.tilt_applies)
        return self.tilt * gate

    def __call__(
        self,
        positions: torch.Tensor,
        quats: torch.Tensor,
        tips: torch.Tensor,
        controls: torch.Tensor,
        target_position: torch.Tensor,
        target_quat: torch.Tensor,
    ) -> torch.Tensor:
        """Total cost ``(...)`` of a rollout.

        Args:
            positions: ``(..., T+1, 3)`` object positions p₀…p_T.
            quats: ``(..., T+1, 4)`` object quaternions.
            tips: ``(..., T+1, n_tips, 3)`` fingertip positions.
            controls: ``(..., T, n_u)`` controls u₀…u_{T−1}.
            target_position: ``(..., 3)``; target_quat: ``(..., 4)``.
        """
        if self.hold is not None:
            target_position, target_quat = self.hold.aims(
                positions, quats, target_position, target_quat
            )
        p, quat, tip = positions[..., :-1, :], quats[..., :-1, :], tips[..., :-1, :, :]
        anchor = p if self.contact_floor is None else raised(p, self.contact_floor)
        pull = contact_cost(anchor, tip)
        if self.hold is not None and self.hold.approach != 1:
            pull = pull * self.hold.contact_weight(pull)
        path = (
            self.contact * pull
            + self.grasp * grasp_cost(anchor, quat, tip)
            + self.control * controls.square().sum(-1)
        ).sum(-1)
        if self.tilt:
            target = target_quat.unsqueeze(-2)
            weight = (
                self.tilt if self.tilt_applies is None else self.tilt * self.tilt_applies.to(path)
            )
            path = path + weight * tilt_cost(quats[..., 1:, :], target).sum(-1)
        final = self.position * position_cost(
            positions[..., -1, :], target_position
        ) + self.orientation * quaternion_error(quats[..., -1, :], target_quat)
        total = path + self.final * final
        if self.tip_height is not None:
            bound = height_bound_cost(tips[..., 1:, :, :], *self.tip_height).sum(-1)
            total = total + self.tip_height_weight * bound
        return total

    def observe(self, contacts) -> None:
        """Take in the contacts at the start of a plan (the MPC calls it before each solve):
        whether the object is held (:meth:`HoldFirst.observe`)."""
        if self.hold is not None:
            self.hold.observe(contacts)


class Cost(Protocol):
    """The MPC cost protocol: any callable with this signature plugs in (by duck typing).

    Called with ``positions (..., T+1, 3)`` [m] and ``quats (..., T+1, 4)`` of the object over
    a planned rollout (q₀…q_T), ``tips (..., T+1, n_tips, 3)`` [m], ``controls (..., T, n_u)``
    and the target ``target_position (..., 3)`` [m], ``target_quat (..., 4)``; returns the
    total cost ``(...)``, rows independent. It must be differentiable (``torch.func.grad``)
    and, to be compiled into the planner, free of host syncs and data-dependent branches.
    A cost may also have an ``observe(contacts)`` method, which the MPC calls with the
    contacts at the start of each plan, outside the compiled graph
    (:meth:`ManipulationCost.observe`).
    """

    def __call__(
        self,
        positions: torch.Tensor,
        quats: torch.Tensor,
        tips: torch.Tensor,
        controls: torch.Tensor,
        target_position: torch.Tensor,
        target_quat: torch.Tensor,
    ) -> torch.Tensor: ...


@dataclass(frozen=True)
class PushingCost:
    """A pusher's cost: the nearest tip behind the object on the line to the goal, then the goal.

    c = contact·minᵢ‖tipᵢ − (p − standoff·d̂)‖² + control·‖u‖², with d̂ the unit horizontal
    direction from the object to its target; V = final·(position·‖p − p*‖² +
    orientation·(1 − ⟨q, q*⟩²)). Unlike :class:`ManipulationCost`, whose tips are all pulled to
    the object's centre (a grasp), one tip is pulled to where it pushes the object goalward and
    the others are free to keep out of its way.

    Attributes:
        standoff: distance [m] behind the object's centre the nearest tip aims at. At 0 it
            aims at the centre, through the object, so the model predicts a push; a standoff
            of about the object's half-width brings a tip round to the far side first.
    """

    standoff: float = 0.0
    contact: float = 1.0
    control: float = 10.0
    position: float = 500.0
    orientation: float = 0.0
    final: float = 10.0

    def __call__(self, positions, quats, tips, controls, target_position, target_quat):
        p = positions[..., :-1, :]
        ahead = (target_position.unsqueeze(-2) - p) * p.new_tensor([1.0, 1.0, 0.0])
        direction = ahead / ahead.square().sum(-1, keepdim=True).clamp_min(1e-12).sqrt()
        behind = p - self.standoff * direction
        nearest = (tips[..., :-1, :, :] - behind.unsqueeze(-2)).square().sum(-1).amin(-1)
        path = (self.contact * nearest + self.control * controls.square().sum(-1)).sum(-1)
        final = self.position * position_cost(positions[..., -1, :], target_position)
        if self.orientation:
            final = final + self.orientation * quaternion_error(quats[..., -1, :], target_quat)
        return path + self.final * final


COSTS: dict[str, Callable[..., Cost]] = {
    "manipulation": ManipulationCost,
    "pushing": PushingCost,
}
"""Costs by name: grasp-style manipulation (the paper's) and pushing; keyword arguments are
their weights."""


def register_cost(name: str, factory: Callable[..., Cost]) -> None:
    """Make ``cost(name, **weights)`` (and ``torchcontact run --cost NAME``, from a module
    ``--import`` names) call ``factory(**weights)``, which returns a callable
    ``cost(positions, quats, tips, controls, target_position, target_quat)`` (:class:`Cost`);
    ``name`` must be new."""
    register(COSTS, name, factory, "cost")


def cost(name: str, **weights) -> Cost:
    """The cost registered as ``name`` (one of :data:`COSTS`) with ``weights``."""
    if name not in COSTS:
        raise ValueError(f"cost must be one of {sorted(COSTS)}, got {name!r}")
    return COSTS[name](**weights)
