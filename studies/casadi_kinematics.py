"""Fingertip forward kinematics as a CasADi function, built from the same MJCF as the MPC's.

The paper's implementation writes each hand's forward kinematics by hand in CasADi. The IPOPT
baseline (:mod:`studies.ipopt_baseline`) needs the same map to state the hands' MPC,
so this composes it from the MuJoCo model instead: per body, its fixed offset from the
parent, then its joints in order, as MuJoCo's own kinematics pass does. Agreement with the
MuJoCo sites is tested.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

from torchcontact.sim.kinematics import load_robot


def _quat_matrix(quat: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion (w, x, y, z)."""
    matrix = np.zeros(9)
    mujoco.mju_quat2Mat(matrix, np.asarray(quat, dtype=np.float64))
    return matrix.reshape(3, 3)


def _axis_rotation(axis: np.ndarray, angle):
    """Rodrigues' rotation (3, 3, CasADi) by ``angle`` about the unit ``axis (3,)``."""
    import casadi as cs

    x, y, z = (float(a) for a in axis)
    cross = cs.DM([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return cs.DM.eye(3) + cs.sin(angle) * cross + (1 - cs.cos(angle)) * cs.mtimes(cross, cross)


def casadi_fingertips(mjcf: str | Path, tips: Sequence[str]):
    """``joints (n,) ↦ tips (n_tips, 3)`` [m] as a ``casadi.Function`` named ``fingertips``.

    Args:
        mjcf: a robot MJCF file whose world frame is the scene's, with hinge and slide joints
            only (joint values in the file's order, as
            :class:`~torchcontact.sim.kinematics.FingertipKinematics` takes them).
        tips: names of the sites to evaluate.

    Raises ``ValueError`` naming the argument for a missing file, unknown sites or other joint
    types.
    """
    import casadi as cs

    path, model, site_ids = load_robot(mjcf, tips)
    # MuJoCo 4 reports joint types as NumPy integers, unequal to its enum members: use ints
    hinge, slide = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
    other = [
        model.joint(j).name for j in range(model.njnt) if model.jnt_type[j] not in (hinge, slide)
    ]
    if other:
        raise ValueError(f"{path.name}: joints must be hinges or slides, got {other}")

    joints = cs.SX.sym("joints", model.nq)
    rotation, position = [cs.DM.eye(3)], [cs.DM.zeros(3)]  # per body, in the world frame
    for body in range(1, model.nbody):
        parent = model.body_parentid[body]
        R = cs.mtimes(rotation[parent], cs.DM(_quat_matrix(model.body_quat[body])))
        p = position[parent] + cs.mtimes(rotation[parent], cs.DM(model.body_pos[body]))
        start = model.body_jntadr[body]
        for j in range(start, start + model.body_jntnum[body]):
            value = joints[model.jnt_qposadr[j]] - model.qpos0[model.jnt_qposadr[j]]
            axis = model.jnt_axis[j]
            if model.jnt_type[j] == slide:
                p = p + cs.mtimes(R, cs.DM(axis)) * value
            else:  # a hinge turns the body about its anchor, the joint's position in the body
                anchor = cs.DM(model.jnt_pos[j])
                turned = cs.mtimes(R, _axis_rotation(axis, value))
                p = p + cs.mtimes(R, anchor) - cs.mtimes(turned, anchor)
                R = turned
        rotation.append(R)
        position.append(p)
    points = [
        position[model.site_bodyid[i]]
        + cs.mtimes(rotation[model.site_bodyid[i]], cs.DM(model.site_pos[i]))
        for i in site_ids
    ]
    return cs.Function("fingertips", [joints], [cs.horzcat(*points).T])
