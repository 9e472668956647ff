"""A robot as a description read from its MJCF: joints, actuation, fingertip sites, batched FK.

As pytorch-kinematics turns a file into a chain, :meth:`Robot.from_mjcf` turns a MuJoCo model
file into a :class:`Robot`: the joints in MuJoCo's order (a free-jointed object in the same
file is left out), their ranges, the actuators that drive them, and a batched, differentiable
map from joint values to fingertip sites. The built-in hands and a user's robot are built the
same way; a robot of point fingertips (each on three slide joints along the world axes) is
recognised and evaluated as the identity on its joints.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import torch

from torchcontact.sim.kinematics import (
    JOINT_TYPES,
    SLIDE,
    FingertipKinematics,
    load_model,
    object_bodies,
    robot_joints,
    site_ids,
)
from torchcontact.validation import check_shape, check_tensor

ACTUATOR_KINDS = ("position", "velocity", "motor", "other")
"""How an :class:`Actuator` turns its control into force (see :attr:`Actuator.kind`)."""

TIP_SUFFIX = "tip"
"""Sites whose names end in this are a file's fingertips when none are named."""


@dataclass(frozen=True)
class Actuator:
    """One actuator of a robot file.

    Attributes:
        name: its MuJoCo name ("" when unnamed).
        joint: name of the joint it drives; None for other transmissions (tendons, sites).
        kind: ``"position"`` (force ``kp(ctrl − gear·q)``, a servo to ``q = ctrl/gear``),
            ``"velocity"`` (``kv(ctrl − gear·q̇)``), ``"motor"`` (force ``ctrl``) or
            ``"other"`` (any other gain, bias or activation dynamics).
        kp: position gain [N/m or N·m/rad] of a ``"position"`` actuator, else None.
        gear: the transmission's gear (MuJoCo's ``gear[0]``).
    """

    name: str
    joint: str | None
    kind: str
    kp: float | None
    gear: float


class Robot(torch.nn.Module):
    """A robot read from its MJCF, with batched forward kinematics of its fingertip sites.

    Build with :meth:`from_mjcf` (any file) or :meth:`point_tips` (free point fingertips).
    Call with ``joints (..., n_joints)`` [rad or m], the robot's joints in the file's order;
    returns the fingertips ``(..., n_tips, 3)`` [m] in the file's world frame. The map is
    differentiable and composes with ``torch.func.grad`` and ``torch.compile``;
    ``.to(dtype, device)`` moves it.

    Attributes:
        kinematics: the :class:`~torchcontact.sim.kinematics.FingertipKinematics` evaluating
            the fingertips, or None where they are the joints themselves (point fingertips).
    """

    joint_ranges: torch.Tensor | None
    """``(n_joints, 2)`` lower and upper limit per joint [rad or m], ``(−inf, inf)`` for an
    unlimited joint; None when no joint is limited (a buffer: it moves with ``.to``)."""

    def __init__(
        self,
        *,
        joint_names: Sequence[str],
        joint_types: Sequence[str],
        joint_ranges: torch.Tensor | None,
        actuators: Sequence[Actuator],
        tips: Sequence[str],
        mjcf: Path | None,
        kinematics: FingertipKinematics | None,
    ):
        super().__init__()
        self._joint_names = tuple(joint_names)
        self._joint_types = tuple(joint_types)
        self._actuators = tuple(actuators)
        self._tips = tuple(tips)
        self._mjcf = mjcf
        self.kinematics = kinematics
        self.register_buffer("joint_ranges", joint_ranges)

    @classmethod
    def from_mjcf(
        cls,
        mjcf: str | Path,
        tips: Sequence[str] | None = None,
        *,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> Robot:
        """The robot of the MJCF file ``mjcf``.

        Args:
            mjcf: path of the file; its world frame is the one the fingertips are given in.
                Free-jointed bodies (an object in the same file) are not the robot's.
            tips: names of the fingertip sites; None takes every site of the robot whose name
                ends in :data:`TIP_SUFFIX`, in MuJoCo's order.
            dtype, device: of the kinematic constants and :attr:`joint_ranges`.

        Raises ``ValueError`` naming ``mjcf`` or ``tips`` for a missing file, unknown sites or
        no fingertip site, and for joints pytorch-kinematics cannot represent (ball joints).
        """
        path, model = load_model(mjcf)
        if tips is None:
            tips = default_tips(model)
            if not tips:
                raise ValueError(
                    f"tips must name the fingertip sites: {path.name} has no site whose name "
                    f"ends in {TIP_SUFFIX!r}"
                )
        sites = site_ids(model, tips, path.name)
        joints = robot_joints(model, path.name)
        point = _are_point_tips(model, joints, sites)
        return cls(
            joint_names=[model.joint(j).name for j in joints],
            joint_types=[JOINT_TYPES[int(model.jnt_type[j])] for j in joints],
            joint_ranges=_joint_ranges(model, joints, dtype, device),
            actuators=[_actuator(model, a) for a in range(model.nu)],
            tips=tips,
            mjcf=path,
            kinematics=None if point else FingertipKinematics(path, tips, dtype, device),
        )

    @classmethod
    def point_tips(cls, n_tips: int) -> Robot:
        """``n_tips`` point fingertips ``tip<i>``, each on slide joints ``tip<i>_x``,
        ``tip<i>_y``, ``tip<i>_z`` along the world axes and driven by one motor per joint
        (the three-fingertip plant's robot): the fingertips are the joints,
        ``joints.unflatten(-1, (n_tips, 3))``. It has no file (:attr:`mjcf` is None)."""
        if not isinstance(n_tips, int) or n_tips < 1:
            raise ValueError(f"n_tips must be a positive integer, got {n_tips!r}")
        tips = [f"tip{i}" for i in range(n_tips)]
        names = [f"{tip}_{axis}" for tip in tips for axis in "xyz"]
        return cls(
            joint_names=names,
            joint_types=["slide"] * len(names),
            joint_ranges=None,
            actuators=[Actuator(name, name, "motor", None, 1.0) for name in names],
            tips=tips,
            mjcf=None,
            kinematics=None,
        )

    @property
    def n_joints(self) -> int:
        return len(self._joint_names)

    @property
    def n_tips(self) -> int:
        return len(self._tips)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The robot's joints in the file's (MuJoCo's) order."""
        return self._joint_names

    @property
    def joint_types(self) -> tuple[str, ...]:
        """``"hinge"`` [rad] or ``"slide"`` [m] per joint."""
        return self._joint_types

    @property
    def actuators(self) -> tuple[Actuator, ...]:
        """Every actuator of the file, in MuJoCo's (``ctrl``) order."""
        return self._actuators

    @property
    def tips(self) -> tuple[str, ...]:
        """Names of the fingertip sites, in the output's order."""
        return self._tips

    @property
    def mjcf(self) -> Path | None:
        """Path of the robot's file (None for :meth:`point_tips`)."""
        return self._mjcf

    def forward(self, joints: torch.Tensor) -> torch.Tensor:
        """Fingertips ``(..., n_tips, 3)`` [m] of ``joints (..., n_joints)`` [rad or m]."""
        check_tensor("joints", joints)
        if self.kinematics is not None:
            dtype = self.kinematics.chain.dtype
            if joints.dtype != dtype:
                raise TypeError(
                    f"joints must be {dtype} like the robot (move it with robot.to({joints.dtype})"
                    f"), got {joints.dtype}"
                )
            return self.kinematics(joints)
        check_shape(
            "joints", joints, f"(..., {self.n_joints})", joints.shape[-1:] == (self.n_joints,)
        )
        return joints.unflatten(-1, (self.n_tips, 3))

    def extra_repr(self) -> str:
        source = self._mjcf.name if self._mjcf is not None else "point fingertips"
        return f"{source}, n_joints={self.n_joints}, tips={list(self._tips)}"


def default_tips(model: mujoco.MjModel) -> tuple[str, ...]:
    """Names of the robot's sites (not on a free-jointed object) ending in :data:`TIP_SUFFIX`,
    in MuJoCo's order."""
    objects = object_bodies(model)
    sites = (i for i in range(model.nsite) if model.site_bodyid[i] not in objects)
    return tuple(name for name in (model.site(i).name for i in sites) if name.endswith(TIP_SUFFIX))


def _joint_ranges(model, joints, dtype, device) -> torch.Tensor | None:
    limited = model.jnt_limited[joints].astype(bool)
    if not limited.any():
        return None
    ranges = np.where(limited[:, None], model.jnt_range[joints], [-np.inf, np.inf])
    return torch.tensor(ranges, dtype=dtype, device=device)


def _actuator(model: mujoco.MjModel, index: int) -> Actuator:
    """The :class:`Actuator` ``index`` of ``model``, its kind read from gain and bias."""
    joint = None
    if model.actuator_trntype[index] == mujoco.mjtTrn.mjTRN_JOINT:
        joint = model.joint(model.actuator_trnid[index, 0]).name
    gain, bias = model.actuator_gainprm[index], model.actuator_biasprm[index]
    fixed = model.actuator_gaintype[index] == mujoco.mjtGain.mjGAIN_FIXED
    plain = model.actuator_dyntype[index] == mujoco.mjtDyn.mjDYN_NONE and fixed
    biastype = model.actuator_biastype[index]
    kind = "other"
    if plain and biastype == mujoco.mjtBias.mjBIAS_NONE:
        kind = "motor"
    elif plain and biastype == mujoco.mjtBias.mjBIAS_AFFINE and bias[0] == 0 and gain[0] > 0:
        if bias[1] == -gain[0]:
            kind = "position"
        elif bias[1] == 0 and bias[2] == -gain[0]:
            kind = "velocity"
    return Actuator(
        name=model.actuator(index).name,
        joint=joint,
        kind=kind,
        kp=float(gain[0]) if kind == "position" else None,
        gear=float(model.actuator_gear[index, 0]),
    )


def _are_point_tips(model: mujoco.MjModel, joints: list[int], sites: list[int]) -> bool:
    """Whether every fingertip site sits at the origin of a body placed at the world origin,
    unrotated, whose only joints are slides along world x, y, z (from a zero reference), and
    these joints, tip by tip, are all of the robot's: then the fingertips are the joints."""
    expected = iter(joints)
    for site in sites:
        body = model.site_bodyid[site]
        start, count = model.body_jntadr[body], model.body_jntnum[body]
        placed = (
            model.body_parentid[body] == 0
            and not model.body_pos[body].any()
            and np.array_equal(model.body_quat[body], [1.0, 0.0, 0.0, 0.0])
            and not model.site_pos[site].any()
        )
        if not placed or count != 3 or len(joints) != 3 * len(sites):
            return False
        for axis, joint in zip(np.eye(3), range(start, start + 3), strict=True):
            if (
                joint != next(expected)
                or model.jnt_type[joint] != SLIDE
                or not np.array_equal(model.jnt_axis[joint], axis)
                or model.qpos0[model.jnt_qposadr[joint]] != 0
            ):
                return False
    return True
