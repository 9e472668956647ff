"""Configuration update ``q ⊕ h·v`` for MuJoCo-style joints, batched and differentiable."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch

from torchcontact.functional import Scalar
from torchcontact.rotations import (
    quaternion_conjugate,
    quaternion_exp,
    quaternion_log,
    quaternion_multiply,
)
from torchcontact.validation import (
    check_broadcasts_to,
    check_finite,
    check_positive,
    check_shape,
    check_tensor,
    checking_values,
)

JOINT_SIZES = {"free": (7, 6), "ball": (4, 3), "slide": (1, 1), "hinge": (1, 1)}
"""(nq, nv) per joint type, as in MuJoCo."""


class JointLayout:
    """The joints of q in order, grouped into named blocks of consecutive joints.

    Free joints: position (3) then quaternion (w, x, y, z) in q; linear velocity in the world
    frame then angular velocity in the body frame in v. Ball joints: a quaternion and a
    body-frame angular velocity. Slide and hinge joints: one coordinate each.

    Args:
        joints: joint types in order, each among :data:`JOINT_SIZES`, e.g.
            ``["free", "slide", "slide", "slide"]``.
        blocks: block name → number of consecutive joints, in the joints' order, the counts
            summing to ``len(joints)``, e.g. ``{"object": 1, "robot": 9}``; None: one block
            ``"all"`` of every joint. :meth:`manipulation` builds the object-then-robot layout.
            Kept in ``layout.blocks`` (read it, do not change it).
    """

    def __init__(self, joints: Sequence[str], blocks: Mapping[str, int] | None = None):
        unknown = [j for j in joints if j not in JOINT_SIZES]
        if unknown:
            raise ValueError(f"joints must be among {sorted(JOINT_SIZES)}, got {unknown}")
        self.joints = tuple(joints)
        linear_q, linear_v, quat_q, angular_v = [], [], [], []
        starts = [(0, 0)]  # (q, v) offset of every joint, then (nq, nv)
        iq = iv = 0
        for joint in self.joints:
            if joint in ("slide", "hinge"):
                linear_q.append(iq)
                linear_v.append(iv)
            else:
                if joint == "free":
                    linear_q += [iq, iq + 1, iq + 2]
                    linear_v += [iv, iv + 1, iv + 2]
                quat_q.append(
                    list(range(iq + 3, iq + 7)) if joint == "free" else list(range(iq, iq + 4))
                )
                angular_v.append(
                    list(range(iv + 3, iv + 6)) if joint == "free" else list(range(iv, iv + 3))
                )
            dq, dv = JOINT_SIZES[joint]
            iq, iv = iq + dq, iv + dv
            starts.append((iq, iv))
        self.nq, self.nv = iq, iv
        self.linear_q = torch.tensor(linear_q, dtype=torch.long)
        self.linear_v = torch.tensor(linear_v, dtype=torch.long)
        self.quat_q = torch.tensor(quat_q, dtype=torch.long).reshape(-1, 4)
        self.angular_v = torch.tensor(angular_v, dtype=torch.long).reshape(-1, 3)
        order = torch.cat([self.linear_q, self.quat_q.flatten()])
        self.assemble = torch.argsort(order)
        self.blocks = _check_blocks(blocks, len(self.joints))
        self._joint_ranges, self._q_slices, self._v_slices = {}, {}, {}
        first = 0
        for name, count in self.blocks.items():
            (q0, v0), (q1, v1) = starts[first], starts[first + count]
            self._joint_ranges[name] = range(first, first + count)
            self._q_slices[name], self._v_slices[name] = slice(q0, q1), slice(v0, v1)
            first += count

    @classmethod
    def manipulation(cls, robot_joints: Sequence[str]) -> JointLayout:
        """The object's free joint, then ``robot_joints`` (slide or hinge: a robot's q and v
        coincide): blocks ``"object"`` and ``"robot"``."""
        if isinstance(robot_joints, str):
            raise TypeError(f"robot_joints must be a sequence of joint types, got {robot_joints!r}")
        robot_joints = list(robot_joints)
        others = [j for j in robot_joints if j not in ("slide", "hinge")]
        if others:
            raise ValueError(f"robot_joints must be 'slide' or 'hinge' joints, got {others}")
        return cls(["free", *robot_joints], blocks={"object": 1, "robot": len(robot_joints)})

    def _block_name(self, name: str) -> str:
        if name not in self.blocks:
            raise ValueError(f"name must be a block among {list(self.blocks)}, got {name!r}")
        return name

    def q_slice(self, name: str) -> slice:
        """The coordinates of block ``name`` in q ``(nq,)``."""
        return self._q_slices[self._block_name(name)]

    def v_slice(self, name: str) -> slice:
        """The velocities of block ``name`` in v ``(nv,)``."""
        return self._v_slices[self._block_name(name)]

    def block(self, q: torch.Tensor, name: str) -> torch.Tensor:
        """Block ``name`` of ``q: (..., nq)``, a view ``(..., nq_block)``."""
        check_shape("q", q, f"(..., {self.nq})", q.dim() >= 1 and q.shape[-1] == self.nq)
        return q[..., self.q_slice(name)]

    def block_velocity(self, v: torch.Tensor, name: str) -> torch.Tensor:
        """Block ``name`` of ``v: (..., nv)``, a view ``(..., nv_block)``."""
        check_shape("v", v, f"(..., {self.nv})", v.dim() >= 1 and v.shape[-1] == self.nv)
        return v[..., self.v_slice(name)]

    def object_pose(self, q: torch.Tensor) -> torch.Tensor:
        """The object's pose ``(..., 7)``, position [m] then quaternion, of ``q: (..., nq)``.

        Needs a block ``"object"`` made of a single free joint.
        """
        joints = [self.joints[i] for i in self._joint_ranges.get("object", ())]
        if joints != ["free"]:
            raise ValueError(
                f"layout must have a block 'object' of one free joint, got blocks {self.blocks} "
                f"of joints {list(self.joints)}"
            )
        return self.block(q, "object")

    def robot(self, q: torch.Tensor) -> torch.Tensor:
        """The robot's coordinates ``(..., nq_robot)`` of ``q: (..., nq)`` (block ``"robot"``)."""
        return self.block(q, "robot")

    def __repr__(self) -> str:
        if self.blocks == {"all": len(self.joints)}:
            return f"JointLayout({list(self.joints)})"
        return f"JointLayout({list(self.joints)}, blocks={self.blocks})"


def object_indices(joints: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
    """Indices ``(n_obj, 7)`` in q and ``(n_obj, 6)`` in v of the free joints (the objects)."""
    iq = iv = 0
    q_index, v_index = [], []
    for joint in JointLayout(joints).joints:
        if joint == "free":
            q_index.append(list(range(iq, iq + 7)))
            v_index.append(list(range(iv, iv + 6)))
        iq, iv = iq + JOINT_SIZES[joint][0], iv + JOINT_SIZES[joint][1]
    if not q_index:
        raise ValueError(f"joints must include a free joint (the object), got {joints}")
    return torch.tensor(q_index), torch.tensor(v_index)


def _check_blocks(blocks: Mapping[str, int] | None, n_joints: int) -> dict[str, int]:
    """``blocks`` as a dict, checked to split ``n_joints`` joints; None: one block ``"all"``."""
    if blocks is None:
        return {"all": n_joints}
    if not isinstance(blocks, Mapping):
        raise ValueError(f"blocks must map block names to joint counts, got {blocks!r}")
    for name, count in blocks.items():
        if not isinstance(name, str):
            raise ValueError(f"blocks must be named by strings, got {name!r}")
        if isinstance(count, bool) or not isinstance(count, int) or count < 0:
            raise ValueError(f"blocks[{name!r}] must be a non-negative integer, got {count!r}")
    if sum(blocks.values()) != n_joints:
        raise ValueError(
            f"blocks must count all {n_joints} joints, got {dict(blocks)} "
            f"(summing to {sum(blocks.values())})"
        )
    return dict(blocks)


def _check_integrate_inputs(q, v, h: Scalar, layout: JointLayout) -> None:
    """Raise ``ValueError`` (``TypeError`` for non-tensors) naming the bad argument of
    :func:`integrate`."""
    if not isinstance(layout, JointLayout):
        raise TypeError(f"layout must be a JointLayout, got {type(layout).__name__}")
    check_tensor("q", q)
    check_tensor("v", v)
    check_shape("q", q, f"(..., {layout.nq})", q.dim() >= 1 and q.shape[-1] == layout.nq)
    check_shape("v", v, f"(..., {layout.nv})", v.dim() >= 1 and v.shape[-1] == layout.nv)
    try:
        batch = torch.broadcast_shapes(q.shape[:-1], v.shape[:-1])
    except RuntimeError:
        raise ValueError(
            f"batch shapes of q and v must broadcast, got q{tuple(q.shape[:-1])}, "
            f"v{tuple(v.shape[:-1])}"
        ) from None
    if isinstance(h, torch.Tensor):
        check_broadcasts_to("h", h, batch, "the batch shape of q and v")
    check_positive("h", h)
    check_finite("q", q)
    check_finite("v", v)
    if checking_values(q) and layout.quat_q.numel():
        norms = torch.linalg.vector_norm(q.detach()[..., layout.quat_q.to(q.device)], dim=-1)
        if not bool((norms > 0).all()):
            raise ValueError("q must hold non-zero quaternions, got a zero quaternion")


def integrate(q: torch.Tensor, v: torch.Tensor, h: Scalar, layout: JointLayout) -> torch.Tensor:
    """Advance ``q: (..., nq)`` by ``v: (..., nv)`` over ``h`` [s] (float or ``(...)`` tensor).

    Slide/hinge coordinates and free-joint positions move linearly; quaternions rotate by the
    body-frame angular velocity, ``q ← q ⊗ exp(h ω)``, and are renormalized (as MuJoCo does).

    The batch shape is that of ``q`` and ``v`` broadcast together; ``h`` must broadcast to it
    without enlarging it. Raises ``ValueError`` naming ``h`` unless it is positive and finite,
    ``v`` when it holds NaN or Inf, and ``q`` when it does or holds a zero quaternion.
    """
    _check_integrate_inputs(q, v, h, layout)
    if isinstance(h, torch.Tensor) and h.dim() > 0:
        h = h.unsqueeze(-1)
    device = q.device
    linear = q[..., layout.linear_q.to(device)] + h * v[..., layout.linear_v.to(device)]
    quat = q[..., layout.quat_q.to(device)]
    omega = v[..., layout.angular_v.to(device)]
    step = h.unsqueeze(-1) if isinstance(h, torch.Tensor) and h.dim() > 0 else h
    rotated = quaternion_multiply(quat, quaternion_exp(step * omega))
    rotated = rotated / torch.linalg.vector_norm(rotated, dim=-1, keepdim=True)
    batch = torch.broadcast_shapes(linear.shape[:-1], rotated.shape[:-2])
    pieces = torch.cat([linear.expand(*batch, -1), rotated.expand(*batch, -1, -1).flatten(-2)], -1)
    return pieces[..., layout.assemble.to(device)]


def difference(q0: torch.Tensor, q1: torch.Tensor, h: Scalar, layout: JointLayout) -> torch.Tensor:
    """The velocity ``v: (..., nv)`` that :func:`integrate` takes from ``q0`` to ``q1`` (both
    ``(..., nq)``) in ``h`` [s]: linear coordinates ``(q1 − q0)/h``, quaternions the
    body-frame ``log(q0⁻¹ ⊗ q1)/h`` (the shorter rotation). MuJoCo's ``mj_differentiatePos``.
    """
    _check_integrate_inputs(q0, q0.new_zeros(layout.nv), h, layout)
    check_tensor("q1", q1)
    check_shape("q1", q1, f"(..., {layout.nq})", q1.dim() >= 1 and q1.shape[-1] == layout.nq)
    check_finite("q1", q1)
    device = q0.device
    linear_q, quat_q = layout.linear_q.to(device), layout.quat_q.to(device)
    linear = (q1[..., linear_q] - q0[..., linear_q]) / h
    start, end = q0[..., quat_q], q1[..., quat_q]
    relative = quaternion_multiply(quaternion_conjugate(start), end)
    relative = relative / torch.linalg.vector_norm(relative, dim=-1, keepdim=True)
    angular = quaternion_log(relative).flatten(-2) / h
    batch = torch.broadcast_shapes(linear.shape[:-1], angular.shape[:-1])
    v = torch.zeros(*batch, layout.nv, dtype=linear.dtype, device=device)
    v[..., layout.linear_v.to(device)] = linear.expand(*batch, -1)
    v[..., layout.angular_v.flatten().to(device)] = angular.expand(*batch, -1)
    return v
