"""The built-in objects' shapes: convex-part meshes at the paper's sizes, and user meshes.

No MuJoCo here (NumPy, trimesh, SciPy); :mod:`torchcontact.sim.objects` turns an
:class:`ObjectMesh` into a MuJoCo body.

MuJoCo collides every mesh geom through its convex hull, so an object is a union of convex
parts (its convex decomposition). The procedural shapes below are built from convex primitives
(boxes, ellipsoids, cylinders, hulls, sectors of revolved profiles), so they come decomposed:
a cup's wall is a ring of wall segments, a torus a ring of tube segments, and the hole stays
open to the fingertips.

What the robot touches is a choice (``make_object(..., collision=...)``). The paper's code
gives MuJoCo each object as one mesh geom, so its objects collide as their convex hulls. By
default (``"auto"``) ours do the same, except the :data:`HOLLOW_OBJECTS`, whose hole or cavity
a fingertip can reach: those collide part by part. A hull-colliding object still shows its
parts (visual-only geoms) and keeps their mass properties.

Every object is scaled per axis so the bounding box of the union is the listed size, with
the body origin at the centre of its bounding box: the origin of the paper's object meshes
(the reference code spawns each at about half its height; its bunny and cup lower, see
:data:`OBJECT_ORIGIN_HEIGHTS`), so the pose the costs and success criteria see is the same
point. Mass properties are those of the union with uniform density (overlapping
parts count once); the centre of mass is given to MuJoCo.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError
from trimesh.transformations import rotation_matrix

DEFAULT_MASS = 0.01
"""Object mass [kg] used by the paper's fingertip and TriFinger experiments."""

OBJECT_SIZES: dict[str, tuple[float, float, float]] = {
    "cube": (0.06, 0.06, 0.06),
    "foam_brick": (0.052, 0.075, 0.047),
    "stick": (0.13, 0.035, 0.03),
    "bunny": (0.108, 0.088, 0.108),
    "airplane": (0.101, 0.13, 0.036),
    "binoculars": (0.098, 0.033, 0.075),
    "bowl": (0.088, 0.088, 0.045),
    "camera": (0.091, 0.037, 0.053),
    "can": (0.065, 0.065, 0.065),
    "cup": (0.065, 0.065, 0.077),
    "elephant": (0.092, 0.052, 0.068),
    "mug": (0.073, 0.052, 0.066),
    "piggy_bank": (0.101, 0.065, 0.073),
    "rubber_duck": (0.089, 0.065, 0.093),
    "teapot": (0.104, 0.064, 0.05),
    "torus": (0.091, 0.091, 0.03),
    "water_bottle": (0.046, 0.046, 0.104),
}
"""Bounding box (x, y, z) [m] of each object in its body frame, z up when resting upright."""

OBJECT_ORIGIN_HEIGHTS: dict[str, float] = {"bunny": 0.030, "cup": 0.020}
"""Height [m] of the body origin above the bottom, at the listed size, where the paper's mesh
has its origin lower than its box centre (the reference spawns its bunny at 0.03 m and its cup
at 0.025 m with the mesh 0.02 m lower); every other object has its origin at the box centre."""

HOLLOW_OBJECTS = frozenset({"bowl", "cup", "mug", "torus"})
"""Built-in objects with a hole or cavity a fingertip can reach (the cup's, bowl's and mug's
opening, the torus' hole): they collide part by part under ``collision="auto"``. The teapot's
handle leaves a gap narrower than a fingertip, so it is not one of them."""

COLLISIONS = ("auto", "hull", "parts")
"""How a built-in object collides: ``"hull"`` as one convex hull of all its parts (the paper's
objects, one mesh geom each), ``"parts"`` part by part, ``"auto"`` parts for the
:data:`HOLLOW_OBJECTS` and the hull for the others."""

DECOMPOSITIONS = ("auto", "coacd", "hull")
_GRID = 64  # cells per axis of the mass-property grid: ≈ 1 % error at most on the shapes below


@dataclass(frozen=True, eq=False)
class ObjectMesh:
    """A rigid object: convex parts in its body frame (origin: the box centre, by default).

    Attributes:
        name: identifier, also the prefix of its MuJoCo mesh assets.
        parts: convex, watertight meshes [m] whose union is the object.
        mass: total mass [kg].
        inertia: ``(3, 3)`` inertia tensor about the centre of mass, body axes [kg·m²].
        centre_of_mass: ``(3,)`` in the body frame [m].
        collide_hull: whether MuJoCo collides the object as the convex hull of all its parts
            (one geom, the paper's way) instead of part by part; the parts still give its
            looks and mass properties.
    """

    name: str
    parts: tuple[trimesh.Trimesh, ...]
    mass: float
    inertia: np.ndarray
    centre_of_mass: np.ndarray
    collide_hull: bool = False

    @functools.cached_property
    def collision_parts(self) -> tuple[trimesh.Trimesh, ...]:
        """The convex meshes [m] MuJoCo collides: the hull of all parts, or the parts."""
        return (convex(self.vertices),) if self.collide_hull else self.parts

    @property
    def vertices(self) -> np.ndarray:
        """``(n, 3)`` vertices of all parts [m]."""
        return np.concatenate([part.vertices for part in self.parts])

    @property
    def size(self) -> np.ndarray:
        """``(3,)`` bounding-box extents of the union [m]."""
        vertices = self.vertices
        return vertices.max(0) - vertices.min(0)

    def resting_height(self, quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0)) -> float:
        """Height [m] of the origin when the object, turned by ``quat`` (w, x, y, z), meets z = 0.

        That is minus the lowest z of the rotated vertices: the body's z for a pose that
        rests on the ground without penetrating it.
        """
        rotation = _rotation_matrix(_unit_quaternion("quat", quat))
        return float(-(self.vertices @ rotation[2]).min())

    def base(self, base_tolerance: float = 1e-3) -> ConvexHull | None:
        """The face the upright object stands on: the hull, in the body's x, y [m], of the
        vertices within ``base_tolerance`` [m] of the lowest; None where it has no area (a
        point or an edge: a ball, a rod on its round side)."""
        vertices = self.vertices
        lowest = vertices[vertices[:, 2] <= vertices[:, 2].min() + base_tolerance, :2]
        try:
            return ConvexHull(lowest)
        except QhullError:  # fewer than 3 points, or all on a line
            return None

    def edge_distances(self, base: ConvexHull) -> np.ndarray:
        """``(K,)`` distances [m] from the centre of mass, seen from above, to the lines of the
        edges of ``base`` (:meth:`base`): positive on their inner side."""
        # base.equations: rows (n, offset) with n·x + offset ≤ 0 inside, ‖n‖ = 1
        return -(base.equations[:, :2] @ self.centre_of_mass[:2] + base.equations[:, 2])

    def tipping_ratio(self, base_tolerance: float = 1e-3) -> float:
        """How easily the upright object tips over: h / r (≥ 0, inf on a point or edge base).

        h is the height of the origin (the pose point, where the MPC's contact cost pulls the
        fingertips) above the ground, r the distance from the centre of mass to the nearest
        edge of the base (:meth:`base`). A horizontal push at height h against ground
        friction μ tips the object before it slides when μ·h/r > 1 (moments about that edge,
        the push just overcoming μ·m·g).
        """
        hull = self.base(base_tolerance)
        if hull is None:
            return math.inf
        r = float(self.edge_distances(hull).min())
        return self.resting_height() / r if r > 0 else math.inf

    def critical_tilt(self, directions: int = 16, step: float = math.radians(0.25)) -> float:
        """[rad] The least tilt from upright, over ``directions`` evenly spaced horizontal
        directions, at which the centre of mass passes over the point the object pivots on:
        past it, gravity tips the object over. Found on a grid of ``step`` [rad] up to π/2
        (π/2 where the object does not tip by then), so round bottoms count as well as bases."""
        if isinstance(directions, bool) or not isinstance(directions, int) or directions < 1:
            raise ValueError(f"directions must be a whole number >= 1, got {directions!r}")
        if not (math.isfinite(step) and 0 < step <= math.pi / 2):
            raise ValueError(f"step must be in (0, pi/2] rad, got {step!r}")
        tilts = np.arange(1, int(math.pi / 2 / step) + 1) * step  # (A,)
        cos, sin = np.cos(tilts)[:, None], np.sin(tilts)[:, None]
        centre, vertices = self.centre_of_mass, self.vertices
        z = vertices[:, 2]
        least = math.pi / 2
        for k in range(directions):
            angle = 2 * math.pi * k / directions
            u = np.array([math.cos(angle), math.sin(angle)])
            # in the vertical plane along u: tilted by θ toward u, s' = s cosθ + z sinθ
            s = vertices[:, :2] @ u
            heights = -s[None] * sin + z[None] * cos  # (A, V)
            lowest = heights <= heights.min(1, keepdims=True) + 1e-9
            pivot = np.where(lowest, s[None] * cos + z[None] * sin, -np.inf).max(1)
            over = (centre[:2] @ u) * cos[:, 0] + centre[2] * sin[:, 0] >= pivot
            if over.any():
                least = min(least, float(tilts[over.argmax()]))
        return least


def object_names() -> tuple[str, ...]:
    """Names of the built-in objects, in the order of :data:`OBJECT_SIZES`."""
    return tuple(OBJECT_SIZES)


def make_object(
    name: str,
    mass: float = DEFAULT_MASS,
    size: Sequence[float] | None = None,
    collision: str = "auto",
) -> ObjectMesh:
    """Built-in object ``name`` scaled to ``size`` (x, y, z) [m], default its listed size; the
    origin at the box centre or at :data:`OBJECT_ORIGIN_HEIGHTS` (scaled with the height).
    ``collision``: one of :data:`COLLISIONS`, how MuJoCo collides it."""
    if name not in _SHAPES:
        raise ValueError(f"name must be one of {object_names()}, got {name!r}")
    if collision not in COLLISIONS:
        raise ValueError(f"collision must be one of {COLLISIONS}, got {collision!r}")
    listed = OBJECT_SIZES[name]
    target = _positive_vector("size", listed if size is None else size, 3)
    if float(target.max()) > MAX_MESH_EXTENT:
        raise ValueError(f"size must be at most {MAX_MESH_EXTENT:g} m per side, got {size!r}")
    origin = OBJECT_ORIGIN_HEIGHTS.get(name, listed[2] / 2) * target[2] / listed[2]
    obj = assemble(
        name, _SHAPES[name](), target, _positive_scalar("mass", mass), origin_height=origin
    )
    hull = collision == "hull" or (collision == "auto" and name not in HOLLOW_OBJECTS)
    # a single part is its own hull: nothing to change
    return dataclasses.replace(obj, collide_hull=True) if hull and len(obj.parts) > 1 else obj


MIN_PART_VOLUME = 1e-14
"""[m³] The least volume a convex part of an object may enclose: MuJoCo refuses a mesh below
about 1e-15 m³ ("mesh volume is too small"), so an object is refused with this first."""

MIN_THICKNESS = 1e-4
"""[m] The least extent an object may have along any axis, a tenth of a millimetre: MuJoCo
takes a thinner sheet without a word, but it is a sheet, not a solid for the fingers to push."""

MAX_MESH_EXTENT = 1.0
"""[m] A mesh file whose largest extent, after its size or scale, exceeds this is refused: it
is most likely in millimetres."""


def load_object(
    path: str | Path,
    size: float | Sequence[float] | None = None,
    mass: float = DEFAULT_MASS,
    decomposition: str = "auto",
    name: str | None = None,
    scale: float | None = None,
) -> ObjectMesh:
    """An object from a mesh file (.stl, .obj, ...), in metres, split into convex parts.

    Args:
        path: mesh file readable by trimesh, its coordinates in metres.
        size: None keeps the file's own size (times ``scale``); a number scales uniformly so
            the largest extent equals it [m]; a triple ``(x, y, z)`` scales per axis to that
            bounding box [m].
        mass: total mass [kg].
        decomposition: ``"coacd"`` splits the mesh into approximately convex parts with the
            optional ``coacd`` package (holes and cavities stay open); ``"hull"`` keeps its
            convex hull (what MuJoCo would collide anyway); ``"auto"`` uses coacd when it is
            installed, else the hull.
        name: asset name; default the file stem.
        scale: factor on the file's coordinates (0.001 for a file in millimetres); not with
            ``size``.

    Raises ``ValueError`` naming the argument for a missing or empty file, a bad size, scale
    or mass, and for an object larger than :data:`MAX_MESH_EXTENT` (most likely millimetres).
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a mesh file path, got {type(path).__name__}")
    if name is not None and (not isinstance(name, str) or not name):
        raise TypeError(f"name must be a non-empty string or None, got {name!r}")
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"path must be an existing mesh file, got {str(path)!r}")
    if decomposition not in DECOMPOSITIONS:
        raise ValueError(f"decomposition must be one of {DECOMPOSITIONS}, got {decomposition!r}")
    if size is not None and scale is not None:
        raise ValueError("size and scale both set the object's size: give one of them")
    try:
        # unprocessed first: processing silently drops vertices that are not finite
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as error:  # whatever trimesh's parsers raise on a file they cannot read
        raise ValueError(
            f"path must hold a readable triangle mesh, but {str(path)!r} is not one "
            f"({type(error).__name__}: {error})"
        ) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"path must hold a triangle mesh, got nothing usable from {str(path)!r}")
    if not np.isfinite(mesh.vertices).all():
        raise ValueError(
            f"path must hold finite vertex coordinates, but {str(path)!r} has NaN or Inf"
        )
    mesh.process()
    if size is None:
        factor = 1.0 if scale is None else _positive_scalar("scale", scale)
        target = mesh.extents * factor
    elif np.ndim(size) == 0:
        target = mesh.extents * (_positive_scalar("size", size) / float(mesh.extents.max()))
    else:
        target = _positive_vector("size", size, 3)
    if not np.all(target > 0):
        raise ValueError(f"path must hold a solid mesh, but {str(path)!r} is flat")
    if float(target.max()) > MAX_MESH_EXTENT:
        raise ValueError(
            f"{str(path)!r} is {float(target.max()):g} m across, more than {MAX_MESH_EXTENT:g} m: "
            "it is most likely in millimetres. Give its size (size=, --object-size: largest "
            "extent in m) or a scale (scale=, --object-scale: 0.001 for millimetres)"
        )
    mass = _positive_scalar("mass", mass)
    try:
        return assemble(name or path.stem, _decompose(mesh, decomposition), target, mass)
    except QhullError:  # every point on a plane, a line or one point
        raise ValueError(
            f"path must hold a solid mesh, but the points of {str(path)!r} enclose no volume"
        ) from None


# --- assembly ------------------------------------------------------------------------------


def assemble(
    name: str,
    parts: Sequence[trimesh.Trimesh],
    size: np.ndarray,
    mass: float,
    origin_height: float | None = None,
) -> ObjectMesh:
    """Scale the union of ``parts`` to the box ``size``, centred on its bounding box, the origin
    ``origin_height`` [m] above its bottom (default half the height: the box centre)."""
    vertices = np.concatenate([p.vertices for p in parts])
    low, high = vertices.min(0), vertices.max(0)
    scale = size / (high - low)
    lift = 0.0 if origin_height is None else size[2] / 2 - origin_height
    offset = np.array([0.0, 0.0, lift])
    thinnest = float(np.min(size))
    if thinnest < MIN_THICKNESS:
        raise ValueError(
            f"object {name!r} is too small or too thin to be a solid: it is {thinnest:.3g} m "
            f"across its thinnest extent, less than {MIN_THICKNESS:g} m; give it a larger size"
        )
    fitted = tuple(convex((p.vertices - (low + high) / 2) * scale + offset) for p in parts)
    smallest = min(float(part.volume) for part in fitted)
    if smallest < MIN_PART_VOLUME:
        raise ValueError(
            f"object {name!r} is too small or too thin for MuJoCo: a convex part of it encloses "
            f"{smallest:.3g} m³, less than {MIN_PART_VOLUME:g} m³; give it a larger size"
        )
    centre, inertia = _union_mass_properties(fitted, mass)
    return ObjectMesh(name=name, parts=fitted, mass=mass, inertia=inertia, centre_of_mass=centre)


def _union_mass_properties(
    parts: Sequence[trimesh.Trimesh], mass: float
) -> tuple[np.ndarray, np.ndarray]:
    """Centre of mass ``(3,)`` and inertia ``(3, 3)`` about it of the union, uniform density.

    Integrates over a regular grid of cell centres in the bounding box. A convex part meets
    each vertical grid column in one z-interval, found from its hull's half-spaces
    ``a·p + d ≤ 0``; a cell is filled when its centre lies in some part's interval. Each
    filled cell adds its own box inertia, so unions of aligned boxes come out exact.
    """
    vertices = np.concatenate([p.vertices for p in parts])
    low, high = vertices.min(0), vertices.max(0)
    cell = (high - low) / _GRID
    xs, ys, zs = (low[k] + cell[k] * (np.arange(_GRID) + 0.5) for k in range(3))
    columns = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1)  # (G, G, 2)
    filled = np.zeros((_GRID, _GRID, _GRID), dtype=bool)
    for part in parts:
        equations = ConvexHull(part.vertices).equations
        slope = equations[:, 2]
        rest = columns @ equations[:, :2].T + equations[:, 3]  # (G, G, k): a·p + d at z = 0
        vertical = np.abs(slope) < 1e-12
        bound = -rest / np.where(vertical, 1.0, slope)  # z where each plane is crossed
        top = np.where(slope > 1e-12, bound, np.inf).min(-1)
        bottom = np.where(slope < -1e-12, bound, -np.inf).max(-1)
        admitted = np.all((rest <= 1e-12) | ~vertical, axis=-1)
        filled |= admitted[..., None] & (zs >= bottom[..., None]) & (zs <= top[..., None])
    if not filled.any():
        raise ValueError("the object has no volume")
    points = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), -1)[filled]
    cell_mass = mass / len(points)
    centre = points.mean(0)
    r = points - centre
    inertia = cell_mass * (np.sum(r * r) * np.eye(3) - r.T @ r)
    own = cell**2
    inertia += mass / 12 * np.diag([own[1] + own[2], own[0] + own[2], own[0] + own[1]])
    return centre, inertia


def _decompose(mesh: trimesh.Trimesh, decomposition: str) -> list[trimesh.Trimesh]:
    if decomposition == "hull" or (decomposition == "auto" and not _has_coacd()):
        return [mesh.convex_hull]
    if not _has_coacd():
        raise ModuleNotFoundError(
            "decomposition='coacd' needs the optional coacd package: pip install coacd"
        )
    import coacd

    coacd.set_log_level("error")
    pieces = coacd.run_coacd(
        coacd.Mesh(mesh.vertices, mesh.faces), threshold=0.05, max_convex_hull=16, seed=0
    )
    return [convex(np.asarray(vertices)) for vertices, _ in pieces]


@functools.cache
def _has_coacd() -> bool:
    try:
        import coacd  # noqa: F401
    except ImportError:
        return False
    return True


# --- input checks --------------------------------------------------------------------------


def _positive_scalar(name: str, value: object) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number, got {value!r}") from None
    if not (math.isfinite(number) and number > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return number


def _positive_vector(name: str, value: object, length: int) -> np.ndarray:
    array = np.asarray(value, dtype=float)
    if array.shape != (length,) or not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise ValueError(f"{name} must be {length} positive finite numbers, got {value!r}")
    return array


def _unit_quaternion(name: str, value: object) -> np.ndarray:
    quat = np.asarray(value, dtype=float)
    norm = np.linalg.norm(quat) if quat.shape == (4,) else 0.0
    if quat.shape != (4,) or not np.isfinite(norm) or norm < 1e-9:
        raise ValueError(f"{name} must be a non-zero quaternion (w, x, y, z), got {value!r}")
    return quat / norm


def _rotation_matrix(quat: np.ndarray) -> np.ndarray:
    """``(3, 3)`` rotation matrix of the unit quaternion ``quat (4,)`` (w, x, y, z).

    The arithmetic (and its rounding) of MuJoCo 4's ``mju_quat2Mat``: the identity for
    (1, 0, 0, 0), otherwise its pairing of the squares on the diagonal.
    """
    w, x, y, z = (float(q) for q in quat)
    if w == 1 and x == 0 and y == 0 and z == 0:
        return np.eye(3)
    q00, q01, q02, q03 = w * w, w * x, w * y, w * z
    q11, q12, q13 = x * x, x * y, x * z
    q22, q23, q33 = y * y, y * z, z * z
    matrix = [
        (q00 - q22) + (q11 - q33), 2 * (q12 - q03), 2 * (q13 + q02),
        2 * (q12 + q03), (q00 + q22) - (q11 + q33), 2 * (q23 - q01),
        2 * (q13 - q02), 2 * (q23 + q01), (q00 - q22) - (q11 - q33),
    ]  # fmt: skip
    return np.array(matrix).reshape(3, 3)


# --- convex primitives (in arbitrary units; objects are rescaled to their size) -------------


def convex(points: np.ndarray) -> trimesh.Trimesh:
    """The convex hull of ``points (n, 3)`` as a watertight mesh."""
    return trimesh.convex.convex_hull(np.asarray(points, dtype=float))


def _placed(mesh: trimesh.Trimesh, centre=(0, 0, 0), rotation=None) -> trimesh.Trimesh:
    vertices = mesh.vertices if rotation is None else mesh.vertices @ rotation[:3, :3].T
    return convex(vertices + np.asarray(centre, dtype=float))


def _box(extents, centre=(0, 0, 0), rotation=None) -> trimesh.Trimesh:
    return _placed(trimesh.creation.box(extents=extents), centre, rotation)


def _ellipsoid(radii, centre=(0, 0, 0), rotation=None) -> trimesh.Trimesh:
    sphere = trimesh.creation.icosphere(subdivisions=2)
    return _placed(convex(sphere.vertices * np.asarray(radii, dtype=float)), centre, rotation)


def _flat_bottomed(mesh: trimesh.Trimesh, z: float = 0.0) -> trimesh.Trimesh:
    """``mesh`` cut flat at height ``z``: a base to stand on, as the toys the paper's meshes
    were scanned from have (a round bottom rolls away from its resting pose)."""
    vertices = mesh.vertices.copy()
    vertices[:, 2] = np.maximum(vertices[:, 2], z)
    return convex(vertices)


def _cylinder(radius, height, centre=(0, 0, 0), rotation=None) -> trimesh.Trimesh:
    """Cylinder along z (before ``rotation``)."""
    return _placed(trimesh.creation.cylinder(radius, height, sections=24), centre, rotation)


def _frustum(radius_bottom, radius_top, z_bottom, z_top) -> trimesh.Trimesh:
    """Truncated cone along z."""
    angles = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], -1)
    bottom = ring * [radius_bottom, radius_bottom, 0] + [0, 0, z_bottom]
    top = ring * [radius_top, radius_top, 0] + [0, 0, z_top]
    return convex(np.concatenate([bottom, top]))


def _capsule(start, end, radius) -> trimesh.Trimesh:
    """Convex hull of two spheres: a rod with round ends from ``start`` to ``end``."""
    sphere = trimesh.creation.icosphere(subdivisions=1).vertices * radius
    return convex(np.concatenate([sphere + start, sphere + end]))


def _revolved(profile, sectors: int, start: float = 0.0, stop: float = 2 * np.pi, rotation=None):
    """A solid of revolution about z, as ``sectors`` convex wedges.

    ``profile: (k, 2)`` (radius, height) points of a convex cross-section; each wedge is the
    hull of the profile swept over its angular range (a chord approximation of the arc).
    """
    profile = np.asarray(profile, dtype=float)
    edges = np.linspace(start, stop, sectors + 1)
    parts = []
    for a0, a1 in zip(edges[:-1], edges[1:], strict=True):
        angles = np.linspace(a0, a1, 3)
        points = [
            np.stack([profile[:, 0] * np.cos(a), profile[:, 0] * np.sin(a), profile[:, 1]], -1)
            for a in angles
        ]
        parts.append(_placed(convex(np.concatenate(points)), rotation=rotation))
    return parts


def _circle(centre_radius: float, centre_height: float, radius: float, points: int = 12):
    """``(points, 2)`` (radius, height) samples of a circular cross-section."""
    angles = np.linspace(0, 2 * np.pi, points, endpoint=False)
    return np.stack(
        [centre_radius + radius * np.cos(angles), centre_height + radius * np.sin(angles)], -1
    )


def _wall(inner: float, outer: float, bottom: float, top: float):
    """``(4, 2)`` rectangle cross-section of a straight wall."""
    return [[inner, bottom], [outer, bottom], [outer, top], [inner, top]]


def _half_ring_handle(centre, ring_radius: float, tube_radius: float, facing: float):
    """A handle: half a torus in the xz-plane, opening towards ``facing`` (+1 or -1 along x)."""
    tilt = rotation_matrix(np.pi / 2, [1, 0, 0])  # revolve about y instead of z
    wedges = _revolved(
        _circle(ring_radius, 0.0, tube_radius, 8),
        sectors=4,
        start=np.pi / 2 if facing < 0 else -np.pi / 2,
        stop=3 * np.pi / 2 if facing < 0 else np.pi / 2,
        rotation=tilt,
    )
    return [_placed(w, centre) for w in wedges]


# --- the shapes ----------------------------------------------------------------------------


def _cube():
    return [_box([1, 1, 1])]


def _foam_brick():
    return [_box([0.052, 0.075, 0.047])]


def _stick():
    """Rod along x with an elliptic cross-section and rounded ends, as the paper's stick mesh
    (its ends taper over their last 15 mm)."""
    half, cap = 0.065, 0.015  # half length; length of each ellipsoidal end cap [m]
    # half a step off the axes, so that a flat facet, not a ridge, rests on the support
    angles = (np.arange(32) + 0.5) * (2 * np.pi / 32)
    section = np.stack([0.0175 * np.cos(angles), 0.015 * np.sin(angles)], -1)
    rings = []
    for x in np.concatenate([np.linspace(-half, cap - half, 8), np.linspace(half - cap, half, 8)]):
        along = (abs(x) - (half - cap)) / cap  # 0 where the cap starts, 1 at the tip
        scale = max(np.sqrt(max(1.0 - along**2, 0.0)), 0.05)  # a small flat tip, not a point
        rings.append(np.concatenate([np.full((len(angles), 1), x), scale * section], -1))
    return [convex(np.concatenate(rings))]


def _bunny():
    """Rabbit sitting along +x: haunch, chest, head, two upright ears, tail and four feet."""
    tilt_back = rotation_matrix(-0.25, [0, 1, 0])
    return [
        _ellipsoid([0.030, 0.034, 0.028], [-0.012, 0, 0.030]),  # haunch
        _ellipsoid([0.024, 0.026, 0.026], [0.016, 0, 0.036]),  # chest
        _ellipsoid([0.018, 0.017, 0.016], [0.034, 0, 0.064]),  # head
        _ellipsoid([0.006, 0.006, 0.022], [0.020, 0.009, 0.090], tilt_back),  # ears
        _ellipsoid([0.006, 0.006, 0.022], [0.020, -0.009, 0.090], tilt_back),
        _ellipsoid([0.008, 0.008, 0.008], [-0.042, 0, 0.028]),  # tail
        _ellipsoid([0.020, 0.009, 0.006], [-0.008, 0.026, 0.006]),  # hind feet
        _ellipsoid([0.020, 0.009, 0.006], [-0.008, -0.026, 0.006]),
        _ellipsoid([0.008, 0.006, 0.012], [0.03, 0.012, 0.012]),  # front legs
        _ellipsoid([0.008, 0.006, 0.012], [0.03, -0.012, 0.012]),
    ]


def _airplane():
    """Airliner along +y: fuselage, swept wings, tailplane and fin."""
    wing = convex(
        [[0, 0.01, 0], [0, -0.015, 0], [0.05, -0.02, 0], [0.05, -0.027, 0], [0, 0.01, 0.004]]
        + [[0, -0.015, 0.004], [0.05, -0.02, 0.002], [0.05, -0.027, 0.002]]
    )
    mirror = np.diag([-1.0, 1, 1])
    tailplane = convex(
        [[0, -0.05, 0.006], [0, -0.062, 0.006], [0.02, -0.064, 0.006], [0.02, -0.058, 0.006]]
        + [[0, -0.05, 0.009], [0, -0.062, 0.009], [0.02, -0.064, 0.009], [0.02, -0.058, 0.009]]
    )
    return [
        _capsule([0, -0.058, 0.008], [0, 0.058, 0.008], 0.008),  # fuselage
        wing,
        convex(wing.vertices @ mirror),
        tailplane,
        convex(tailplane.vertices @ mirror),
        convex(  # fin
            [[-0.0015, -0.048, 0.008], [0.0015, -0.048, 0.008], [-0.0015, -0.066, 0.008]]
            + [[0.0015, -0.066, 0.008], [-0.0015, -0.066, 0.036], [0.0015, -0.066, 0.036]]
            + [[-0.0015, -0.06, 0.036], [0.0015, -0.06, 0.036]]
        ),
    ]


def _binoculars():
    """Two upright barrels with eyepieces on top, joined by a bridge."""
    parts = []
    for x in (-0.032, 0.032):
        parts.append(_cylinder(0.016, 0.055, [x, 0, 0.0275]))  # barrel
        parts.append(_cylinder(0.012, 0.02, [x, 0, 0.065]))  # eyepiece
    parts.append(_box([0.04, 0.012, 0.03], [0, 0, 0.05]))  # bridge
    parts.append(_cylinder(0.006, 0.016, [0, 0, 0.073]))  # focus wheel
    return parts


def _bowl():
    """Hemispherical shell: a flat foot and the wall as 12 × 2 wedges of a spherical band."""
    outer, inner = 1.0, 0.9

    def band(low: float, high: float):  # polar angles from the bottom, cross-section corners
        angles = np.linspace(low, high, 3)
        arc = np.stack([np.sin(angles), 1 - np.cos(angles)], -1)
        return np.concatenate([arc * outer, (arc * inner)[[0, -1]] + [0, outer - inner]])

    foot = _cylinder(0.45, 0.1, [0, 0, 0.05])
    return [foot] + _revolved(band(0.35, 0.95), 12) + _revolved(band(0.95, np.pi / 2), 12)


def _camera():
    """Compact camera: body, lens barrel towards −y, viewfinder hump and shutter button."""
    flip_to_y = rotation_matrix(np.pi / 2, [1, 0, 0])
    return [
        _box([0.091, 0.025, 0.05], [0, 0.006, 0.025]),  # body
        _cylinder(0.016, 0.014, [0.01, -0.012, 0.025], flip_to_y),  # lens
        _box([0.03, 0.018, 0.006], [-0.02, 0.006, 0.053]),  # viewfinder
        _cylinder(0.004, 0.004, [0.03, 0.006, 0.052]),  # shutter button
    ]


def _can():
    return [_cylinder(0.5, 0.94, [0, 0, 0.5]), _frustum(0.47, 0.42, 0.96, 1.0)]


def _cup():
    """Open cup: a floor disc and a slightly flared wall of 12 wedges."""
    wall = [[0.42, 0.0], [0.46, 0.0], [0.5, 1.0], [0.46, 1.0]]
    return [_frustum(0.46, 0.465, 0.0, 0.08)] + _revolved(wall, 12)


def _elephant():
    """Standing elephant along +x: body, head, trunk, two ears, four legs and a tail."""
    parts = [
        _ellipsoid([0.03, 0.021, 0.02], [-0.006, 0, 0.04]),  # body
        _ellipsoid([0.015, 0.014, 0.015], [0.03, 0, 0.05]),  # head
        _capsule([0.042, 0, 0.046], [0.05, 0, 0.028], 0.006),  # trunk, upper
        _capsule([0.05, 0, 0.028], [0.046, 0, 0.012], 0.004),  # trunk, lower
        _ellipsoid([0.01, 0.003, 0.013], [0.024, 0.017, 0.052]),  # ears
        _ellipsoid([0.01, 0.003, 0.013], [0.024, -0.017, 0.052]),
        _capsule([-0.036, 0, 0.04], [-0.04, 0, 0.026], 0.0015),  # tail
    ]
    for x in (-0.024, 0.014):
        for y in (-0.011, 0.011):
            parts.append(_cylinder(0.007, 0.03, [x, y, 0.015]))  # legs
    return parts


def _mug():
    """Mug: floor, straight wall of 12 wedges, and a handle on +x."""
    wall = _wall(0.40, 0.46, 0.0, 1.15)
    handle = _half_ring_handle([0.46, 0, 0.58], ring_radius=0.26, tube_radius=0.05, facing=1)
    return [_cylinder(0.42, 0.1, [0, 0, 0.05])] + _revolved(wall, 12) + handle


def _ear(side: float) -> trimesh.Trimesh:
    """A piggy's pointed ear: a tetrahedron on the top of the head, on the ``side`` of y."""
    base = [[0.02, 0.01, 0.06], [0.03, 0.014, 0.062], [0.022, 0.02, 0.062], [0.024, 0.016, 0.073]]
    return convex(np.asarray(base) * [1.0, side, 1.0])


def _piggy_bank():
    """Piggy bank along +x: round body, snout, four stubby legs, two ears and a tail."""
    parts = [
        _ellipsoid([0.042, 0.032, 0.03], [0, 0, 0.04]),  # body
        _cylinder(0.01, 0.014, [0.044, 0, 0.042], rotation_matrix(np.pi / 2, [0, 1, 0])),  # snout
        _ear(side=1.0),
        _ear(side=-1.0),
        _capsule([-0.042, 0, 0.046], [-0.048, 0, 0.05], 0.003),  # tail
    ]
    for x in (-0.022, 0.022):
        for y in (-0.015, 0.015):
            parts.append(_cylinder(0.008, 0.02, [x, y, 0.01]))  # legs
    return parts


def _rubber_duck():
    """Rubber duck along +x: body, head, beak, tail and two wing bumps."""
    return [
        _flat_bottomed(_ellipsoid([0.042, 0.032, 0.03], [0, 0, 0.022])),  # body on a flat base
        _ellipsoid([0.021, 0.02, 0.021], [0.018, 0, 0.064]),  # head
        _ellipsoid([0.012, 0.01, 0.004], [0.041, 0, 0.06]),  # beak
        convex([[-0.03, -0.01, 0.03], [-0.03, 0.01, 0.03], [-0.046, 0, 0.05], [-0.036, 0, 0.02]]),
        _ellipsoid([0.02, 0.004, 0.01], [-0.004, 0.03, 0.032]),  # wings
        _ellipsoid([0.02, 0.004, 0.01], [-0.004, -0.03, 0.032]),
    ]


def _teapot():
    """Squat teapot along x: body, lid knob, spout towards +x and handle towards −x."""
    return [
        _flat_bottomed(_ellipsoid([0.032, 0.032, 0.026], [0, 0, 0.018])),  # body on a flat base
        _cylinder(0.012, 0.004, [0, 0, 0.044]),  # lid
        _ellipsoid([0.004, 0.004, 0.003], [0, 0, 0.048]),  # knob
        _capsule([0.026, 0, 0.016], [0.048, 0, 0.036], 0.004),  # spout
        *_half_ring_handle([-0.028, 0, 0.024], ring_radius=0.012, tube_radius=0.003, facing=-1),
    ]


def _torus():
    return _revolved(_circle(1.0, 0.0, 0.33), 12)


def _water_bottle():
    """Bottle: body, tapered shoulder, neck and cap."""
    return [
        _cylinder(0.5, 1.3, [0, 0, 0.65]),
        _frustum(0.5, 0.2, 1.3, 1.7),
        _cylinder(0.18, 0.25, [0, 0, 1.8]),
        _cylinder(0.21, 0.22, [0, 0, 2.0]),
    ]


_SHAPES: dict[str, Callable[[], list[trimesh.Trimesh]]] = {
    "cube": _cube,
    "foam_brick": _foam_brick,
    "stick": _stick,
    "bunny": _bunny,
    "airplane": _airplane,
    "binoculars": _binoculars,
    "bowl": _bowl,
    "camera": _camera,
    "can": _can,
    "cup": _cup,
    "elephant": _elephant,
    "mug": _mug,
    "piggy_bank": _piggy_bank,
    "rubber_duck": _rubber_duck,
    "teapot": _teapot,
    "torus": _torus,
    "water_bottle": _water_bottle,
}
