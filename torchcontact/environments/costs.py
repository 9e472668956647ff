"""The paper's MPC cost terms, batched over any leading dimensions.

Poses are an object position ``p (..., 3)`` [m] and quaternion ``quat (..., 4)`` (w, x, y, z);
fingertips are world positions ``tips (..., n_tips, 3)`` [m], from forward kinematics.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import torch

from torchcontact.rotations import (
    quaternion_conjugate,
    quaternion_error,
    quaternion_log,
    quaternion_multiply,
    quaternion_to_matrix,
    up_axis,
)


def position_cost(p: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``‖p − p*‖²`` [m²], shape ``(...)``."""
    return (p - target).square().sum(-1)


def contact_cost(p: torch.Tensor, tips: torch.Tensor) -> torch.Tensor:
    """``Σᵢ ‖p − tipᵢ‖²`` [m²]: pulls every fingertip toward the object."""
    return (tips - p.unsqueeze(-2)).square().sum((-1, -2))


def axis_contact_cost(
    p: torch.Tensor, quat: torch.Tensor, tips: torch.Tensor, half_axis: torch.Tensor
) -> torch.Tensor:
    """``Σᵢ ‖aᵢ − tipᵢ‖²`` [m²], ``aᵢ`` the point of the segment ``p ± R(q)·half_axis`` nearest
    tip i: pulls every fingertip toward the object's long axis, not all to its centre, so tips
    near an end of a long object stay there, where a push turns it. ``half_axis (3,)`` [m] is
    in the body frame; zero gives :func:`contact_cost`."""
    axis = (quaternion_to_matrix(quat) @ half_axis).unsqueeze(-2)  # (..., 1, 3)
    offsets = tips - p.unsqueeze(-2)
    length2 = axis.square().sum(-1, keepdim=True).clamp_min(1e-12)
    along = ((offsets * axis).sum(-1, keepdim=True) / length2).clamp(-1.0, 1.0)
    return (offsets - along * axis).square().sum((-1, -2))


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


def support_cost(p: torch.Tensor, region: tuple[float, float, float, float]) -> torch.Tensor:
    """``dist²`` [m²] of positions ``p (..., 3)``'s x, y outside the rectangle ``region =
    (x_min, y_min, x_max, y_max)`` [m], shape ``(...)``; zero inside."""
    xy = p[..., :2]
    lower, upper = xy.new_tensor(region[:2]), xy.new_tensor(region[2:])
    return ((lower - xy).clamp_min(0).square() + (xy - upper).clamp_min(0).square()).sum(-1)


BALANCE_DIRECTIONS = 16
"""Directions, evenly spaced about the vertical, in which :class:`Balance` holds its base."""

HOLDING_DISTANCE = 0.005
"""[m] A contact of the object with a moving body (a fingertip) this close holds it, for
:meth:`Balance.observe`: the hands' detection margin, so a second finger on its way in opens
the way for the first one's push."""


def balance_directions(dtype: torch.dtype = torch.float64, device=None) -> torch.Tensor:
    """``(BALANCE_DIRECTIONS, 2)`` unit vectors in the body's x, y plane, the first along x."""
    angles = torch.arange(BALANCE_DIRECTIONS, dtype=dtype, device=device)
    angles = angles * (2 * math.pi / BALANCE_DIRECTIONS)
    return torch.stack([angles.cos(), angles.sin()], -1)


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

    With a ``lean_limit`` [rad] (ours, off by default, measured in docs/experiments.md), a held
    object whose up axis leans further than it from the target's is aimed at where it stands,
    turned upright (:func:`righted`), until it leans less.

    ``approach`` (ours; 1: off) multiplies the cost's contact term while the object is not
    held. Aimed at where it stands, the object asks nothing of the tips, so only that term
    draws them in, and at the paper's weight it moves them a few milliradians a step: a
    larger weight closes the grip sooner, and the weight returns to 1 once it holds.

    ``held`` (a 0-d tensor, 1 or 0) and the limit's cosine ``lean_cos`` are inputs of a
    compiled plan, and the repr names the settings only, so one graph serves every object.
    """

    def __init__(self, grip: int = 2, lean_limit: float | None = None, approach: float = 1.0):
        if isinstance(grip, bool) or not isinstance(grip, int) or grip < 1:
            raise ValueError(f"grip must be a whole number of contacts >= 1, got {grip!r}")
        if lean_limit is not None and not (0 < lean_limit <= math.pi):
            raise ValueError(f"lean_limit must be in (0, pi] rad or None, got {lean_limit!r}")
        if not (math.isfinite(approach) and approach > 0):
            raise ValueError(f"approach must be a positive finite weight, got {approach!r}")
        self.grip, self.lean_limit, self.approach = grip, lean_limit, float(approach)
        self.held = torch.zeros((), dtype=torch.float64)
        self.lean_cos = torch.tensor(math.cos(lean_limit or math.pi), dtype=torch.float64)

    @property
    def upright(self) -> bool:
        """Whether a held object is righted past :attr:`lean_limit`."""
        return self.lean_limit is not None

    def observe(self, contacts) -> None:
        """Set :attr:`held` from ``contacts``: 1 when at least :attr:`grip` contacts with
        moving bodies lie within :data:`HOLDING_DISTANCE`, else 0."""
        self.held.fill_(float(holding_contacts(contacts, "the hold-first term") >= self.grip))

    def contact_weight(self, like: torch.Tensor) -> torch.Tensor:
        """The contact term's multiplier (0-d, ``like``'s dtype and device): :attr:`approach`
        while the object is not held, 1 once it is."""
        return 1 + (self.approach - 1) * (1 - self.held.to(like))

    def aims(
        self,
        positions: torch.Tensor,
        quats: torch.Tensor,
        target_position: torch.Tensor,
        target_quat: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The pose ``(..., 3), (..., 4)`` the plan aims at: the target when held (and, with a
        :attr:`lean_limit`, leaning less than it from the target's up axis), else the start
        ``positions[..., 0, :]`` of the rollout, in the start's orientation ``quats[..., 0,
        :]``, or with a lean limit that orientation turned upright (:func:`righted`)."""
        start = quats[..., 0, :]
        go = self.held.to(positions)
        stay = start
        if self.upright:
            lean_cos = (up_axis(start) * up_axis(target_quat)).sum(-1, keepdim=True)
            go = go * (lean_cos >= self.lean_cos.to(positions)).to(positions)
            stay = righted(start, target_quat)
        position = go * target_position + (1 - go) * positions[..., 0, :]
        return position, go * target_quat + (1 - go) * stay

    def __repr__(self) -> str:
        return (
            f"HoldFirst(grip={self.grip!r}, distance={HOLDING_DISTANCE!r}, "
            f"upright={self.upright!r}"
            + (f", approach={self.approach!r})" if self.approach != 1 else ")")
        )


def righted(quat: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``quat (..., 4)`` turned by the least rotation that brings its z axis onto
    ``target (..., 4)``'s: its lean taken out, its turn about that axis kept. The half-way
    quaternion ``(1 + u·u*, u × u*)``, normalized, is that rotation; upside down (u = −u*)
    it has no axis, and the quaternion stays as it is."""
    u, goal = torch.broadcast_tensors(up_axis(quat), up_axis(target))
    half = torch.cat([1 + (u * goal).sum(-1, keepdim=True), torch.linalg.cross(u, goal)], -1)
    norm = half.square().sum(-1, keepdim=True).sqrt()
    identity = half.new_tensor([1.0, 0.0, 0.0, 0.0]).expand_as(half)
    half = torch.where(norm > 1e-9, half / norm.clamp_min(1e-9), identity)
    return quaternion_multiply(half, quat.expand_as(half))


class Balance:
    """What :func:`balance_cost` needs to know of an object standing on a flat support (ours).

    The per-object values are tensors of one shape for every object, so a compiled plan traces
    them as inputs and one graph serves all objects; the repr names the settings only, for the
    same reason (it keys the compiled graphs).

    The term applies while the object stands alone: :meth:`observe` sets ``alone`` (a 0-d
    tensor, 1 or 0) from the contacts at the start of each plan. Two or more fingers within
    :data:`HOLDING_DISTANCE` of it hold it as well as the support does, which the centre of
    pressure on the support alone does not tell: a grasp may carry an object tilted past its
    base's edge.

    Args:
        reaches: ``(BALANCE_DIRECTIONS,)`` [m], how far the base reaches from the centre of
            mass, seen from above, along each of :func:`balance_directions` in the body frame
            (the base's support function): all positive when the centre stands over the base.
        height: [m] of the pose point above the base.
        friction: μ between the object and its support.
        lever: the model's rotational over translational metric [m²] (0.1/50 in the hands'):
            the moment per radian over the force per metre the model's object answers with.
        weight: the object's weight over the translational metric [m] (the model's free
            fall in one step, g·h²/ε).
        threshold: the fraction of the base's reach the centre of pressure may take before
            the term charges.
    """

    def __init__(self, reaches, height: float, friction: float, lever: float, weight: float,
                 threshold: float = 0.5):  # fmt: skip
        reaches = torch.as_tensor(reaches, dtype=torch.float64)
        if reaches.shape != (BALANCE_DIRECTIONS,) or not bool((reaches > 0).all()):
            raise ValueError(
                f"reaches must be {BALANCE_DIRECTIONS} positive distances [m] (the centre of "
                f"mass over the base), got {reaches.tolist()}"
            )
        for name, value in (("height", height), ("friction", friction), ("lever", lever),
                            ("weight", weight), ("threshold", threshold)):  # fmt: skip
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        self.reaches = reaches
        self.facts = torch.tensor([height, friction], dtype=torch.float64)
        self.lever, self.weight, self.threshold = float(lever), float(weight), float(threshold)
        self.alone = torch.ones((), dtype=torch.float64)

    def observe(self, contacts) -> None:
        """Set :attr:`alone` from ``contacts`` (unbatched, with ``static`` marked, as a
        :class:`~torchcontact.sim.detect.ContactDetector` gives them): 1 when at most one
        contact with a moving body lies within :data:`HOLDING_DISTANCE`, else 0."""
        self.alone.fill_(float(holding_contacts(contacts, "the balance term") <= 1))

    @staticmethod
    def of_base(points, centre, **values) -> Balance:
        """The balance of a base whose outline passes through ``points (n, 2)`` [m] (body x, y)
        around a centre of mass at ``centre (2,)``; ``values``: the other arguments."""
        offsets = torch.as_tensor(points, dtype=torch.float64) - torch.as_tensor(
            centre, dtype=torch.float64
        )
        reaches = (offsets @ balance_directions().T).amax(0)
        return Balance(reaches, **values)

    def __repr__(self) -> str:
        return (
            f"Balance(directions={BALANCE_DIRECTIONS}, lever={self.lever!r}, "
            f"weight={self.weight!r}, threshold={self.threshold!r})"
        )


def balance_cost(positions: torch.Tensor, quats: torch.Tensor, balance: Balance) -> torch.Tensor:
    """``Σₜ max(0, sₜ − threshold)²`` of a planned rollout, shape ``(...)`` (ours).

    The model's object moves by its metric's answer to the net push of the robot, so each
    planned step ``(pₜ, qₜ) → (pₜ₊₁, qₜ₊₁)`` tells the force F and the moment τ (about the pose
    point) the plan puts on the object. The support must answer them: its centre of pressure
    lies at ``(τ⊥ + z·F_h)/N`` from the centre of mass (z the pose point's height, τ⊥ = (τ_y,
    −τ_x)), with ``N`` the weight while the push is held by static friction and ``|F_h|/μ`` once
    it slides. ``sₜ`` is that offset over the base's reach in its direction (the largest
    ratio over the base's directions): at 1 the object starts to tip over the base's edge. A
    push at a height where it tips the object instead of sliding it costs; one low enough,
    or a pair that turns the object without a net push, does not. Zero while the object is
    held (:attr:`Balance.alone`). Positions ``(..., T+1, 3)`` [m] and quaternions
    ``(..., T+1, 4)`` as the cost's.
    """
    step = positions[..., 1:, :] - positions[..., :-1, :]
    previous = quats[..., :-1, :]
    turn = quaternion_log(quaternion_multiply(quats[..., 1:, :], quaternion_conjugate(previous)))
    height, friction = balance.facts.to(positions).unbind()
    force = step[..., :2]  # per unit of translational metric [m]
    moment = balance.lever * torch.stack([turn[..., 1], -turn[..., 0]], -1) + height * force
    sliding = force.square().sum(-1, keepdim=True) / friction.square()
    offset = moment / (balance.weight**2 + sliding).sqrt()  # world x, y [m]
    # into the body frame at the step's start (the object stands near upright)
    rotation = quaternion_to_matrix(previous)[..., :2, :2]
    body = (offset.unsqueeze(-2) @ rotation).squeeze(-2)  # rows dᵀR = (Rᵀd)ᵀ
    directions = balance_directions(positions.dtype, positions.device)
    share = (body @ directions.T) / balance.reaches.to(positions)
    charge = (share.amax(-1) - balance.threshold).clamp_min(0).square().sum(-1)
    return balance.alone.to(positions) * charge


@dataclass(frozen=True)
class ManipulationCost:
    """Σₜ c(qₜ, uₜ) + V(q_T) with the paper's weights.

    c = contact·Σ‖p − tip‖² + grasp·‖Σ Rᵀd̂ᵢ‖² + control·‖u‖² (+ tilt·(1 − ⟨R(q)ẑ, R(q*)ẑ⟩));
    V = final·(position·‖p − p*‖² + orientation·(1 − ⟨q, q*⟩²)).

    ``tilt`` (ours, default off) charges every planned state q₁…q_T for leaning its z axis away
    from the target's: the MPC then avoids pushes that its model predicts tip the object over,
    while turning it about that axis stays free.

    ``tip_height = (low, high)`` [m] bounds the fingertips' planned heights q₁…q_T, as the
    paper's fingertip MPC does with hard state bounds (z ≥ 0, and z ≤ 0.1 m for the foam brick
    and stick): here a quadratic penalty of weight ``tip_height_weight`` [1/m²] on the excess,
    since the L-BFGS box holds the controls only. The model has no tip–ground contact, so
    without it a plan may push a tip through the floor to lift the object from below.

    ``support = (x_min, y_min, x_max, y_max)`` [m] is the region over which the object's
    centre is held up (a palm's footprint shrunk by a margin): planned positions p₁…p_T
    outside it cost ``support_weight`` [1/m²] × their squared distance to it. The frozen
    contact model sees the support as an endless plane, so without it nothing in the plan
    tells an object pushed over the palm's edge from one turned on it.

    ``contact_floor`` [m] is the lowest height of the point the contact and grasp terms draw
    the tips toward and around: the object's centre raised to it. At the height of a tip's
    centre resting on the support, a plate thinner than the tips' diameter draws them to its
    rim, where they push it sideways, instead of pressing them into the support, whose
    friction then holds them (the model has no tip–support contact to tell it so). None: the
    object's centre, the paper's.

    ``hold`` (:class:`HoldFirst`) aims every target term at the object's pose at the plan's
    start until enough fingers hold it, and meanwhile weighs the contact term by its
    :attr:`~HoldFirst.approach`. None: at the target throughout, the paper's.

    ``contact_axis (3,)`` [m], in the body frame, turns the contact term into
    :func:`axis_contact_cost`: each tip is drawn toward its nearest point of the segment
    ``p ± R(q)·contact_axis`` instead of the centre p. None: the centre, the paper's.

    ``stage`` (ours) charges the pose terms of V on the planned states q₁…q_{T−1} as well, at
    ``stage`` times their weight on q_T. With V on q_T alone (0, the paper's), a plan may put
    off its push to its later steps, which are planned again before they run: the first
    step, the one applied, then moves the object little, and a receding horizon can stall
    short of the target on it. ``stage_radius`` [m] confines this to plans that start with
    the object's centre within it of the target's (inf: every plan): far from the target, a
    push charged on every step hurries large moves, and objects tip in them.
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
    support: tuple[float, float, float, float] | None = None
    support_weight: float = 1e5
    contact_floor: float | None = None
    contact_axis: tuple[float, float, float] | None = None
    balance: Balance | None = None
    balance_weight: float = 1.0
    hold: HoldFirst | None = None
    stage: float = 0.0
    stage_radius: float = math.inf

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
        if self.contact_axis is None:
            pull = contact_cost(anchor, tip)
        else:
            pull = axis_contact_cost(anchor, quat, tip, tip.new_tensor(self.contact_axis))
        if self.hold is not None and self.hold.approach != 1:
            pull = pull * self.hold.contact_weight(pull)
        path = (
            self.contact * pull
            + self.grasp * grasp_cost(anchor, quat, tip)
            + self.control * controls.square().sum(-1)
        ).sum(-1)
        if self.tilt:
            target = target_quat.unsqueeze(-2)
            path = path + self.tilt * tilt_cost(quats[..., 1:, :], target).sum(-1)
        final = self.position * position_cost(
            positions[..., -1, :], target_position
        ) + self.orientation * quaternion_error(quats[..., -1, :], target_quat)
        if self.stage:
            position, quat = positions[..., 1:-1, :], quats[..., 1:-1, :]
            early = self.position * position_cost(
                position, target_position.unsqueeze(-2)
            ) + self.orientation * quaternion_error(quat, target_quat.unsqueeze(-2))
            start = (positions[..., 0, :] - target_position).norm(dim=-1)
            near = (start < self.stage_radius).to(early)  # q₀ is given: a gate, not a gradient
            final = final + self.stage * near * early.sum(-1)
        total = path + self.final * final
        if self.tip_height is not None:
            bound = height_bound_cost(tips[..., 1:, :, :], *self.tip_height).sum(-1)
            total = total + self.tip_height_weight * bound
        if self.support is not None:
            outside = support_cost(positions[..., 1:, :], self.support).sum(-1)
            total = total + self.support_weight * outside
        if self.balance is not None:
            total = total + self.balance_weight * balance_cost(positions, quats, self.balance)
        return total

    def observe(self, contacts) -> None:
        """Take in the contacts at the start of a plan (the MPC calls it before each solve):
        whether the balance term applies (:meth:`Balance.observe`) and whether the object is
        held (:meth:`HoldFirst.observe`)."""
        if self.balance is not None:
            self.balance.observe(contacts)
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


def cost(name: str, **weights) -> Cost:
    """The cost registered as ``name`` (one of :data:`COSTS`) with ``weights``."""
    if name not in COSTS:
        raise ValueError(f"cost must be one of {sorted(COSTS)}, got {name!r}")
    return COSTS[name](**weights)
