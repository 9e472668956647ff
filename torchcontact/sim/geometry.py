"""A MuJoCo scene's contact geometry, read from its model: the torch twin of its detector.

:func:`body_tree` reads the kinematic tree (bodies, offsets, joints); :func:`geom_shape` a
geom's collision shape (a mesh by its convex hull, as MuJoCo collides it);
:func:`scene_geometry` the pairs a :class:`~torchcontact.sim.detect.ContactDetector` models,
with its slots, margin, μ and per-pair budget. What comes back is pure torch
(:class:`~torchcontact.geometry.SceneGeometry`): no MuJoCo call is left in its evaluation.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from torchcontact.geometry import BodyTree, Joint, Pair, SceneGeometry, Shape
from torchcontact.sim.detect import ContactDetector

DEFAULT_PER_PAIR = 4
"""Points per pair where the detector keeps them all (``per_pair=None``)."""

_JOINTS = {
    int(mujoco.mjtJoint.mjJNT_FREE): "free",
    int(mujoco.mjtJoint.mjJNT_BALL): "ball",
    int(mujoco.mjtJoint.mjJNT_SLIDE): "slide",
    int(mujoco.mjtJoint.mjJNT_HINGE): "hinge",
}


def body_tree(model: mujoco.MjModel, dtype: torch.dtype = torch.float64) -> BodyTree:
    """The bodies and joints of ``model`` as a :class:`~torchcontact.geometry.BodyTree` over
    its ``qpos (nq,)`` and ``qvel (nv,)`` (mocap bodies stay at their model offsets)."""
    joints = []
    for j in range(model.njnt):
        kind = _JOINTS[int(model.jnt_type[j])]
        address = int(model.jnt_qposadr[j])
        joints.append(
            Joint(
                body=int(model.jnt_bodyid[j]),
                kind=kind,
                axis=tuple(float(x) for x in model.jnt_axis[j]),
                anchor=tuple(float(x) for x in model.jnt_pos[j]),
                qpos=address,
                dof=int(model.jnt_dofadr[j]),
                reference=float(model.qpos0[address]) if kind in ("slide", "hinge") else 0.0,
            )
        )
    return BodyTree(
        parent=[int(p) for p in model.body_parentid],
        offset_position=torch.tensor(model.body_pos, dtype=dtype),
        offset_quaternion=torch.tensor(model.body_quat, dtype=dtype),
        joints=joints,
        nq=model.nq,
        nv=model.nv,
    )


def geom_shape(model: mujoco.MjModel, geom: int) -> Shape:
    """The collision shape of ``geom`` in its body's frame; ``ValueError`` naming the geom for
    a type the torch geometry does not model (cylinders, ellipsoids, height fields, SDFs)."""
    kind = int(model.geom_type[geom])
    size = model.geom_size[geom]
    position = model.geom_pos[geom]
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.geom_quat[geom])
    rotation = rotation.reshape(3, 3)
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return Shape.sphere(size[0], position)
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return Shape.capsule(size[0], size[1], position, rotation)
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return Shape.box(size, position, rotation)
    if kind == mujoco.mjtGeom.mjGEOM_PLANE:
        return Shape.plane(rotation[:, 2], position)
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = model.geom_dataid[geom]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        return Shape.hull(model.mesh_vert[start : start + count] @ rotation.T + position)
    name = _geom_name(model, geom)
    raise ValueError(
        f"geom {name!r} is a {mujoco.mjtGeom(kind).name}: the torch geometry models spheres, "
        "capsules, boxes, planes and meshes (by their convex hull)"
    )


def _geom_name(model: mujoco.MjModel, geom: int) -> str:
    return model.geom(geom).name or f"#{geom}"


def geom_id(model: mujoco.MjModel, label: str) -> int:
    """The id of the geom a :attr:`Pair.label` half names (its name, or ``#id``)."""
    if label.startswith("#"):
        return int(label[1:])
    return int(model.geom(label).id)


def collides(model: mujoco.MjModel, g1: int, g2: int) -> bool:
    """Whether MuJoCo's collision filter lets geoms ``g1`` and ``g2`` collide: their
    contype/conaffinity match, their bodies differ, not both welded to the world, not a parent
    and its child (unless one is the world), and no ``<exclude>`` names them."""
    if not (
        model.geom_contype[g1] & model.geom_conaffinity[g2]
        or model.geom_contype[g2] & model.geom_conaffinity[g1]
    ):
        return False
    b1, b2 = int(model.geom_bodyid[g1]), int(model.geom_bodyid[g2])
    w1, w2 = int(model.body_weldid[b1]), int(model.body_weldid[b2])
    if w1 == w2:
        return False
    parent1, parent2 = (
        int(model.body_weldid[model.body_parentid[w1]]),
        int(model.body_weldid[model.body_parentid[w2]]),
    )
    filter_parent = not model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT
    if filter_parent and w1 != 0 and w2 != 0 and (parent1 == w2 or parent2 == w1):
        return False
    signature = (min(b1, b2) << 16) + max(b1, b2)
    return signature not in set(int(s) for s in model.exclude_signature)


def scene_geometry(
    detector: ContactDetector,
    *,
    smoothing: float | None = None,
    dtype: torch.dtype | None = None,
) -> SceneGeometry:
    """The torch geometry of the pairs ``detector`` models: the collision pairs with one of its
    bodies, less its exclusions, at its slots, margin (its model's, per pair the larger of the
    two geoms') and μ (its override, else MuJoCo's combined sliding friction).

    Raises ``ValueError`` when the pairs' margins differ or a geom's type is not modelled."""
    model = detector.model
    dtype = dtype or detector.dtype
    shapes, bodies, index, pairs, margins = [], [], {}, [], set()

    def shape_of(geom: int) -> int:
        if geom not in index:
            index[geom] = len(shapes)
            shapes.append(geom_shape(model, geom))
            bodies.append(int(model.geom_bodyid[geom]))
        return index[geom]

    for g1 in range(model.ngeom):
        if model.geom_bodyid[g1] not in detector.bodies:
            continue
        for g2 in range(model.ngeom):
            b2 = int(model.geom_bodyid[g2])
            if g2 == g1 or (b2 in detector.bodies and g2 < g1) or not collides(model, g1, g2):
                continue
            if frozenset((int(model.geom_bodyid[g1]), b2)) in detector.exclude:
                continue
            if model.geom_type[g1] == mujoco.mjtGeom.mjGEOM_PLANE:
                g1, g2 = g2, g1  # a plane is always shape b
            mu = detector.mu
            if mu is None:
                mu = float(max(model.geom_friction[g1, 0], model.geom_friction[g2, 0]))
            label = f"{_geom_name(model, g1)}|{_geom_name(model, g2)}"
            pairs.append(Pair(shape_of(g1), shape_of(g2), float(mu), label))
            margins.add(float(max(model.geom_margin[g1], model.geom_margin[g2])))
    if len(margins) > 1:
        raise ValueError(f"detector: the modelled pairs' margins must agree, got {sorted(margins)}")
    return SceneGeometry(
        body_tree(model, dtype),
        shapes,
        bodies,
        pairs,
        slots=detector.slots,
        margin=margins.pop() if margins else 0.0,
        per_pair=detector.per_pair or DEFAULT_PER_PAIR,
        smoothing=smoothing,
    )
