"""Convex shapes in their body's frame: a core (point, segment or polytope) grown by a radius,
or a plane (a half-space)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import ConvexHull, QhullError

KINDS = ("point", "segment", "polytope", "plane")


@dataclass(frozen=True)
class Shape:
    """One convex shape, fixed to a body, in that body's frame [m].

    Build with :meth:`sphere`, :meth:`capsule`, :meth:`box`, :meth:`hull` or :meth:`plane`.

    Attributes:
        kind: ``"point"`` (a sphere), ``"segment"`` (a capsule), ``"polytope"`` (a box, a
            mesh's convex hull) or ``"plane"`` (the half-space below ``normal·x = offset``).
        vertices: ``(V, 3)`` the core's vertices (a plane: none).
        triangles: ``(T, 3)`` vertex indices of a polytope's surface, counter-clockwise seen
            from outside; empty for the others.
        radius: how far the surface lies beyond the core [m].
        normal, offset: a plane's outward unit normal and offset [m].
    """

    kind: str
    vertices: np.ndarray
    triangles: np.ndarray
    radius: float = 0.0
    normal: np.ndarray | None = None
    offset: float = 0.0

    @classmethod
    def sphere(cls, radius: float, position=(0, 0, 0)) -> Shape:
        """A sphere of ``radius`` centred at ``position (3,)``."""
        return cls("point", _points([position]), _no_triangles(), _positive("radius", radius))

    @classmethod
    def capsule(cls, radius: float, half_length: float, position=(0, 0, 0), rotation=None):
        """A capsule of ``radius`` about the segment from ``−half_length`` to ``+half_length``
        along the local z axis, placed at ``position (3,)`` turned by ``rotation (3, 3)``."""
        ends = np.array([[0, 0, -half_length], [0, 0, half_length]], dtype=float)
        vertices = _placed(ends, position, rotation)
        return cls("segment", vertices, _no_triangles(), _positive("radius", radius))

    @classmethod
    def box(cls, half_sizes, position=(0, 0, 0), rotation=None) -> Shape:
        """A box of half sizes ``(3,)`` centred at ``position`` turned by ``rotation``."""
        half = np.asarray(half_sizes, dtype=float)
        if half.shape != (3,) or not (half > 0).all():
            raise ValueError(f"half_sizes must be 3 positive sizes, got {half_sizes!r}")
        corners = np.array(list(itertools.product((-1, 1), repeat=3)), dtype=float) * half
        return cls.hull(_placed(corners, position, rotation))

    @classmethod
    def hull(cls, points) -> Shape:
        """The convex hull of ``points (N, 3)`` (a mesh's vertices)."""
        points = _points(points)
        try:
            hull = ConvexHull(points)
        except QhullError as error:
            raise ValueError(
                f"points must span a volume, got {len(points)} points: {error}"
            ) from None
        vertices = points[hull.vertices]
        renumber = {int(old): new for new, old in enumerate(hull.vertices)}
        triangles = np.vectorize(renumber.__getitem__)(hull.simplices)
        # orient every triangle counter-clockwise from outside (qhull leaves them unordered)
        corners = vertices[triangles]
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        outward = (normal * hull.equations[:, :3]).sum(-1) > 0
        triangles = np.where(outward[:, None], triangles, triangles[:, ::-1])
        return cls("polytope", vertices, triangles.astype(np.int64))

    @classmethod
    def plane(cls, normal=(0, 0, 1), point=(0, 0, 0)) -> Shape:
        """The half-space below the plane through ``point`` with outward ``normal``."""
        normal = np.asarray(normal, dtype=float)
        length = np.linalg.norm(normal)
        if normal.shape != (3,) or not length > 0:
            raise ValueError(f"normal must be a non-zero 3-vector, got {normal!r}")
        normal = normal / length
        offset = float(normal @ np.asarray(point, dtype=float))
        return cls("plane", np.zeros((0, 3)), _no_triangles(), 0.0, normal, offset)

    def edges(self) -> np.ndarray:
        """``(E, 2)`` vertex index pairs: a polytope's edges, a segment's one, a point's
        degenerate one; none for a plane."""
        if self.kind == "point":
            return np.zeros((1, 2), dtype=np.int64)
        if self.kind == "segment":
            return np.array([[0, 1]], dtype=np.int64)
        if self.kind == "plane":
            return np.zeros((0, 2), dtype=np.int64)
        pairs = np.sort(self.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        return np.unique(pairs, axis=0)

    def directions(self) -> np.ndarray:
        """``(D, 3)`` unit directions of the edges, each once up to sign: a polytope's edges
        between faces that are not coplanar (not a triangulation's diagonals)."""
        edges = self.edges()
        if self.kind == "polytope":
            normals, _ = self.planes()
            bent = [
                key for key, ts in self._edge_faces().items()
                if len(ts) != 2 or normals[ts[0]] @ normals[ts[1]] < 1 - 1e-9
            ]  # fmt: skip
            edges = np.array(bent, dtype=np.int64)
        along = self.vertices[edges[:, 1]] - self.vertices[edges[:, 0]]
        along = along / np.linalg.norm(along, axis=1, keepdims=True)
        flip = np.take_along_axis(along, np.abs(along).argmax(1)[:, None], 1) < 0
        along = np.where(flip, -along, along)
        return np.unique(along.round(9), axis=0)

    def edge_normals(self) -> np.ndarray:
        """``(E, 2, 3)`` a polytope's outward normals of the two triangles beside each of its
        :meth:`edges` (equal for a diagonal between coplanar triangles)."""
        normals, _ = self.planes()
        beside = self._edge_faces()
        faces = [beside[(int(i), int(j))] for i, j in self.edges()]
        return np.stack([normals[[f[0], f[-1]]] for f in faces])

    def _edge_faces(self) -> dict[tuple[int, int], list[int]]:
        """A polytope's triangles beside each edge, by the edge's sorted vertex indices."""
        faces: dict[tuple[int, int], list[int]] = {}
        for t, tri in enumerate(self.triangles):
            for i, j in ((0, 1), (1, 2), (2, 0)):
                faces.setdefault(tuple(sorted((int(tri[i]), int(tri[j])))), []).append(t)
        return faces

    def planes(self) -> tuple[np.ndarray, np.ndarray]:
        """A polytope's outward face planes: ``normals (T, 3)`` and ``offsets (T,)``."""
        corners = self.vertices[self.triangles]
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        return normal, (normal * corners[:, 0]).sum(-1)

    def bounding_radius(self) -> float:
        """Radius [m] of a ball about the core's centre that holds the shape (inf: a plane)."""
        if self.kind == "plane":
            return float("inf")
        centre = self.vertices.mean(0)
        return float(np.linalg.norm(self.vertices - centre, axis=1).max() + self.radius)

    def centre(self) -> np.ndarray:
        return self.vertices.mean(0) if len(self.vertices) else np.zeros(3)


def _points(points) -> np.ndarray:
    array = np.asarray(points, dtype=float)
    if array.ndim != 2 or array.shape[-1] != 3 or not np.isfinite(array).all():
        raise ValueError(f"points must be finite with shape (N, 3), got {array.shape}")
    return array


def _no_triangles() -> np.ndarray:
    return np.zeros((0, 3), dtype=np.int64)


def _positive(name: str, value: float) -> float:
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def _placed(points: np.ndarray, position, rotation) -> np.ndarray:
    rotation = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float)
    return points @ rotation.T + np.asarray(position, dtype=float)


def as_tensor(x: np.ndarray, dtype: torch.dtype) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(x), dtype=dtype)
