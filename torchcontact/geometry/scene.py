"""A scene's contact geometry: shapes on bodies, the pairs it models, ``Contacts`` at any q.

The pipeline of :meth:`SceneGeometry.forward`, one stage a line: the bodies' poses from q
(:class:`~torchcontact.geometry.kinematics.BodyTree`); every pair's signed distance and its
patch points (:mod:`~torchcontact.geometry.distance`); per pair up to ``per_pair`` points that
span the patch; the ``slots`` deepest of them all; their rows from the bodies' point
Jacobians. Pure torch: batched over q's leading dimensions, on q's device and dtype.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from torchcontact.contacts import PAD_DISTANCE, Contacts
from torchcontact.geometry.distance import Core, core_separation, points_to_solid, safe_norm
from torchcontact.geometry.kinematics import BodyTree
from torchcontact.geometry.shapes import Shape, as_tensor

SPREAD = 1e-3
"""[m] A patch point this close to one already kept adds no support and is skipped."""


@dataclass(frozen=True)
class Pair:
    """A modelled pair: shape ``a`` (on a body whose contacts are modelled) and shape ``b``.

    Attributes:
        a, b: indices into the scene's shapes; ``b`` may be a plane, ``a`` may not.
        mu: the friction coefficient of its rows.
        label: what it is, for messages and reports (the reader gives MuJoCo's geom names,
            ``"geom_a|geom_b"``).
    """

    a: int
    b: int
    mu: float
    label: str = ""


class SceneGeometry(torch.nn.Module):
    """Contacts of a scene as a differentiable function of q.

    Call with ``q (..., nq)``; returns :class:`~torchcontact.contacts.Contacts` of batch shape
    ``...`` with ``slots`` slots: φ [m] (MuJoCo's ``dist``, negative in penetration), Jⁿ and
    Jᵗ over the tree's nv velocities (``Jⁿ v > 0`` opens the gap), μ, the frame (rows n, t₁,
    t₂; n from shape a towards b), the position (midway between the two surfaces) and
    ``static`` (the other body is welded to the world). A contact is active when φ < ``margin``.

    Where the answer switches (documented, as MuJoCo's detection switches too): the witness
    feature of a pair changes where two features are equally near (φ is continuous there, its
    gradient jumps; ``smoothing`` blends them); a patch point is kept or not as it crosses
    ``margin`` or :data:`SPREAD`; beyond ``slots`` active points, the deepest ``slots`` are kept
    (a point leaving the budget takes its force with it). The tangent directions t₁, t₂ are
    the normal's cross products with the world axis least aligned with it.

    Args:
        tree: the bodies' kinematics.
        shapes: every shape; ``bodies[i]`` the body shape ``i`` is fixed to.
        pairs: the modelled pairs.
        slots: contact slots nc of the output.
        margin: detection distance [m].
        per_pair: at most this many points per pair, spanning its patch.
        smoothing: None (hard feature choice) or a length [m] for softmin feature blending
            (see :mod:`~torchcontact.geometry.distance`).
    """

    def __init__(
        self,
        tree: BodyTree,
        shapes: Sequence[Shape],
        bodies: Sequence[int],
        pairs: Sequence[Pair],
        slots: int,
        margin: float = 0.0,
        per_pair: int = 4,
        smoothing: float | None = None,
    ):
        super().__init__()
        if len(bodies) != len(shapes):
            raise ValueError(
                f"bodies must name one body per shape ({len(shapes)}), got {len(bodies)}"
            )
        if isinstance(slots, bool) or not isinstance(slots, int) or slots < 1:
            raise ValueError(f"slots must be a positive integer, got {slots!r}")
        if isinstance(per_pair, bool) or not isinstance(per_pair, int) or per_pair < 1:
            raise ValueError(f"per_pair must be a positive integer, got {per_pair!r}")
        if not (np.isfinite(margin) and margin >= 0):
            raise ValueError(f"margin must be a non-negative finite number, got {margin!r}")
        if smoothing is not None and not (np.isfinite(smoothing) and smoothing > 0):
            raise ValueError(f"smoothing must be None or a positive length, got {smoothing!r}")
        if not pairs:
            raise ValueError("pairs must hold at least one pair of shapes")
        for pair in pairs:
            if shapes[pair.a].kind == "plane":
                raise ValueError(f"pairs: shape a of {pair} must not be a plane")
        self.tree = tree
        self.shapes, self.bodies, self.pairs = tuple(shapes), tuple(bodies), tuple(pairs)
        self.slots, self.margin, self.per_pair = slots, float(margin), per_pair
        self.smoothing = smoothing
        dtype = tree.offset_position.dtype
        welded = ~tree.moves.any(-1)
        groups: dict[tuple[str, str], list[Pair]] = {}
        for pair in pairs:
            groups.setdefault((shapes[pair.a].kind, shapes[pair.b].kind), []).append(pair)
        ordered = [pair for members in groups.values() for pair in members]
        self.order = [ordered.index(pair) for pair in pairs]
        self.groups = torch.nn.ModuleList(
            _Group(kinds, members, shapes, bodies, welded, dtype)
            for kinds, members in groups.items()
        )

    def distances(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Every pair's signed distance ``(..., n_pairs)`` [m] and unit normal from shape a
        towards b ``(..., n_pairs, 3)``, in :attr:`pairs`' order (no slot budget, no margin)."""
        (position, rotation), _ = self.tree._poses(q)
        found = [
            group.patch(position, rotation, self.margin, self.smoothing) for group in self.groups
        ]
        phi = torch.cat([f["phi"].amin(-1) for f in found], -1)
        first = torch.cat(
            [f["normal"].gather(-2, _deepest_index(f["phi"])).squeeze(-2) for f in found], -2
        )
        return phi[..., self.order], first[..., self.order, :]

    def within(self, q: torch.Tensor, distance: float) -> tuple[bool, ...]:
        """Per group of :attr:`groups`, whether any of its pairs' bounding spheres come within
        ``distance`` [m] of each other at any of ``q (..., nq)`` (a plane: the sphere's height
        above it): the broad phase for :meth:`forward`'s ``groups``. A cheap bound, never more
        than the pairs' true distances."""
        if isinstance(distance, bool) or not np.isfinite(distance):
            raise ValueError(f"distance must be a finite length [m], got {distance!r}")
        with torch.no_grad():
            (position, rotation), _ = self.tree._poses(q)
            return tuple(
                bool((group.bound(position, rotation) < distance).any()) for group in self.groups
            )

    def lever(self, q: torch.Tensor) -> float:
        """[m per rad or m] The most a shape's point moves at ``q (..., nq)`` when each joint
        other than a free one turns or slides by one unit at once (at most): over the joints
        moving its body, the sum of its bounding sphere's farthest distance from each hinge's
        anchor, and one per slide. Times a joint step, a bound on how far the robot's shapes
        move (free bodies, the objects, are moved by what touches them)."""
        with torch.no_grad():
            (position, rotation), (_, anchors) = self.tree._poses(q)
            driven = torch.ones(self.tree.nv, dtype=torch.bool, device=q.device)
            for joint in self.tree.joints:
                if joint.kind == "free":
                    driven[joint.dof : joint.dof + 6] = False
            most = 0.0
            for group in self.groups:
                centres, radii, bodies = group.spheres(position, rotation)
                arm = safe_norm(centres.unsqueeze(-2) - anchors.unsqueeze(-3)) + radii[:, None]
                arm = torch.where(self.tree.rotational, arm, 1.0)
                arm = arm * (self.tree.moves[bodies] & driven).to(arm.dtype)
                most = max(most, float(arm.sum(-1).max()))
            return most

    def forward(self, q: torch.Tensor, groups: tuple[bool, ...] | None = None) -> Contacts:
        """``groups``: per group of :attr:`groups`, whether its pairs are evaluated (None:
        all); a group left out adds no contacts (from :meth:`within`, for pairs out of reach)."""
        if groups is not None and len(groups) != len(self.groups):
            raise ValueError(
                f"groups must hold one flag per group ({len(self.groups)}), got {len(groups)}"
            )
        (position, rotation), dofs = self.tree._poses(q)
        evaluated = self.groups if groups is None else [
            group for group, kept in zip(self.groups, groups, strict=True) if kept
        ]  # fmt: skip
        if not evaluated:
            return Contacts.empty(self.slots, self.tree.nv, q.shape[:-1], q.dtype, q.device)
        found = [
            group.patch(position, rotation, self.margin, self.smoothing) for group in evaluated
        ]
        kept = [_spanning(points, self.per_pair) for points in found]
        points = {
            key: torch.cat([k[key] for k in kept], -1 if key in _SCALARS else -2) for key in kept[0]
        }
        chosen = _deepest(points, self.slots)
        return self._contacts(chosen, dofs)

    def _contacts(self, points: dict[str, torch.Tensor], dofs) -> Contacts:
        active = points["active"]
        normal = points["normal"]
        frame = _frame(normal)
        position = points["position"]
        jac_b = self.tree.point_jacobian(dofs, points["body_b"], position)
        jac_a = self.tree.point_jacobian(dofs, points["body_a"], position)
        rows = frame @ (jac_b - jac_a)  # (..., nc, 3, nv)
        mask = active.unsqueeze(-1).to(rows.dtype)
        rows = rows * mask.unsqueeze(-1)
        eye = torch.eye(3, dtype=frame.dtype, device=frame.device)
        return Contacts._unchecked(
            {
                "phi": torch.where(active, points["phi"], PAD_DISTANCE),
                "jac_normal": rows[..., 0, :],
                "jac_tangent": rows[..., 1:, :],
                "mu": torch.where(active, points["mu"], 0.0),
                "active": active,
                "frame": torch.where(active[..., None, None], frame, eye),
                "position": position * mask,
                "static": points["static"] & active,
            }
        )

    def extra_repr(self) -> str:
        return (
            f"shapes={len(self.shapes)}, pairs={len(self.pairs)}, slots={self.slots}, "
            f"margin={self.margin}, per_pair={self.per_pair}, smoothing={self.smoothing}"
        )


_SCALARS = ("phi", "mu", "active", "static", "body_a", "body_b")
"""The per-point fields without a trailing (3,) dimension."""


class _Group(torch.nn.Module):
    """The pairs of one kind of shape a against one kind of shape b, padded to one size."""

    def __init__(self, kinds, pairs, shapes, bodies, welded, dtype):
        super().__init__()
        self.kind_a, self.kind_b = kinds
        a = [shapes[p.a] for p in pairs]
        b = [shapes[p.b] for p in pairs]
        self.register_buffer("body_a", torch.tensor([bodies[p.a] for p in pairs]))
        self.register_buffer("body_b", torch.tensor([bodies[p.b] for p in pairs]))
        self.register_buffer("mu", torch.tensor([p.mu for p in pairs], dtype=dtype))
        static = [bool(welded[bodies[p.a]] or welded[bodies[p.b]]) for p in pairs]
        self.register_buffer("static", torch.tensor(static))
        self.register_buffer(
            "radius",
            torch.tensor([s.radius + t.radius for s, t in zip(a, b, strict=True)], dtype=dtype),
        )
        self.register_buffer("radius_a", torch.tensor([s.radius for s in a], dtype=dtype))
        self.core_a = _CoreConstants(a, dtype)
        self.core_b = _CoreConstants(b, dtype)
        centre_a, sphere_a = _sphere(a)
        centre_b, sphere_b = _sphere(b)
        self.register_buffer("centre_a", as_tensor(centre_a, dtype))
        self.register_buffer("centre_b", as_tensor(centre_b, dtype))
        self.register_buffer("sphere_a", as_tensor(sphere_a, dtype))
        self.register_buffer("sphere_b", as_tensor(sphere_b, dtype))

    def bound(self, position, rotation) -> torch.Tensor:
        """``(..., P)`` a lower bound [m] on each pair's distance: the gap between bounding
        spheres about the shapes (a plane: the sphere's height above it)."""
        centre = _moved(position, rotation, self.body_a, self.centre_a)
        if self.kind_b == "plane":
            normal, offset = self.core_b.plane(position, rotation, self.body_b)
            return (centre * normal).sum(-1) - offset - self.sphere_a
        other = _moved(position, rotation, self.body_b, self.centre_b)
        return safe_norm(centre - other) - self.sphere_a - self.sphere_b

    def spheres(self, position, rotation):
        """World centres ``(..., 2P, 3)``, radii ``(2P,)`` and bodies ``(2P,)`` of both sides'
        bounding spheres (a plane's: radius zero)."""
        centres = torch.cat(
            [
                _moved(position, rotation, self.body_a, self.centre_a),
                _moved(position, rotation, self.body_b, self.centre_b),
            ],
            -2,
        )
        radii = torch.cat([self.sphere_a, self.sphere_b])
        return centres, radii, torch.cat([self.body_a, self.body_b])

    def patch(self, position, rotation, margin: float, smoothing) -> dict[str, torch.Tensor]:
        """Candidate points ``(..., P, C)`` of every pair: the pair's own witness first, then
        each vertex of either core against the other's solid (or a plane)."""
        a = self.core_a.world(position, rotation, self.body_a)
        if self.kind_b == "plane":
            normal, offset = self.core_b.plane(position, rotation, self.body_b)
            height = (a.vertices * normal.unsqueeze(-2)).sum(-1) - offset.unsqueeze(-1)
            phi = height - self.radius_a.unsqueeze(-1)
            towards = (-normal).unsqueeze(-2).expand_as(a.vertices)
            point = a.vertices + towards * (self.radius_a[:, None] + 0.5 * phi).unsqueeze(-1)
            # the deepest vertex first: the pair's own point, where its patch starts
            first = phi.argmin(-1, keepdim=True)
            phi = torch.cat([phi.gather(-1, first), phi], -1)
            point = torch.cat(
                [point.gather(-2, first.unsqueeze(-1).expand(*first.shape, 3)), point], -2
            )
            towards = torch.cat([towards[..., :1, :], towards], -2)
            return self._points(phi, point, towards, margin)
        b = self.core_b.world(position, rotation, self.body_b)
        main = core_separation(a, b, smoothing)
        phi = [main.distance.unsqueeze(-1)]
        normal = [main.normal.unsqueeze(-2)]
        surface_a = [main.point_a.unsqueeze(-2)]
        surface_b = [main.point_b.unsqueeze(-2)]
        if main.vertices_a is not None:
            distance, surface, outward = main.vertices_a
            phi.append(distance)
            normal.append(-outward)
            surface_a.append(a.vertices)
            surface_b.append(surface)
        if main.vertices_b is not None:
            distance, surface, outward = main.vertices_b
            phi.append(distance)
            normal.append(outward)
            surface_a.append(surface)
            surface_b.append(b.vertices)
        if main.crossings is not None:
            distance, surface, outward = points_to_solid(main.crossings, b, smoothing)
            phi.append(distance)
            normal.append(-outward)
            surface_a.append(main.crossings)
            surface_b.append(surface)
        normal = torch.cat(normal, -2)
        phi = torch.cat(phi, -1) - self.radius.unsqueeze(-1)
        ra = self.radius_a[:, None, None]
        rb = (self.radius - self.radius_a)[:, None, None]
        point = 0.5 * (
            torch.cat(surface_a, -2) + ra * normal + torch.cat(surface_b, -2) - rb * normal
        )
        return self._points(phi, point, normal, margin)

    def _points(self, phi, point, normal, margin: float) -> dict[str, torch.Tensor]:
        shape = phi.shape
        return {
            "phi": phi,
            "position": point,
            "normal": normal,
            "active": phi < margin,
            "mu": self.mu.unsqueeze(-1).expand(shape),
            "static": self.static.unsqueeze(-1).expand(shape),
            "body_a": self.body_a.unsqueeze(-1).expand(shape),
            "body_b": self.body_b.unsqueeze(-1).expand(shape),
        }


class _CoreConstants(torch.nn.Module):
    """Body-frame cores of one kind, padded to a common count by repeating an entry (a
    repeated vertex, triangle or edge changes no least or greatest).

    Polytopes are padded further, to the capacities of a polytope of :func:`vertex_bucket`
    vertices (Euler's bounds: at most 3V − 6 edges and 2V − 4 triangles), so that a compiled
    geometry is specialised to the bucket rather than to each hull: every object of a scene
    whose hull falls in one bucket shares its graph."""

    def __init__(self, shapes: Sequence[Shape], dtype):
        super().__init__()
        self.kind = shapes[0].kind
        if self.kind == "plane":
            self.register_buffer("normal", as_tensor(np.stack([s.normal for s in shapes]), dtype))
            self.register_buffer("offset", torch.tensor([s.offset for s in shapes], dtype=dtype))
            return
        vertices = edges = triangles = None
        if self.kind == "polytope":
            vertices = vertex_bucket(max(len(s.vertices) for s in shapes))
            edges, triangles = 3 * vertices - 6, 2 * vertices - 4
        self.register_buffer("vertices", _padded([s.vertices for s in shapes], dtype, vertices))
        self.register_buffer(
            "edges", _padded([s.vertices[s.edges()] for s in shapes], dtype, edges)
        )
        if self.kind != "point":
            self.register_buffer(
                "directions", _padded([s.directions() for s in shapes], dtype, edges)
            )
        if self.kind == "polytope":
            planes = [s.planes() for s in shapes]
            self.register_buffer(
                "corners", _padded([s.vertices[s.triangles] for s in shapes], dtype, triangles)
            )
            self.register_buffer("normals", _padded([n for n, _ in planes], dtype, triangles))
            self.register_buffer("offsets", _padded([d for _, d in planes], dtype, triangles))
            self.register_buffer(
                "edge_normals", _padded([s.edge_normals() for s in shapes], dtype, edges)
            )

    def world(self, position, rotation, bodies) -> Core:
        """The cores in the world frame at the bodies' ``position (..., nbody, 3)`` and
        ``rotation (..., nbody, 3, 3)``."""
        x, r = position[..., bodies, :], rotation[..., bodies, :, :]  # (..., P, 3), (..., P, 3, 3)

        def move(points):  # (P, N, ..., 3) body frame → world
            extra = points.dim() - 3
            rr = r.reshape(*r.shape[:-2], *([1] * (extra + 1)), 3, 3)
            xx = x.reshape(*x.shape[:-1], *([1] * (extra + 1)), 3)
            return (rr @ points.unsqueeze(-1)).squeeze(-1) + xx

        vertices, edges = move(self.vertices), move(self.edges)
        if self.kind == "point":
            return Core(vertices, edges=edges)
        rr = r.unsqueeze(-3)
        directions = (rr @ self.directions.unsqueeze(-1)).squeeze(-1)
        if self.kind == "segment":
            return Core(vertices, edges=edges, directions=directions)
        normals = (rr @ self.normals.unsqueeze(-1)).squeeze(-1)
        offsets = self.offsets + (normals * x.unsqueeze(-2)).sum(-1)
        edge_normals = (rr.unsqueeze(-3) @ self.edge_normals.unsqueeze(-1)).squeeze(-1)
        return Core(vertices, move(self.corners), normals, offsets, edges, directions, edge_normals)

    def plane(self, position, rotation, bodies):
        """World outward normals ``(..., P, 3)`` and offsets ``(..., P)`` of planes."""
        x, r = position[..., bodies, :], rotation[..., bodies, :, :]
        normal = (r @ self.normal.unsqueeze(-1)).squeeze(-1)
        return normal, self.offset + (normal * x).sum(-1)


def _sphere(shapes: Sequence[Shape]) -> tuple[np.ndarray, np.ndarray]:
    """Centres ``(P, 3)`` (of the cores' bounding boxes, body frame) and radii ``(P,)`` [m] of
    spheres holding each shape; a plane's are zero (its bound is its height)."""
    centres, radii = [], []
    for shape in shapes:
        if shape.kind == "plane":
            centres.append(np.zeros(3))
            radii.append(0.0)
            continue
        centre = 0.5 * (shape.vertices.min(0) + shape.vertices.max(0))
        centres.append(centre)
        radii.append(np.linalg.norm(shape.vertices - centre, axis=-1).max() + shape.radius)
    return np.stack(centres), np.array(radii)


def _moved(position, rotation, bodies, points) -> torch.Tensor:
    """Body-frame ``points (P, 3)`` on ``bodies (P,)`` in the world frame ``(..., P, 3)``."""
    r = rotation[..., bodies, :, :]
    return (r @ points.unsqueeze(-1)).squeeze(-1) + position[..., bodies, :]


def _deepest_index(phi: torch.Tensor) -> torch.Tensor:
    """``(..., P, 1, 3)`` index of each pair's least φ, to gather its normal."""
    index = phi.argmin(-1, keepdim=True).unsqueeze(-1)
    return index.expand(*index.shape[:-1], 3)


def _padded(arrays: Sequence[np.ndarray], dtype, count: int | None = None) -> torch.Tensor:
    """``(P, N, ...)`` from arrays of ``(N_i, ...)``, each padded with its first entry to
    ``count`` entries (default: the longest's)."""
    count = max(len(a) for a in arrays) if count is None else count
    rows = [np.concatenate([a, np.repeat(a[:1], count - len(a), 0)]) for a in arrays]
    return as_tensor(np.stack(rows), dtype)


def vertex_bucket(vertices: int) -> int:
    """The polytope capacity a hull of ``vertices`` vertices is padded to: the next power of
    two, at least 8 (a box): ⌈log₂⌉ graphs over every object size, each at most 2× the work."""
    return max(8, 1 << (vertices - 1).bit_length())


def _spanning(points: dict[str, torch.Tensor], per_pair: int) -> dict[str, torch.Tensor]:
    """Per pair, up to ``per_pair`` of its candidates ``(..., P, C)``: the first (the pair's
    nearest), then each time the active candidate farthest from those kept, if farther than
    :data:`SPREAD`. Returns every field flattened to ``(..., P·per_pair)``."""
    position, active = points["position"], points["active"]
    chosen = [torch.zeros_like(active[..., 0], dtype=torch.long)]
    keep = [active[..., 0]]
    gap = safe_norm(position - position[..., :1, :])  # (..., P, C)
    for _ in range(1, min(per_pair, active.shape[-1])):
        score = torch.where(active, gap, -1.0)
        best = score.argmax(-1)
        far = score.gather(-1, best.unsqueeze(-1)).squeeze(-1) > SPREAD
        chosen.append(best)
        keep.append(far)
        picked = position.gather(-2, best[..., None, None].expand(*best.shape, 1, 3))
        gap = torch.minimum(gap, safe_norm(position - picked))
    index = torch.stack(chosen, -1)  # (..., P, k)
    out = {}
    for key, value in points.items():
        if key in _SCALARS:
            out[key] = value.gather(-1, index).flatten(-2)
        else:
            out[key] = value.gather(-2, index.unsqueeze(-1).expand(*index.shape, 3)).flatten(-3, -2)
    out["active"] = out["active"] & torch.stack(keep, -1).flatten(-2)
    return out


def _deepest(points: dict[str, torch.Tensor], slots: int) -> dict[str, torch.Tensor]:
    """The ``slots`` active points of least φ (padded with inactive ones), each field
    ``(..., slots)`` or ``(..., slots, 3)``."""
    phi, active = points["phi"], points["active"]
    count = phi.shape[-1]
    if count < slots:  # fewer candidates than slots: pad with inactive copies of the first
        extra = slots - count
        points = {
            key: torch.cat([v, v[..., :1].expand(*v.shape[:-1], extra)], -1)
            if key in _SCALARS
            else torch.cat([v, v[..., :1, :].expand(*v.shape[:-2], extra, 3)], -2)
            for key, v in points.items()
        }
        points["active"][..., count:] = False
        phi, active = points["phi"], points["active"]
    score = torch.where(active, phi, torch.inf)
    index = score.topk(slots, -1, largest=False, sorted=True).indices
    return {
        key: value.gather(-1, index) if key in _SCALARS
        else value.gather(-2, index.unsqueeze(-1).expand(*index.shape, 3))
        for key, value in points.items()
    }  # fmt: skip


def _frame(normal: torch.Tensor) -> torch.Tensor:
    """``(..., 3, 3)`` rows n, t₁, t₂ of a right-handed frame about unit ``normal (..., 3)``."""
    axes = torch.eye(3, dtype=normal.dtype, device=normal.device)
    least = normal.abs().argmin(-1)
    axis = axes[least]
    t1 = torch.linalg.cross(normal, axis)
    t1 = t1 / safe_norm(t1).unsqueeze(-1)
    t2 = torch.linalg.cross(normal, t1)
    return torch.stack([normal, t1, t2], -2)
