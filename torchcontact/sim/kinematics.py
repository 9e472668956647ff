"""Fingertip forward kinematics through pytorch-kinematics, built from MJCF files.

The chain is built from the same model file the MuJoCo scene attaches, so the MPC's fingertips
and the plant's sites share one source. The robot's joints are the file's hinge and slide
joints in MuJoCo's order, outside the subtrees of free-jointed bodies (an object in the same
file is not part of the robot). A file whose bodies carry at most one such joint each, at the
body's origin, is parsed by ``pytorch_kinematics.build_chain_from_mjcf`` itself (our TriFinger
and Allegro); any other tree (several joints in one body, joints off their body's origin, a
free-jointed object) is assembled from the compiled ``MjModel`` into the same ``Chain`` type,
one frame per joint, as MuJoCo composes them. Either way the evaluation uses
pytorch-kinematics' tensor FK with plain autograd, so it composes with ``torch.func.grad`` and
``torch.compile`` in the MPC objective.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np
import pytorch_kinematics as pk
import pytorch_kinematics.transforms as tf
import torch
from pytorch_kinematics.frame import Frame, Joint, Link

from torchcontact.validation import check_shape

# pytorch-kinematics 0.10 keys its joint-type map by MuJoCo's enum members; MuJoCo 4 reports
# joint types as NumPy integers that do not compare equal to them, so key the map by integers.
pk.mjcf.JOINT_TYPE_MAP = {int(k): v for k, v in pk.mjcf.JOINT_TYPE_MAP.items()}

FREE, BALL = int(mujoco.mjtJoint.mjJNT_FREE), int(mujoco.mjtJoint.mjJNT_BALL)
HINGE, SLIDE = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
JOINT_TYPES = {HINGE: "hinge", SLIDE: "slide"}
"""MuJoCo joint type ↦ name, for the joint types a robot may have."""


def load_model(mjcf: str | Path) -> tuple[Path, mujoco.MjModel]:
    """The MJCF file's path and its compiled MuJoCo model; ``ValueError`` naming ``mjcf``
    when the file is missing."""
    if not isinstance(mjcf, (str, Path)):
        raise ValueError(f"mjcf must be the path of an MJCF file, got {type(mjcf).__name__}")
    path = Path(mjcf)
    if not path.is_file():
        raise ValueError(f"mjcf must be an existing MJCF file, got {str(mjcf)!r}")
    try:
        return path, mujoco.MjModel.from_xml_path(str(path))
    except ValueError as error:  # MuJoCo's parser message spans lines: its first says why
        first = str(error).strip().splitlines()[0] if str(error).strip() else "unreadable"
        raise ValueError(
            f"mjcf must be a readable MJCF file, {path.name} is not: {first}"
        ) from None


def site_ids(model: mujoco.MjModel, tips: Sequence[str], source: str = "the model") -> list[int]:
    """MuJoCo ids of the sites named ``tips``; ``ValueError`` naming ``tips`` when one is
    missing (``source``: how the message names the file)."""
    if isinstance(tips, str) or not tips or not all(isinstance(t, str) for t in tips):
        raise ValueError(f"tips must be a sequence of site names, got {tips!r}")
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name) for name in tips]
    unknown = [name for name, i in zip(tips, ids, strict=True) if i < 0]
    if unknown:
        raise ValueError(f"tips must name sites of {source}, got {unknown}")
    return ids


def load_robot(mjcf: str | Path, tips: Sequence[str]) -> tuple[Path, mujoco.MjModel, list[int]]:
    """The robot file's path, its MuJoCo model and the ids of the sites ``tips``; raises
    ``ValueError`` naming ``mjcf`` or ``tips`` when the file or a site is missing."""
    path, model = load_model(mjcf)
    return path, model, site_ids(model, tips, path.name)


def object_bodies(model: mujoco.MjModel) -> set[int]:
    """Ids of the bodies at or below a free-jointed body: objects, not the robot."""
    free = set()
    for body in range(1, model.nbody):  # a parent's id is smaller than its children's
        start, count = model.body_jntadr[body], model.body_jntnum[body]
        own = any(model.jnt_type[j] == FREE for j in range(start, start + count))
        if own or model.body_parentid[body] in free:
            free.add(body)
    return free


def robot_joints(model: mujoco.MjModel, source: str = "the model") -> list[int]:
    """Ids of the robot's joints in MuJoCo order: the hinge and slide joints outside
    :func:`object_bodies`; ``ValueError`` for a ball joint of the robot, which
    pytorch-kinematics cannot represent."""
    objects = object_bodies(model)
    joints = [j for j in range(model.njnt) if model.jnt_bodyid[j] not in objects]
    balls = [model.joint(j).name or f"#{j}" for j in joints if model.jnt_type[j] == BALL]
    if balls:
        raise ValueError(
            f"{source}: the robot's joints must be hinges or slides (pytorch-kinematics has no "
            f"ball joint), got ball joints {balls}"
        )
    return joints


class FingertipKinematics(torch.nn.Module):
    """World positions of named sites as a batched, differentiable function of the joints.

    Args:
        mjcf: path of an MJCF file whose world frame is the scene's world frame. It may also
            hold free-jointed objects: their joints are not the robot's.
        tips: names of the sites to evaluate (one per fingertip), on the robot.
        dtype, device: of the chain's constants; ``.to(dtype, device)`` moves them later.

    Call with ``joints (..., n_joints)`` [rad or m], the robot's joints in the file's order
    (:attr:`joint_names`); returns ``(..., n_tips, 3)`` [m].
    """

    def __init__(
        self,
        mjcf: str | Path,
        tips: Sequence[str],
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ):
        super().__init__()
        path, model, sites = load_robot(mjcf, tips)
        joints = robot_joints(model, path.name)
        objects = object_bodies(model)
        on_objects = [
            n for n, s in zip(tips, sites, strict=True) if model.site_bodyid[s] in objects
        ]
        if on_objects:
            raise ValueError(f"tips must be sites of the robot, not of a free body: {on_objects}")
        bodies = {model.body(b).name for b in range(model.nbody)}
        shared = [name for name in tips if name in bodies]
        if shared:
            raise ValueError(f"{path.name}: tips must not share their names with bodies: {shared}")
        chain, chain_joints = _chain(path, model)
        # pytorch-kinematics parses offsets in float32: positions agree with MuJoCo to ~1e-8 m.
        self.chain = chain.to(dtype=dtype, device=device)
        self.mjcf = path
        self.tips = tuple(tips)
        self.joint_names = tuple(model.joint(j).name for j in joints)
        # chain joint k reads robot joint permutation[k]
        permutation = [joints.index(j) for j in chain_joints]
        self.register_buffer("permutation", torch.tensor(permutation, device=device))
        self.register_buffer("tip_frames", self.chain.get_frame_indices(*self.tips).to(device))
        # MuJoCo measures a joint from its reference (qpos0); pytorch-kinematics from zero
        reference = model.qpos0[model.jnt_qposadr[joints]] if joints else np.zeros(0)
        self.register_buffer(
            "reference",
            torch.tensor(reference, dtype=dtype, device=device) if reference.any() else None,
        )

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def forward(self, joints: torch.Tensor) -> torch.Tensor:
        check_shape(
            "joints", joints, f"(..., {self.n_joints})", joints.shape[-1:] == (self.n_joints,)
        )
        if self.reference is not None:
            joints = joints - self.reference
        batch = joints.shape[:-1]
        flat = joints.reshape(-1, self.n_joints)[:, self.permutation]
        transforms = self.chain.forward_kinematics_tensor(flat, analytical_grad=False)
        tips = transforms[self.tip_frames, :, :3, 3]  # (n_tips, B, 3)
        return tips.transpose(0, 1).reshape(*batch, len(self.tips), 3)

    def _apply(self, fn, recurse=True):
        # Move the chain's own tensors with the module (it is not an nn.Module).
        probe = fn(torch.zeros((), dtype=self.chain.dtype, device=self.chain.device))
        self.chain = self.chain.to(dtype=probe.dtype, device=probe.device)
        return super()._apply(fn, recurse)


def _chain(path: Path, model: mujoco.MjModel) -> tuple[pk.Chain, list[int]]:
    """The robot's chain and the MuJoCo ids of its joints in the chain's parameter order."""
    if _pk_parses(model):
        chain = pk.build_chain_from_mjcf(path.read_text(), assets=_mesh_assets(path))
        names = chain.get_joint_parameter_names()
        return chain, [model.joint(name).id for name in names]
    chain = _chain_from_model(model)
    return chain, [int(name) for name in chain.get_joint_parameter_names()]


def _pk_parses(model: mujoco.MjModel) -> bool:
    """Whether pytorch-kinematics' own MJCF parser builds this model right: named hinge and
    slide joints only, at most one per body, each at its body's origin."""
    return (
        all(model.jnt_type[j] in JOINT_TYPES for j in range(model.njnt))
        and all(model.joint(j).name for j in range(model.njnt))
        and int(np.max(model.body_jntnum, initial=0)) <= 1
        and not model.jnt_pos.any()
    )


def _offset(quat=None, pos=None) -> tf.Transform3d:
    """A fixed transform in float64 from a quaternion (w, x, y, z) and a position [m]."""
    as_tensor = lambda x: None if x is None else torch.tensor(x, dtype=torch.float64)  # noqa: E731
    return tf.Transform3d(rot=as_tensor(quat), pos=as_tensor(pos), dtype=torch.float64)


def _chain_from_model(model: mujoco.MjModel) -> pk.Chain:
    """A pytorch-kinematics chain of the robot's bodies, as MuJoCo's kinematics composes them.

    A body's joints act in order, each turning (or sliding) the body about its anchor
    ``jnt_pos`` in the body's frame: ``T = T_parent · T_body · Π_k A_k J_k(q_k) A_k⁻¹`` with
    ``A_k`` the translation to joint k's anchor. Each joint gets its own frame (named
    ``"<body>/joint<id>"``, the chain's parameter named by the joint's MuJoCo id); the frame
    named after the body holds its sites and child bodies. Free-jointed subtrees are left out.
    """
    objects = object_bodies(model)
    world = model.body(0)
    root = Frame(world.name, link=Link(world.name, offset=_offset(world.quat, world.pos)))

    def add_body(parent: Frame, body: int) -> Frame:
        name = model.body(body).name
        start = model.body_jntadr[body]
        own = list(range(start, start + model.body_jntnum[body]))
        offset = _offset(model.body_quat[body], model.body_pos[body])
        for j in own:
            anchor = model.jnt_pos[j]
            frame = Frame(
                f"{name}/joint{j}",
                link=Link(f"{name}/joint{j}", offset=offset),
                joint=Joint(
                    str(j),
                    offset=_offset(pos=anchor) if anchor.any() else None,
                    joint_type="revolute" if model.jnt_type[j] == HINGE else "prismatic",
                    axis=model.jnt_axis[j],
                    dtype=torch.float64,
                    limits=tuple(model.jnt_range[j]),
                ),
            )
            parent.add_child(frame)
            parent = frame
            offset = _offset(pos=-anchor) if anchor.any() else None
        if own and offset is None:  # the last joint's frame is the body's
            parent.name = parent.link.name = name
            return parent
        frame = Frame(name, link=Link(name, offset=offset), joint=Joint(name + "_fixed_joint"))
        parent.add_child(frame)
        return frame

    def add_subtree(frame: Frame, body: int) -> None:
        for child in range(body + 1, model.nbody):
            if model.body_parentid[child] == body and child not in objects:
                add_subtree(add_body(frame, child), child)
        for site in np.flatnonzero(model.site_bodyid == body):
            site_name = model.site(site).name
            link = Link(site_name, offset=_offset(model.site_quat[site], model.site_pos[site]))
            frame.add_child(Frame(site_name, link=link))

    add_subtree(root, 0)
    return pk.Chain(root, dtype=torch.float64)


def _mesh_assets(path: Path) -> dict[str, bytes] | None:
    """Mesh files next to the MJCF, for models that reference them (ours use primitives)."""
    meshes = {p.name: p.read_bytes() for p in path.parent.glob("*.stl")}
    return meshes or None
