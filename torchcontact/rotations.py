"""Quaternion helpers in pure torch, batched over any leading dimensions.

Quaternions are ``(..., 4)`` tensors ordered (w, x, y, z), scalar part first, as in MuJoCo.
"""

from __future__ import annotations

import torch


def quaternion_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a ⊗ b (..., 4)`` of ``a, b: (..., 4)`` (broadcast), not normalized.

    No sign convention is imposed on the result: ``a ⊗ b`` and ``−(a ⊗ b)`` are the same rotation.
    """
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    w = aw * bw - ax * bx - ay * by - az * bz
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    return torch.stack((w, x, y, z), -1)


def quaternion_conjugate(quat: torch.Tensor) -> torch.Tensor:
    """``q* (..., 4)``: the vector part negated; the inverse rotation of a unit ``quat``."""
    return quat * quat.new_tensor([1.0, -1.0, -1.0, -1.0])


def quaternion_exp(rotation: torch.Tensor) -> torch.Tensor:
    """Unit quaternion ``(..., 4)`` of the rotation vector ``rotation: (..., 3)`` [rad].

    Uses ``sinc`` so the value and the gradient are exact at a zero rotation (where an
    axis-angle conversion through ``θ`` and ``axis = rotation/θ`` has a 0/0 in its gradient).
    """
    angle = torch.linalg.vector_norm(rotation, dim=-1, keepdim=True)
    half_sinc = 0.5 * torch.sinc(angle / (2 * torch.pi))  # sin(θ/2)/θ
    return torch.cat([torch.cos(0.5 * angle), rotation * half_sinc], dim=-1)


def quaternion_log(quat: torch.Tensor) -> torch.Tensor:
    """Rotation vector ``(..., 3)`` [rad] of unit ``quat: (..., 4)``, the inverse of
    :func:`quaternion_exp`: the shorter of the two rotations ``q`` and ``−q`` describe, so its
    angle is at most π."""
    quat = torch.where(quat[..., :1] < 0, -quat, quat)
    vector = quat[..., 1:]
    sine = torch.linalg.vector_norm(vector, dim=-1, keepdim=True)
    angle = 2 * torch.atan2(sine, quat[..., :1])
    # angle/sin(θ/2) → 2 as the rotation vanishes; the guarded ratio keeps the gradient finite
    ratio = torch.where(sine > 1e-12, angle / sine.clamp_min(1e-12), torch.full_like(sine, 2.0))
    return vector * ratio


def quaternion_to_matrix(quat: torch.Tensor) -> torch.Tensor:
    """Rotation matrix ``R (..., 3, 3)`` of ``quat: (..., 4)``, of any non-zero length.

    The quaternion is normalized implicitly: every product is scaled by ``2/‖q‖²``.
    """
    w, x, y, z = quat.unbind(-1)
    scale = 2.0 / (quat * quat).sum(-1)
    entries = (
        1 - scale * (y * y + z * z),
        scale * (x * y - z * w),
        scale * (x * z + y * w),
        scale * (x * y + z * w),
        1 - scale * (x * x + z * z),
        scale * (y * z - x * w),
        scale * (x * z - y * w),
        scale * (y * z + x * w),
        1 - scale * (x * x + y * y),
    )
    return torch.stack(entries, -1).reshape(quat.shape[:-1] + (3, 3))


def up_axis(quat: torch.Tensor) -> torch.Tensor:
    """The body's z axis in the world, ``R(q) ẑ (..., 3)``, for unit ``quat: (..., 4)``."""
    w, x, y, z = quat.unbind(-1)
    return torch.stack((2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)), -1)


def quaternion_error(quat: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``e = 1 − ⟨q, q*⟩² (...)`` = sin²(θ/2) for unit ``quat, target: (..., 4)``, in [0, 1].

    Zero when aligned; blind to the sign of either quaternion (q and −q agree).
    """
    return 1.0 - (quat * target).sum(-1).square()


def quaternion_angle(quat: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Rotation angle ``θ = arccos(1 − 2e) (...)`` [rad] in [0, π] between unit ``(..., 4)``
    quaternions, with ``e`` the :func:`quaternion_error` (clamped into arccos's domain).

    Its gradient is infinite where θ is 0 or π: use :func:`quaternion_error` in a loss.
    """
    cosine = 1.0 - 2.0 * quaternion_error(quat, target)
    return torch.arccos(cosine.clamp(-1.0, 1.0))
