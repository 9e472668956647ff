"""The parts every manipulation scene shares, composed with ``MjSpec``: light, camera, ground,
the object (first, so its free joint leads q) and its see-through goal marker."""

from __future__ import annotations

from collections.abc import Sequence

import mujoco

from torchcontact.shapes import ObjectMesh
from torchcontact.sim.objects import add_goal_marker, add_object

OBJECT_BODY = "object"
GOAL_BODY = "goal"


def scene_spec(
    name: str,
    obj: ObjectMesh,
    *,
    object_friction: float,
    ground_friction: float,
    condim: int,
    camera_position: Sequence[float],
    camera_target: Sequence[float] = (0.0, 0.0, 0.0),
    ground_height: float = 0.0,
) -> mujoco.MjSpec:
    """A new scene with a checkered ground plane at ``ground_height`` [m], ``obj`` as the free
    body :data:`OBJECT_BODY`, the goal marker :data:`GOAL_BODY` and a camera ``"overview"``
    at ``camera_position`` looking at ``camera_target`` [m]. The robot is added by the caller.
    """
    spec = mujoco.MjSpec()
    spec.modelname = name
    spec.visual.global_.offwidth = 1920
    spec.visual.global_.offheight = 1920
    world = spec.worldbody
    world.add_light(
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
        pos=[0.0, 0.3, 1.0],
        dir=[0.0, -0.3, -1.0],
        diffuse=[0.8, 0.8, 0.8],
        ambient=[0.3, 0.3, 0.3],
        castshadow=False,  # the translucent goal marker would cast an opaque shadow
    )
    target = world.add_body(name="camera_target", pos=list(camera_target))
    world.add_camera(
        name="overview",
        pos=list(camera_position),
        mode=mujoco.mjtCamLight.mjCAMLIGHT_TARGETBODY,
        targetbody=target.name,
    )
    spec.add_texture(
        name="checker",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.55, 0.6, 0.65],
        rgb2=[0.45, 0.5, 0.55],
        width=256,
        height=256,
    )
    floor = spec.add_material(name="floor", texrepeat=[20, 20], texuniform=True)
    floor.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "checker"
    world.add_geom(
        name="ground",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        pos=[0.0, 0.0, ground_height],
        size=[0.0, 0.0, 0.05],
        friction=[ground_friction, 0.005, 0.0001],
        condim=condim,
        material="floor",
    )
    add_object(spec, obj, OBJECT_BODY, friction=object_friction, condim=condim)
    add_goal_marker(spec, obj, GOAL_BODY)
    return spec
