"""Fingertip forward kinematics through pytorch-kinematics, built from the project's MJCF files.

The chain is parsed by ``pytorch_kinematics.build_chain_from_mjcf`` from the same model file
the MuJoCo scene attaches, so the MPC's fingertips and the plant's sites share one source.
Joint values are taken in MuJoCo's order (the order of the robot's joints in the file), and
the evaluation uses pytorch-kinematics' tensor FK with plain autograd, so it composes with
``torch.func.grad`` and ``torch.compile`` in the MPC objective.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import pytorch_kinematics as pk
import torch

from torchcontact.validation import check_shape

# pytorch-kinematics 0.10 keys its joint-type map by MuJoCo's enum members; MuJoCo 4 reports
# joint types as NumPy integers that do not compare equal to them, so key the map by integers.
pk.mjcf.JOINT_TYPE_MAP = {int(k): v for k, v in pk.mjcf.JOINT_TYPE_MAP.items()}


def load_robot(mjcf: str | Path, tips: Sequence[str]) -> tuple[Path, mujoco.MjModel, list[int]]:
    """The robot file's path, its MuJoCo model and the ids of the sites ``tips``; raises
    ``ValueError`` naming ``mjcf`` or ``tips`` when the file or a site is missing."""
    path = Path(mjcf)
    if not path.is_file():
        raise ValueError(f"mjcf must be an existing MJCF file, got {str(mjcf)!r}")
    model = mujoco.MjModel.from_xml_path(str(path))
    if not tips:
        raise ValueError("tips must name at least one site")
    site_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name) for name in tips]
    unknown = [name for name, i in zip(tips, site_ids, strict=True) if i < 0]
    if unknown:
        raise ValueError(f"tips must name sites of {path.name}, got {unknown}")
    return path, model, site_ids


class FingertipKinematics(torch.nn.Module):
    """World positions of named sites as a batched, differentiable function of the joints.

    Args:
        mjcf: path of a robot MJCF file whose world frame is the scene's world frame.
        tips: names of the sites to evaluate (one per fingertip).
        dtype, device: of the chain's constants; ``.to(dtype, device)`` moves them later.

    Call with ``joints (..., n_joints)`` [rad or m] in the file's joint order; returns
    ``(..., n_tips, 3)`` [m].
    """

    def __init__(
        self,
        mjcf: str | Path,
        tips: Sequence[str],
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ):
        super().__init__()
        path, model, _ = load_robot(mjcf, tips)
        # pytorch-kinematics parses offsets in float32: positions agree with MuJoCo to ~1e-8 m.
        chain = pk.build_chain_from_mjcf(path.read_text(), assets=_mesh_assets(path))
        self.chain = chain.to(dtype=dtype, device=device)
        self.mjcf = path
        self.tips = tuple(tips)
        self.joint_names = tuple(model.joint(j).name for j in range(model.njnt))
        offset = [model.joint(j).name for j in range(model.njnt) if model.jnt_pos[j].any()]
        if offset:
            # pytorch-kinematics would move the child frame by the joint's offset instead of
            # rotating about a shifted axis: such models give wrong fingertips, so refuse them.
            raise ValueError(f"{path.name}: joints must sit at their body's origin: {offset}")
        chain_order = self.chain.get_joint_parameter_names()
        if sorted(chain_order) != sorted(self.joint_names):
            raise ValueError(f"{path.name}: every joint must be a hinge or slide in a tree")
        # chain joint k reads MuJoCo joint permutation[k]
        permutation = [self.joint_names.index(name) for name in chain_order]
        self.register_buffer("permutation", torch.tensor(permutation, device=device))
        self.register_buffer("tip_frames", self.chain.get_frame_indices(*self.tips).to(device))

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def forward(self, joints: torch.Tensor) -> torch.Tensor:
        check_shape(
            "joints", joints, f"(..., {self.n_joints})", joints.shape[-1:] == (self.n_joints,)
        )
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


def _mesh_assets(path: Path) -> dict[str, bytes] | None:
    """Mesh files next to the MJCF, for models that reference them (ours use primitives)."""
    meshes = {p.name: p.read_bytes() for p in path.parent.glob("*.stl")}
    return meshes or None
