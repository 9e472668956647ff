"""What every manipulation plant shares: state access, the goal marker, contacts, rendering.

A plant is a MuJoCo scene whose first joint is the object's free joint, so ``q`` starts with
the object's position [m] and quaternion (w, x, y, z), followed by the robot's joints.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from torchcontact.contacts import Contacts
from torchcontact.shapes import ObjectMesh
from torchcontact.sim.detect import ContactDetector


class Plant:
    """Base of the simulated plants; subclasses build ``model``, ``data`` and ``detector``.

    Attributes:
        model, data: the MuJoCo scene.
        detector: contacts of the object with everything else (see :meth:`contacts`).
        object: the manipulated :class:`ObjectMesh`.
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    detector: ContactDetector
    object: ObjectMesh
    support_height: float = 0.0
    """Height [m] of the plane the object rests on: the ground, or a hand's palm."""
    contact_capacity: int | None = None
    """Contact slots the MPC pads this plant's contacts to, the same for every object of the
    scene (:class:`~torchcontact.mpc.controller.ContactImplicitMPC`'s ``contact_slots``): a
    compiled plan is specialised to its number of rows, so one capacity that holds every
    object's :attr:`~torchcontact.sim.detect.ContactDetector.slots` lets one compiled graph
    serve them all. None: each plant's own slots, rounded up to the MPC's bucket."""

    def __init__(self):
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    @property
    def nu(self) -> int:
        return self.model.nu

    def set_target(self, target_pose) -> None:
        """Move the goal marker to ``target_pose (7,)`` (position [m], quaternion)."""
        pose = as_pose("target_pose", target_pose)
        self.data.mocap_pos[0] = pose[:3]
        self.data.mocap_quat[0] = pose[3:]

    @property
    def target(self) -> np.ndarray:
        """``(7,)`` pose of the goal marker."""
        return np.concatenate([self.data.mocap_pos[0], self.data.mocap_quat[0]])

    def resting_height(self, quat) -> float:
        """Height [m] of the object's origin when, turned by ``quat (4,)`` (w, x, y, z), it
        rests on the support: the lowest height at which it does not sink into it."""
        return self.support_height + self.object.resting_height(quat)

    def state(self) -> np.ndarray:
        """``(nq,)`` copy of q: object position, quaternion, then the robot's coordinates."""
        return self.data.qpos.copy()

    def velocity(self) -> np.ndarray:
        """``(nv,)`` copy of v: object linear (world) and angular (body) velocity, robot."""
        return self.data.qvel.copy()

    def contacts(self, dtype: torch.dtype | None = None) -> Contacts:
        """Contacts of the object with the robot and its support at the current state.

        MuJoCo's contacts at touch, or within the detector's margin (a hand's
        ``contact_margin``), in the detector's slots, with its μ; φ is MuJoCo's distance (≤ 0
        when touching, up to the margin when not). More contacts than slots follow the
        detector's ``overflow`` policy.
        """
        if dtype is not None and not (isinstance(dtype, torch.dtype) and dtype.is_floating_point):
            raise TypeError(f"dtype must be a floating torch.dtype or None, got {dtype!r}")
        contacts = self.detector(self.data.qpos)
        return contacts if dtype is None else contacts.to(dtype)

    def render(self, width: int = 480, height: int = 360, camera: str | int = "overview"):
        """``(height, width, 3)`` uint8 offscreen image from a named or numbered camera.

        Needs an OpenGL backend (``MUJOCO_GL=egl`` or ``osmesa`` on headless machines).
        """
        for name, value in (("width", width), ("height", height)):
            if not isinstance(value, int) or not 0 < value <= 1920:
                raise ValueError(f"{name} must be an integer in [1, 1920], got {value!r}")
        camera_id = camera
        if isinstance(camera, str):
            camera_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
            if camera_id < 0:
                raise ValueError(f"camera must name a camera of the scene, got {camera!r}")
        elif not (isinstance(camera, int) and -1 <= camera < self.model.ncam):
            raise ValueError(f"camera must be a name or an id in [-1, {self.model.ncam})")
        renderer = self._renderers.get((width, height))
        if renderer is None:
            renderer = mujoco.Renderer(self.model, height, width)
            self._renderers[(width, height)] = renderer
        renderer.update_scene(self.data, camera_id)
        return renderer.render()

    def close(self) -> None:
        """Free the renderers' OpenGL contexts."""
        for renderer in self._renderers.values():
            renderer.close()
        self._renderers.clear()


def as_vector(name: str, value, size: int) -> np.ndarray:
    """``value`` as a finite float64 ``(size,)`` array of its own (a copy: the caller's NumPy
    array or tensor is never changed through it)."""
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {size} numbers, got {value!r}") from None
    if array.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {array}")
    return array


def as_pose(name: str, value) -> np.ndarray:
    """A ``(7,)`` pose with its quaternion normalised."""
    pose = as_vector(name, value, 7)
    norm = np.linalg.norm(pose[3:])
    if norm < 1e-9:
        raise ValueError(f"{name} must have a non-zero quaternion in its last 4 entries")
    pose[3:] /= norm
    return pose
