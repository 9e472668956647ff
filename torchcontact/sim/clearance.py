"""A start without interpenetration: the robot's joints moved out of the object it overlaps.

A hand's initial configuration is fixed while its objects and their placements vary, so a large
object may be placed through a finger (before scenes 10, in 35–48 % of the TriFinger's trials).
MuJoCo then resolves the overlap by a shove in the first substeps that no controller
commanded. :func:`clear_joints` instead starts the robot near its initial configuration, clear
of the object, by damped least squares on the penetrating contacts' distances. It is a local
method: it moves each contact along its normal, so an overlap whose normal no joint moves along
within its limits (a base link, or a pad deep inside an object that only another direction
would leave) stays, and is reported.
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


def penetrations(model: mujoco.MjModel, data: mujoco.MjData, body: int, robot) -> list:
    """The contacts of ``data`` (after collision detection) between ``body`` and any of
    ``robot`` with a negative distance."""
    found = []
    for i in range(data.ncon):
        contact = data.contact[i]
        bodies = model.geom_bodyid[contact.geom1], model.geom_bodyid[contact.geom2]
        if contact.dist < 0 and body in bodies:
            other = bodies[1] if bodies[0] == body else bodies[0]
            if other in robot:
                found.append(contact)
    return found


def robot_overlap(
    model: mujoco.MjModel, data: mujoco.MjData, body: int, joint_dofs: np.ndarray
) -> float:
    """[m] The deepest overlap of ``body`` with the bodies the joints ``joint_dofs`` carry, at
    ``data``'s configuration (0: none)."""
    return _deepest(model, data, body, robot_bodies(model, joint_dofs))


def robot_bodies(model: mujoco.MjModel, joint_dofs: np.ndarray) -> set[int]:
    """Ids of every body the joints ``joint_dofs`` carry (their bodies and all below)."""
    found: set[int] = set()
    for dof in joint_dofs:
        found |= _subtree(model, int(model.dof_bodyid[dof]))
    return found


def clear_joints(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    body: int,
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
        joint_dofs: ``(n,)`` dof indices of the robot's hinge or slide joints.

    Returns:
        The deepest penetration left [m] (as :func:`robot_overlap`; 0 when cleared).
    """
    robot = robot_bodies(model, joint_dofs)
    joints = model.dof_jntid[joint_dofs]
    joint_qpos = model.jnt_qposadr[joints]
    limited = model.jnt_limited[joints].astype(bool)
    low, high = model.jnt_range[joints].T
    jacp = np.zeros((3, model.nv))
    for _ in range(max_iter):
        mujoco.mj_forward(model, data)
        found = penetrations(model, data, body, robot)
        if not found:
            return 0.0
        rows, gaps = [], []
        for contact in found:
            normal, point = contact.frame[:3], contact.pos
            robot_first = model.geom_bodyid[contact.geom1] != body
            link = model.geom_bodyid[contact.geom1 if robot_first else contact.geom2]
            mujoco.mj_jac(model, data, jacp, None, point, link)
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
    return _deepest(model, data, body, robot)


def _deepest(model: mujoco.MjModel, data: mujoco.MjData, body: int, robot: set[int]) -> float:
    """[m] The deepest overlap of ``body`` with ``robot`` at ``data``'s configuration (0: none),
    after computing its kinematics and contacts."""
    mujoco.mj_forward(model, data)
    found = penetrations(model, data, body, robot)
    return max((-contact.dist for contact in found), default=0.0)


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
