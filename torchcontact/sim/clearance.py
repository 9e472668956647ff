"""A start without interpenetration: the robot's joints moved out of the object it overlaps.

A hand's initial configuration is fixed while its objects and their placements vary, so a large
object may be placed through a finger (35–45 % of the TriFinger's generated-object trials, and
most of the Allegro's, whose curled fingers lie over the palm). MuJoCo then resolves the overlap
by a push in the first substeps that no controller commanded. :func:`clear_joints` instead
starts the robot at the nearest configuration clear of the object, by damped least squares on
the penetrating contacts' distances.
"""

from __future__ import annotations

import mujoco
import numpy as np

CLEARANCE = 1e-3
"""[m] How far from the object :func:`clear_joints` moves a penetrating geom."""

MIN_LEVER = 0.02
"""[m/rad] A penetration the joints move out of by less than this per radian (a finger's base
link, turning about an axis that passes near the object) is left as it is: clearing it would
swing the joint to its limit for a millimetre."""


def penetrations(model: mujoco.MjModel, data: mujoco.MjData, body: int, robot_bodies) -> list:
    """The contacts of ``data`` (after collision detection) between ``body`` and any of
    ``robot_bodies`` with a negative distance."""
    found = []
    for i in range(data.ncon):
        contact = data.contact[i]
        bodies = model.geom_bodyid[contact.geom1], model.geom_bodyid[contact.geom2]
        if contact.dist < 0 and body in bodies:
            other = bodies[1] if bodies[0] == body else bodies[0]
            if other in robot_bodies:
                found.append(contact)
    return found


def clear_joints(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    body: int,
    joint_qpos: np.ndarray,
    joint_dofs: np.ndarray,
    *,
    clearance: float = CLEARANCE,
    damping: float = 1e-4,
    max_iter: int = 100,
) -> float:
    """Move the robot's joints in ``data.qpos`` until no robot geom penetrates ``body``.

    Each iteration takes the least-norm joint step (damped by ``damping`` [m²]) that moves every
    penetrating contact to ``clearance`` [m] outside, to first order, and clips the joints to
    their limits. The object and every other coordinate stay; ``data`` ends at the cleared
    configuration with its kinematics and contacts computed.

    Args:
        body: the object's body id.
        joint_qpos: ``(n,)`` qpos indices of the robot's hinge or slide joints.
        joint_dofs: ``(n,)`` their dof indices.

    Returns:
        The deepest penetration left [m] (0 when cleared within ``max_iter`` iterations).
    """
    robot_bodies = {int(model.dof_bodyid[dof]) for dof in joint_dofs}
    for dof in joint_dofs:  # every body carried by a robot joint
        robot_bodies |= _subtree(model, int(model.dof_bodyid[dof]))
    joints = model.dof_jntid[joint_dofs]
    limited = model.jnt_limited[joints].astype(bool)
    low, high = model.jnt_range[joints].T
    jacp = np.zeros((3, model.nv))
    for _ in range(max_iter):
        mujoco.mj_forward(model, data)
        found = penetrations(model, data, body, robot_bodies)
        if not found:
            return 0.0
        rows, gaps = [], []
        for contact in found:
            normal, point = contact.frame[:3], contact.pos
            robot_first = model.geom_bodyid[contact.geom1] != body
            robot = model.geom_bodyid[contact.geom1 if robot_first else contact.geom2]
            mujoco.mj_jac(model, data, jacp, None, point, robot)
            # the distance grows as geom2 moves along the normal and geom1 against it
            row = (-normal if robot_first else normal) @ jacp[:, joint_dofs]
            if np.linalg.norm(row) >= MIN_LEVER:
                rows.append(row)
                gaps.append(clearance - contact.dist)
        if not rows:
            break
        q = data.qpos[joint_qpos]
        q = q + _step(np.array(rows), np.array(gaps), q, limited, low, high, damping)
        data.qpos[joint_qpos] = np.where(limited, np.clip(q, low, high), q)
    mujoco.mj_forward(model, data)
    left = penetrations(model, data, body, robot_bodies)
    return max((-c.dist for c in left), default=0.0)


def _step(a, b, q, limited, low, high, damping) -> np.ndarray:
    """The least-norm ``Δq`` with ``a Δq ≈ b``, over the joints free to move that way: a
    joint held at a limit by the step is left out and the rest solved again."""
    free = np.ones(len(q), dtype=bool)
    for _ in range(len(q)):
        cols = a * free
        step = cols.T @ np.linalg.solve(cols @ cols.T + damping * np.eye(len(b)), b)
        blocked = free & limited & (((q <= low) & (step < 0)) | ((q >= high) & (step > 0)))
        if not blocked.any():
            return step
        free &= ~blocked
    return np.zeros_like(q)


def _subtree(model: mujoco.MjModel, root: int) -> set[int]:
    """Ids of ``root`` and every body below it."""
    found, parents = {root}, model.body_parentid
    for body in range(root + 1, model.nbody):
        if parents[body] in found:
            found.add(body)
    return found
