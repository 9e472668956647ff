"""Configuration update ``q ⊕ h·v`` for MuJoCo-style joints, batched and differentiable."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from pytorch_kinematics.transforms import quaternion_raw_multiply

from torchcontact.functional import Scalar
from torchcontact.validation import check_shape, check_tensor

JOINT_SIZES = {"free": (7, 6), "ball": (4, 3), "slide": (1, 1), "hinge": (1, 1)}
"""(nq, nv) per joint type, as in MuJoCo."""


class JointLayout:
    """The joints of q in order, e.g. ``JointLayout(["free", "slide", "slide", "slide"])``.

    Free joints: position (3) then quaternion (w, x, y, z) in q; linear velocity in the world
    frame then angular velocity in the body frame in v. Ball joints: a quaternion and a
    body-frame angular velocity. Slide and hinge joints: one coordinate each.
    """

    def __init__(self, joints: Sequence[str]):
        unknown = [j for j in joints if j not in JOINT_SIZES]
        if unknown:
            raise ValueError(f"joints must be among {sorted(JOINT_SIZES)}, got {unknown}")
        self.joints = tuple(joints)
        linear_q, linear_v, quat_q, angular_v = [], [], [], []
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
        self.nq, self.nv = iq, iv
        self.linear_q = torch.tensor(linear_q, dtype=torch.long)
        self.linear_v = torch.tensor(linear_v, dtype=torch.long)
        self.quat_q = torch.tensor(quat_q, dtype=torch.long).reshape(-1, 4)
        self.angular_v = torch.tensor(angular_v, dtype=torch.long).reshape(-1, 3)
        order = torch.cat([self.linear_q, self.quat_q.flatten()])
        self.assemble = torch.argsort(order)

    def __repr__(self) -> str:
        return f"JointLayout({list(self.joints)})"


def quaternion_exp(rotation: torch.Tensor) -> torch.Tensor:
    """Unit quaternion of the rotation vector ``rotation: (..., 3)`` [rad], smooth at zero.

    Uses ``sinc`` so the value and the gradient are exact at a zero rotation (where
    ``pytorch_kinematics``' axis-angle conversion has a 0/0 in its gradient).
    """
    angle = torch.linalg.vector_norm(rotation, dim=-1, keepdim=True)
    half_sinc = 0.5 * torch.sinc(angle / (2 * torch.pi))  # sin(θ/2)/θ
    return torch.cat([torch.cos(0.5 * angle), rotation * half_sinc], dim=-1)


def integrate(q: torch.Tensor, v: torch.Tensor, h: Scalar, layout: JointLayout) -> torch.Tensor:
    """Advance ``q: (..., nq)`` by ``v: (..., nv)`` over ``h`` [s] (float or ``(...)`` tensor).

    Slide/hinge coordinates and free-joint positions move linearly; quaternions rotate by the
    body-frame angular velocity, ``q ← q ⊗ exp(h ω)``, and are renormalized (as MuJoCo does).
    """
    check_tensor("q", q)
    check_tensor("v", v)
    check_shape("q", q, f"(..., {layout.nq})", q.dim() >= 1 and q.shape[-1] == layout.nq)
    check_shape("v", v, f"(..., {layout.nv})", v.dim() >= 1 and v.shape[-1] == layout.nv)
    if isinstance(h, torch.Tensor) and h.dim() > 0:
        h = h.unsqueeze(-1)
    device = q.device
    linear = q[..., layout.linear_q.to(device)] + h * v[..., layout.linear_v.to(device)]
    quat = q[..., layout.quat_q.to(device)]
    omega = v[..., layout.angular_v.to(device)]
    step = h.unsqueeze(-1) if isinstance(h, torch.Tensor) and h.dim() > 0 else h
    rotated = quaternion_raw_multiply(quat, quaternion_exp(step * omega))
    rotated = rotated / torch.linalg.vector_norm(rotated, dim=-1, keepdim=True)
    batch = torch.broadcast_shapes(linear.shape[:-1], rotated.shape[:-2])
    pieces = torch.cat([linear.expand(*batch, -1), rotated.expand(*batch, -1, -1).flatten(-2)], -1)
    return pieces[..., layout.assemble.to(device)]
