"""Manipulated objects as MuJoCo bodies: an :class:`~torchcontact.shapes.ObjectMesh` (a union
of convex parts, from :mod:`torchcontact.shapes`) added to an ``MjSpec``.

MuJoCo collides every mesh geom through its convex hull, so each convex part is one mesh geom;
a hull-colliding object (``ObjectMesh.collide_hull``) collides as one hidden geom, the hull of
all its parts, and shows its parts as visual-only geoms. The body carries the union's mass,
inertia and centre of mass.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import trimesh

from torchcontact.shapes import ObjectMesh

COLLISION_GROUP = 3
"""Geom group of a hull-colliding object's hull: MuJoCo draws groups 0–2 by default."""


def add_object(
    spec: mujoco.MjSpec,
    obj: ObjectMesh,
    body_name: str = "object",
    friction: float = 0.9,
    condim: int = 6,
    rgba: Sequence[float] = (0.85, 0.55, 0.25, 1.0),
) -> mujoco.MjsBody:
    """Add ``obj`` to ``spec`` as a free body with one collision mesh geom per convex part
    of ``obj.collision_parts``.

    The body carries the union's mass and inertia explicitly (so overlapping parts are not
    counted twice); ``friction`` is the sliding coefficient, torsional and rolling keep
    MuJoCo's defaults. A hull-colliding object gets its hull in geom group
    :data:`COLLISION_GROUP` (hidden in renderings) and its parts as visual-only geoms.
    Returns the new body; its free joint is named ``{body_name}_free``.
    """
    if not (math.isfinite(friction) and friction >= 0):
        raise ValueError(f"friction must be a non-negative finite number, got {friction!r}")
    if condim not in (1, 3, 4, 6):
        raise ValueError(f"condim must be 1, 3, 4 or 6, got {condim!r}")
    body = spec.worldbody.add_body(name=body_name)
    body.add_freejoint(name=f"{body_name}_free")
    body.explicitinertial = True
    body.mass = obj.mass
    body.ipos = obj.centre_of_mass.tolist()
    i = obj.inertia
    body.fullinertia = [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]
    # parts colliding as they are share their mesh assets with the goal marker's
    prefix = f"{obj.name}_hull" if obj.collide_hull else obj.name
    for mesh_name in _add_meshes(spec, prefix, obj.collision_parts):
        body.add_geom(
            type=mujoco.mjtGeom.mjGEOM_MESH,
            meshname=mesh_name,
            friction=[friction, 0.005, 0.0001],
            condim=condim,
            rgba=list(rgba),
            group=COLLISION_GROUP if obj.collide_hull else 0,
        )
    if obj.collide_hull:
        _add_visual_geoms(body, _add_meshes(spec, obj.name, obj.parts), rgba)
    return body


def add_goal_marker(
    spec: mujoco.MjSpec,
    obj: ObjectMesh,
    body_name: str = "goal",
    rgba: Sequence[float] = (0.2, 0.9, 0.2, 0.3),
) -> mujoco.MjsBody:
    """Add a see-through copy of ``obj`` that never collides, as a mocap body.

    Move it with ``data.mocap_pos`` / ``data.mocap_quat``. Returns the new body.
    """
    body = spec.worldbody.add_body(name=body_name, mocap=True)
    _add_visual_geoms(body, _add_meshes(spec, obj.name, obj.parts), rgba)
    return body


def _add_visual_geoms(body: mujoco.MjsBody, mesh_names: list[str], rgba: Sequence[float]):
    """One mesh geom per name on ``body`` that is drawn but never collides nor weighs."""
    for mesh_name in mesh_names:
        body.add_geom(
            type=mujoco.mjtGeom.mjGEOM_MESH,
            meshname=mesh_name,
            contype=0,
            conaffinity=0,
            density=0.0,
            rgba=list(rgba),
        )


def _add_meshes(spec: mujoco.MjSpec, prefix: str, parts: Sequence[trimesh.Trimesh]) -> list[str]:
    """Register ``parts`` as mesh assets ``{prefix}_part{i}`` (once per spec); their names."""
    names = [f"{prefix}_part{i}" for i in range(len(parts))]
    for mesh_name, part in zip(names, parts, strict=True):
        if spec.mesh(mesh_name) is None:
            spec.add_mesh(
                name=mesh_name,
                uservert=part.vertices.flatten().tolist(),
                userface=part.faces.flatten().tolist(),
            )
    return names
