"""The step's metric Q and linear term b: quasi-dynamic and full-dynamic systems."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from torchcontact.validation import (
    check_count,
    check_finite,
    check_number,
    check_positive,
    check_same_kind,
    check_shape,
    check_tensor,
)

GRAVITY = 9.8
"""Standard gravity g [m/s²], the paper's value: an object of mass m [kg] weighs m·g [N]."""


def _vector(name: str, value, size: int | None = None) -> torch.Tensor:
    try:
        x = torch.as_tensor(value)
    except (TypeError, ValueError, RuntimeError) as error:
        raise TypeError(f"{name} must be a number or a tensor, got {value!r}") from error
    if not x.is_floating_point():
        x = x.to(torch.get_default_dtype())
    if x.dim() == 0 and size is not None:
        x = x.expand(size).clone()
    check_shape(
        name,
        x,
        f"({size if size is not None else 'n'},)",
        x.dim() == 1 and (size is None or x.shape[0] == size),
    )
    check_finite(name, x)
    return x


class QuasiDynamic(nn.Module):
    """Quasi-dynamic system: ``Q = blkdiag(εMₒ/h², Kᵣ)``, ``b = (τₒ, Kᵣ(g ⊙ u) + τᵣ)``.

    The robot is a stiff position-controlled spring: without contact it moves by exactly ``u``
    (or ``g ⊙ u`` with a command gain g) in one step; the object is nearly massless (ε small)
    and moves only when pushed.

    Args:
        object_metric: ``(n_o,)`` εMₒ/h², the object's (diagonal) metric [N/m, N·m/rad].
        robot_stiffness: ``(n_r,)`` or a float, the robot's stiffness Kᵣ [N/m or N·m/rad].
        object_force: ``(n_o,)`` τₒ, the object's constant generalized force (gravity) [N, N·m].
        object_dofs: the object's velocity indices in v; default the first n_o. The robot
            takes the remaining indices in order.
        n_robot: the robot's DoF count when ``robot_stiffness`` is a float.
        command_gain: ``(n_r,)`` positive g, the fraction of its command the robot covers in
            one step unopposed (a fitted :class:`~torchcontact.calibration.SystemCalibration`
            sets it); None: 1.
        object_momentum: m ≥ 0, the weight of the object's previous step's motion in the
            next (:func:`carry_momentum`; a fitted calibration sets it); None: none.

    Call: ``system(u, robot_force=None, object_displacement=None)`` with ``u: (..., n_r)``
    the robot's commanded displacement [m or rad], ``robot_force: (..., n_r)`` τᵣ and
    ``object_displacement: (..., n_o)`` the object's over the previous step [m, rad] (used
    with ``object_momentum`` only; None: at rest); returns ``Q: (nv,)`` and ``b: (..., nv)``.
    Raises ``ValueError`` naming ``u`` or ``robot_force`` when it holds NaN
    or Inf.
    """

    def __init__(
        self,
        object_metric,
        robot_stiffness,
        object_force,
        object_dofs: Sequence[int] | None = None,
        n_robot: int | None = None,
        command_gain=None,
        object_momentum=None,
    ):
        super().__init__()
        metric = _vector("object_metric", object_metric)
        check_positive("object_metric", metric)
        n_o = metric.shape[0]
        if n_o == 0:
            raise ValueError("object_metric must have one entry per object coordinate, got none")
        if n_robot is not None:
            check_count("n_robot", n_robot)
        elif torch.as_tensor(robot_stiffness).dim() == 0:
            raise ValueError("n_robot is required when robot_stiffness is a float")
        stiffness = _vector("robot_stiffness", robot_stiffness, n_robot)
        check_positive("robot_stiffness", stiffness)
        n_r = stiffness.shape[0]
        nv = n_o + n_r
        object_dofs = list(range(n_o)) if object_dofs is None else [int(i) for i in object_dofs]
        if (
            len(object_dofs) != n_o
            or len(set(object_dofs)) != n_o
            or not all(0 <= i < nv for i in object_dofs)
        ):
            raise ValueError(
                f"object_dofs must be {n_o} distinct indices in [0, {nv}), got {object_dofs}"
            )
        robot_dofs = [i for i in range(nv) if i not in set(object_dofs)]
        order = torch.tensor(object_dofs + robot_dofs)
        self.register_buffer("object_metric", metric)
        self.register_buffer("robot_stiffness", stiffness)
        # a number is spread over every object coordinate; a vector must match the metric
        force = _vector("object_force", object_force, n_o if np.ndim(object_force) == 0 else None)
        if force.shape[0] != n_o:
            raise ValueError(
                f"object_metric and object_force must have one entry per object coordinate "
                f"each, got {n_o} and {force.shape[0]}"
            )
        self.register_buffer("object_force", force)
        self.register_buffer("_from_blocks", torch.argsort(order), persistent=False)
        # the object's rows in v, kept as a tensor: deriving them per call (argsort, tolist)
        # would break a compiled rollout's graph at every step
        self.register_buffer("_object_rows", torch.tensor(object_dofs), persistent=False)
        if command_gain is not None:
            command_gain = _vector("command_gain", command_gain, n_r)
            check_positive("command_gain", command_gain)
        self.register_buffer("command_gain", command_gain)
        if object_momentum is not None:
            object_momentum = _vector("object_momentum", object_momentum, 1)
            if bool((object_momentum < 0).any()):
                raise ValueError(f"object_momentum must be >= 0, got {object_momentum.tolist()}")
        self.register_buffer("object_momentum", object_momentum)
        self.n_object, self.n_robot = n_o, n_r

    @property
    def nv(self) -> int:
        return self.n_object + self.n_robot

    @property
    def object_dofs(self) -> list[int]:
        """The object's velocity indices in v."""
        return self._object_rows.tolist()

    def metric(self) -> torch.Tensor:
        """``Q: (nv,)`` the diagonal metric."""
        return torch.cat([self.object_metric, self.robot_stiffness])[self._from_blocks]

    def forward(
        self,
        u: torch.Tensor,
        robot_force: torch.Tensor | None = None,
        object_displacement: torch.Tensor | None = None,
    ):
        n_r, n_o = self.n_robot, self.n_object
        check_tensor("u", u)
        check_shape("u", u, f"(..., {n_r})", u.dim() >= 1 and u.shape[-1] == n_r)
        check_same_kind("robot_stiffness", {"robot_stiffness": self.robot_stiffness, "u": u}, False)
        check_finite("u", u)
        for name, x, n in (
            ("robot_force", robot_force, n_r),
            ("object_displacement", object_displacement, n_o),
        ):
            if x is not None:
                check_tensor(name, x)
                check_shape(name, x, f"(..., {n})", x.dim() >= 1 and x.shape[-1] == n)
                check_finite(name, x)
        if self.command_gain is not None:
            u = self.command_gain * u
        robot = self.robot_stiffness * u
        if robot_force is not None:
            robot = robot + robot_force
        obj = self.object_force.to(robot.dtype).expand(*robot.shape[:-1], self.n_object)
        b = torch.cat([obj, robot], dim=-1)[..., self._from_blocks]
        Q = self.metric().to(b.dtype)
        if self.object_momentum is None:
            return Q, b
        return carry_momentum(Q, b, object_displacement, self.object_momentum, self._object_rows)


def carry_momentum(
    Q: torch.Tensor,
    b: torch.Tensor,
    displacement: torch.Tensor | None,
    momentum: torch.Tensor,
    object_rows,
) -> tuple[torch.Tensor, torch.Tensor]:
    """A quasi-dynamic step that carries part of the object's previous motion.

    The object's rows become ``Q'ₒ = (1 + m)Qₒ`` and ``b'ₒ = bₒ + m·Qₒ·Δₒ``, with Δₒ the
    object's displacement over the previous step; so a free object moves by ``(Δ_quasi +
    m·Δₒ)/(1 + m)``: the quasi-static step blended with the previous one, a momentum the
    quasi-static metric εMₒ/h² has no room for (a tipping or falling object keeps moving).
    ``m = 0`` is the quasi-dynamic step.

    Args:
        Q: ``(..., nv)`` the diagonal metric; b: ``(..., nv)``.
        displacement: ``(..., n_o)`` Δₒ = h·vₒ, the object's velocity over the previous step
            times the step [m, rad] in the rows ``object_rows``; None: at rest.
        momentum: m ≥ 0, a float or a ``(1,)`` tensor.
        object_rows: the object's indices in v (a long tensor).

    Returns ``Q' (..., nv)`` and ``b' (..., nv)``.
    """
    rows = torch.as_tensor(object_rows, device=Q.device)
    momentum = torch.as_tensor(momentum, dtype=Q.dtype, device=Q.device)
    scale = torch.ones(Q.shape[-1], dtype=Q.dtype, device=Q.device)
    scale = scale.index_put((rows,), 1 + momentum)
    if displacement is None:
        return Q * scale, b
    push = momentum * Q[..., rows] * displacement
    batch = torch.broadcast_shapes(b.shape[:-1], push.shape[:-1])
    b = b.expand(*batch, -1).index_add(-1, rows, push.expand(*batch, -1))
    return Q * scale, b


def full_dynamic(
    mass_matrix: torch.Tensor, velocity: torch.Tensor, force: torch.Tensor, h: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Full-dynamic system: ``Q = M/h²``, ``b = Mv/h + τ``.

    Args:
        mass_matrix: ``(..., nv, nv)`` joint-space inertia M(q) [kg, kg·m²].
        velocity: ``(..., nv)`` current velocity v.
        force: ``(..., nv)`` generalized force τ = applied − bias (Coriolis, gravity) [N, N·m].
        h: time step [s].

    Returns ``Q: (..., nv, nv)`` and ``b: (..., nv)``; the contact-free step is then
    ``v + h M⁻¹τ`` (semi-implicit Euler).
    """
    for name, x in (("mass_matrix", mass_matrix), ("velocity", velocity), ("force", force)):
        check_tensor(name, x)
        check_finite(name, x)
    nv = velocity.shape[-1]
    check_shape(
        "mass_matrix", mass_matrix, f"(..., {nv}, {nv})", mass_matrix.shape[-2:] == (nv, nv)
    )
    check_shape("force", force, f"(..., {nv})", force.shape[-1:] == (nv,))
    check_number("h", h)
    check_positive("h", h)
    b = (mass_matrix @ velocity.unsqueeze(-1)).squeeze(-1) / h + force
    return mass_matrix / (h * h), b
