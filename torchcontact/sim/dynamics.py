"""Full-dynamic quantities from MuJoCo: M(q), bias forces, and the joint layout of q."""

from __future__ import annotations

import mujoco
import numpy as np

from torchcontact.integrate import JointLayout

_JOINT_NAMES = {
    int(mujoco.mjtJoint.mjJNT_FREE): "free",
    int(mujoco.mjtJoint.mjJNT_BALL): "ball",
    int(mujoco.mjtJoint.mjJNT_SLIDE): "slide",
    int(mujoco.mjtJoint.mjJNT_HINGE): "hinge",
}


def joint_layout(model: mujoco.MjModel) -> JointLayout:
    """The :class:`JointLayout` of ``model``'s qpos/qvel (joints in MuJoCo's order)."""
    return JointLayout([_JOINT_NAMES[int(t)] for t in model.jnt_type])


def mass_matrix(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Dense joint-space inertia M(q) ``(nv, nv)``; ``data`` must have run ``mj_forward``."""
    dense = np.zeros((model.nv, model.nv))
    if hasattr(data, "qM"):  # MuJoCo 3: mj_fullM(m, dst, qM)
        mujoco.mj_fullM(model, dense, data.qM)
    else:  # MuJoCo 4: mj_fullM(m, d, dst)
        mujoco.mj_fullM(model, data, dense)
    return dense


def bias_force(data: mujoco.MjData) -> np.ndarray:
    """Coriolis, centrifugal and gravity forces ``(nv,)`` (MuJoCo's ``qfrc_bias``) [N, N·m]."""
    return data.qfrc_bias.copy()
