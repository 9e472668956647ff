"""Bodies' world poses and point Jacobians from MuJoCo-style joints, in pure torch.

The same composition as MuJoCo's ``mj_kinematics``: a body sits at its offset from its parent,
then its joints move it in order (a slide along its axis, a hinge about its axis through its
anchor, both by ``q − qpos0``; a ball by its quaternion; a free joint sets the pose outright).
Point Jacobians follow MuJoCo's velocity convention, as ``mj_jac``: a free joint's v is the
origin's linear velocity in the world frame, then the angular velocity in the body frame; a
ball's is the angular velocity in the body frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from torchcontact.rotations import quaternion_to_matrix
from torchcontact.validation import check_shape


@dataclass(frozen=True)
class Joint:
    """One joint of a :class:`BodyTree`, as MuJoCo describes it.

    Attributes:
        body: index of the body it moves.
        kind: ``"free"``, ``"ball"``, ``"slide"`` or ``"hinge"``.
        axis: ``(3,)`` unit axis in the body frame (slide and hinge).
        anchor: ``(3,)`` [m] the joint's position in the body frame (hinge and ball).
        qpos: address of its first coordinate in q; dof: of its first velocity in v.
        reference: q at which a slide or hinge leaves the body at its offset (``qpos0``).
    """

    body: int
    kind: str
    axis: tuple[float, float, float]
    anchor: tuple[float, float, float]
    qpos: int
    dof: int
    reference: float = 0.0


_DOFS = {"free": 6, "ball": 3, "slide": 1, "hinge": 1}


class BodyTree(torch.nn.Module):
    """A tree of rigid bodies moved by joints: batched poses and point Jacobians of q.

    Body 0 is the world. Call with ``q (..., nq)``; returns ``position (..., nbody, 3)`` [m]
    and ``rotation (..., nbody, 3, 3)`` (body frame to world) of every body. Differentiable
    and free of Python branches on values, so it traces under ``torch.compile``;
    ``.to(dtype, device)`` moves its constants.

    Args:
        parent: ``(nbody,)`` each body's parent index (smaller than its own; the world's is 0).
        offset_position: ``(nbody, 3)`` [m] each body's position in its parent's frame.
        offset_quaternion: ``(nbody, 4)`` (w, x, y, z) its orientation in its parent's frame.
        joints: the joints, in q's order (a body's joints in the order MuJoCo applies them).
        nq, nv: sizes of q and v.
    """

    def __init__(
        self,
        parent: Sequence[int],
        offset_position: torch.Tensor,
        offset_quaternion: torch.Tensor,
        joints: Sequence[Joint],
        nq: int,
        nv: int,
    ):
        super().__init__()
        nbody = len(parent)
        if any(not 0 <= p < max(b, 1) for b, p in enumerate(parent)):
            raise ValueError(f"parent must list each body's parent, a smaller index, got {parent}")
        check_shape(
            "offset_position", offset_position, f"({nbody}, 3)", offset_position.shape == (nbody, 3)
        )
        check_shape(
            "offset_quaternion",
            offset_quaternion,
            f"({nbody}, 4)",
            offset_quaternion.shape == (nbody, 4),
        )
        unknown = [j.kind for j in joints if j.kind not in _DOFS]
        if unknown:
            raise ValueError(f"joints must be among {sorted(_DOFS)}, got {unknown}")
        self.parent = tuple(int(p) for p in parent)
        self.joints = tuple(joints)
        self.nq, self.nv = int(nq), int(nv)
        self.register_buffer("offset_position", offset_position.clone())
        axes = offset_position.new_tensor([j.axis for j in joints]).reshape(-1, 3)
        self.register_buffer("joint_axis", axes)
        anchors = offset_position.new_tensor([j.anchor for j in joints]).reshape(-1, 3)
        self.register_buffer("joint_anchor", anchors)
        # which dofs move each body: its own joints' and its ancestors'
        moves = torch.zeros(nbody, nv, dtype=torch.bool)
        for body in range(1, nbody):
            moves[body] = moves[self.parent[body]]
            for joint in joints:
                if joint.body == body:
                    moves[body, joint.dof : joint.dof + _DOFS[joint.kind]] = True
        self.register_buffer("moves", moves)
        rotational = torch.zeros(nv, dtype=torch.bool)
        for joint in joints:
            if joint.kind == "free":
                rotational[joint.dof + 3 : joint.dof + 6] = True
            elif joint.kind in ("ball", "hinge"):
                rotational[joint.dof : joint.dof + _DOFS[joint.kind]] = True
        self.register_buffer("rotational", rotational)
        self._by_body = [[i for i, j in enumerate(joints) if j.body == b] for b in range(nbody)]
        self._moving = [b for b in range(1, nbody) if moves[b].any()]
        self._stages = _stages(self.parent, self._moving, self._by_body, self.joints)
        self.register_buffer("offset_rotation", quaternion_to_matrix(offset_quaternion))
        cross = torch.zeros(len(joints), 3, 3, dtype=offset_position.dtype)
        for i, (x, y, z) in enumerate(j.axis for j in joints):
            cross[i] = offset_position.new_tensor([[0, -z, y], [z, 0, -x], [-y, x, 0]])
        self.register_buffer("joint_cross", cross)
        self.register_buffer("joint_cross_square", cross @ cross)
        self.register_buffer("world_axes", torch.eye(3, dtype=offset_position.dtype))
        for i, (bodies, index) in enumerate(self._stages):
            if len(bodies) > 1:  # a level of hinges: its constants gathered once
                rows, at = torch.tensor(index), list(bodies)
                constants = {
                    "qpos": torch.tensor([joints[j].qpos for j in index]),
                    "reference": offset_position.new_tensor([joints[j].reference for j in index]),
                    "offset": offset_position[at], "turn": self.offset_rotation[at],
                    "axis": self.joint_axis[rows], "anchor": self.joint_anchor[rows],
                    "cross": cross[rows], "square": self.joint_cross_square[rows],
                }  # fmt: skip
                for name in _STAGE_CONSTANTS:  # derived from the above: not saved
                    buffer = constants[name].clone()
                    self.register_buffer(f"_stage{i}_{name}", buffer, persistent=False)
        # the poses of the bodies no joint moves, composed once
        position = torch.zeros(nbody, 3, dtype=offset_position.dtype)
        rotation = torch.eye(3, dtype=offset_position.dtype).repeat(nbody, 1, 1)
        for body in range(1, nbody):
            up = self.parent[body]
            position[body] = position[up] + rotation[up] @ offset_position[body]
            rotation[body] = rotation[up] @ self.offset_rotation[body]
        self.register_buffer("fixed_position", position)
        self.register_buffer("fixed_rotation", rotation)

    @property
    def nbody(self) -> int:
        return len(self.parent)

    def forward(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World ``position (..., nbody, 3)`` [m] and ``rotation (..., nbody, 3, 3)``."""
        poses, _ = self._poses(q)
        return poses

    def _poses(self, q: torch.Tensor):
        """The bodies' poses and, per dof, its world axis ``(..., nv, 3)`` and anchor."""
        check_shape("q", q, f"(..., {self.nq})", q.dim() >= 1 and q.shape[-1] == self.nq)
        batch = q.shape[:-1]
        # bodies no joint moves keep the pose composed once at construction
        positions = list(self.fixed_position.expand(*batch, -1, -1).unbind(-2))
        rotations = list(self.fixed_rotation.expand(*batch, -1, -1, -1).unbind(-3))
        axes: list[torch.Tensor | None] = [None] * self.nv
        anchors: list[torch.Tensor | None] = [None] * self.nv
        for stage, (bodies, _) in enumerate(self._stages):
            if len(bodies) > 1:  # bodies of one tree level, each turned by one hinge
                self._hinges(stage, q, positions, rotations, axes, anchors)
            else:
                self._body(bodies[0], q, positions, rotations, axes, anchors)
        poses = (torch.stack(positions, -2), torch.stack(rotations, -3))
        if self.nv == 0:
            empty = q.new_zeros(*batch, 0, 3)
            return poses, (empty, empty)
        return poses, (torch.stack(axes, -2), torch.stack(anchors, -2))

    def _body(self, body: int, q, positions, rotations, axes, anchors) -> None:
        """Body ``body``'s pose from its parent's and its joints, into the lists (and its dofs'
        world axes and anchors)."""
        batch = q.shape[:-1]
        up = self.parent[body]
        position = positions[up] + _apply(rotations[up], self.offset_position[body])
        rotation = rotations[up] @ self.offset_rotation[body]
        for index in self._by_body[body]:
            joint = self.joints[index]
            anchor_local = self.joint_anchor[index]
            if joint.kind == "free":
                position = q[..., joint.qpos : joint.qpos + 3]
                rotation = quaternion_to_matrix(
                    _normalized(q[..., joint.qpos + 3 : joint.qpos + 7])
                )
                for k in range(3):
                    axes[joint.dof + k] = self.world_axes[k].expand(*batch, 3)
                    axes[joint.dof + 3 + k] = rotation[..., :, k]
                    anchors[joint.dof + k] = anchors[joint.dof + 3 + k] = position
                continue
            anchor = position + _apply(rotation, anchor_local)
            if joint.kind == "slide":
                world_axis = _apply(rotation, self.joint_axis[index])
                position = position + world_axis * (q[..., joint.qpos, None] - joint.reference)
                axes[joint.dof], anchors[joint.dof] = world_axis, anchor
                continue
            if joint.kind == "hinge":
                axes[joint.dof] = _apply(rotation, self.joint_axis[index])
                anchors[joint.dof] = anchor
                angle = (q[..., joint.qpos] - joint.reference)[..., None, None]
                rotation = _turned(
                    rotation, angle, self.joint_cross[index], self.joint_cross_square[index]
                )
            else:  # ball
                turn = quaternion_to_matrix(_normalized(q[..., joint.qpos : joint.qpos + 4]))
                rotation = rotation @ turn
                for k in range(3):
                    axes[joint.dof + k], anchors[joint.dof + k] = rotation[..., :, k], anchor
            # the anchor stays where it is while the body turns about it
            position = anchor - _apply(rotation, anchor_local)
        positions[body] = position
        rotations[body] = rotation

    def _hinges(self, stage: int, q, positions, rotations, axes, anchors) -> None:
        """:meth:`_body` for the bodies of stage ``stage`` at once (one tree level, each moved
        by one hinge): one set of batched ops for a level of every finger, not one a joint."""
        bodies, index = self._stages[stage]
        constant = {name: getattr(self, f"_stage{stage}_{name}") for name in _STAGE_CONSTANTS}
        rotation_up = torch.stack([rotations[self.parent[b]] for b in bodies], -3)
        position_up = torch.stack([positions[self.parent[b]] for b in bodies], -2)
        position = position_up + _apply(rotation_up, constant["offset"])
        rotation = rotation_up @ constant["turn"]
        anchor = position + _apply(rotation, constant["anchor"])
        axis = _apply(rotation, constant["axis"])
        angle = (q[..., constant["qpos"]] - constant["reference"])[..., None, None]
        rotation = _turned(rotation, angle, constant["cross"], constant["square"])
        position = anchor - _apply(rotation, constant["anchor"])
        for k, (body, joint) in enumerate(zip(bodies, index, strict=True)):
            dof = self.joints[joint].dof
            axes[dof], anchors[dof] = axis[..., k, :], anchor[..., k, :]
            positions[body], rotations[body] = position[..., k, :], rotation[..., k, :, :]

    def point_jacobian(self, dofs, bodies: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        """``(..., n, 3, nv)`` Jacobians of world ``points (..., n, 3)`` fixed to ``bodies (n,)``.

        ``dofs`` is the second value of :meth:`_poses` (the dofs' world axes and anchors):
        ``J v`` is the points' velocity [m/s] under the generalized velocity ``v``.
        """
        axes, anchors = dofs  # (..., nv, 3)
        lever = points.unsqueeze(-2) - anchors.unsqueeze(-3)  # (..., n, nv, 3)
        axes = axes.unsqueeze(-3).expand_as(lever)
        columns = torch.where(self.rotational[:, None], torch.linalg.cross(axes, lever), axes)
        columns = columns * self.moves[bodies].unsqueeze(-1).to(columns.dtype)
        return columns.transpose(-1, -2)


_STAGE_CONSTANTS = ("qpos", "reference", "offset", "turn", "axis", "anchor", "cross", "square")
"""The per-stage constants of a level of hinges, each a buffer ``_stage{i}_{name}``."""


def _stages(parent, moving, by_body, joints) -> list[tuple[tuple[int, ...], tuple[int, ...]]]:
    """The moving bodies in an order that composes each after its parent: ``(bodies, joints)``
    per stage, where a stage of several bodies holds those of one tree level that are each
    moved by exactly one hinge (composed together), and any other body is a stage alone."""
    level: dict[int, int] = {}
    for body in moving:
        level[body] = level.get(parent[body], -1) + 1
    stages: list[tuple[tuple[int, ...], tuple[int, ...]]] = []
    for depth in range(max(level.values(), default=-1) + 1):
        at = [b for b in moving if level[b] == depth]
        hinged = [b for b in at if len(by_body[b]) == 1 and joints[by_body[b][0]].kind == "hinge"]
        stages += [((b,), tuple(by_body[b])) for b in at if b not in hinged]
        if len(hinged) > 1:
            stages.append((tuple(hinged), tuple(by_body[b][0] for b in hinged)))
        else:
            stages += [((b,), tuple(by_body[b])) for b in hinged]
    return stages


def _turned(rotation, angle, cross, square) -> torch.Tensor:
    """``rotation (..., 3, 3)`` turned by ``angle (..., 1, 1)`` [rad] about a body-frame axis
    whose cross matrix K is ``cross`` and K² ``square``: Rodrigues, I + sin θ K + (1 − cos θ) K²."""
    return rotation + rotation @ (torch.sin(angle) * cross + (1 - torch.cos(angle)) * square)


def _apply(rotation: torch.Tensor, vector: torch.Tensor) -> torch.Tensor:
    """``rotation @ vector`` for ``rotation (..., 3, 3)`` and ``vector (..., 3)``."""
    return (rotation @ vector.unsqueeze(-1)).squeeze(-1)


def _normalized(quaternion: torch.Tensor) -> torch.Tensor:
    return quaternion / torch.linalg.vector_norm(quaternion, dim=-1, keepdim=True)
