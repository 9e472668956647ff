"""Seeded, procedurally generated objects: the benchmark of shapes nobody tuned for.

Each seed gives one object, the same on every machine: a union of 1–4 convex primitives
(boxes, ellipsoids, cylinders, capsules, hulls of random point clouds), stretched to a
bounding box whose aspect ratio (longest over shortest side) is drawn from 1:1 to 5:1, so flat
plates, tall columns and long rods all occur, then turned onto its most likely stable face and
scaled to a largest extent of 5–15 cm. The resting face is computed, not assumed, by the rule a
user's mesh rests by (:func:`~torchcontact.resting.rest_on_stable_face`), its margin judged at
the final aspect ratio.

Seeds are split: seeds below :data:`REPORT_SEEDS` are for tuning, seeds from
:data:`REPORT_SEEDS` on are the reported, held-out set. ``"random:N"`` names the first N of
the reported set, ``"random:A-B"`` any range (:func:`expand`); one object is named
``"random-SEED"``.

No MuJoCo here; :mod:`torchcontact.sim.objects` turns the :class:`~torchcontact.shapes.
ObjectMesh` into a body.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import trimesh
from trimesh.transformations import random_rotation_matrix

from torchcontact.resting import rest_on_stable_face
from torchcontact.shapes import (
    COLLISIONS,
    DEFAULT_MASS,
    MAX_MESH_EXTENT,
    ObjectMesh,
    assemble,
    convex,
)

GENERATOR_VERSION = 1
"""Version of the seeds' random stream, part of each: a change of what a seed draws bumps it. A
change of what is made of the draws (scenes 11: the resting face's margin judged after the
stretch) bumps :data:`~torchcontact.mpc.trial_config.SCENES_VERSION` only, so old records are
rerun."""

MAX_SET = 100_000
"""The most objects a set (``random:N``, ``random:A-B``) names: a sweep of that many objects
already takes days."""

REPORT_SEEDS = 1000
"""First seed of the reported set: tune on seeds below it, report on seeds from it on."""

PREFIX = "random"
PRIMITIVES = ("box", "ellipsoid", "cylinder", "capsule", "hull")
PARTS = (1, 4)
"""Fewest and most convex parts of an object."""

ASPECT = (1.0, 5.0)
"""Range of the ratio of the longest to the shortest side of the bounding box."""

EXTENT = (0.05, 0.15)
"""Range of the largest extent [m] of the resting object."""

_NAME = re.compile(rf"^{PREFIX}-(\d+)$")
_COUNT = re.compile(rf"^{PREFIX}:(\d+)$")
_RANGE = re.compile(rf"^{PREFIX}:(\d+)-(\d+)$")


def name(seed: int) -> str:
    """The object name of ``seed``: ``"random-1042"``."""
    return f"{PREFIX}-{_seed(seed)}"


def seed_of(obj: object) -> int | None:
    """The seed of a generated object's name (``"random-1042"`` ↦ 1042); None for any other
    value."""
    match = _NAME.match(obj) if isinstance(obj, str) else None
    return int(match.group(1)) if match else None


def is_generated(obj: object) -> bool:
    """Whether ``obj`` names a generated object (``"random-SEED"``)."""
    return seed_of(obj) is not None


def is_set(spec: object) -> bool:
    """Whether ``spec`` names a set of generated objects (``"random:N"``, ``"random:A-B"``)."""
    return isinstance(spec, str) and bool(_COUNT.match(spec) or _RANGE.match(spec))


def expand(spec: str) -> list[str]:
    """The object names of ``spec``: ``"random:N"``, the first N reported seeds (from
    :data:`REPORT_SEEDS`); ``"random:A-B"``, seeds A to B inclusive; at most
    :data:`MAX_SET` objects. Raises ``ValueError`` naming the forms for anything else."""
    if match := _COUNT.match(spec):
        count = int(match.group(1))
        if not 1 <= count <= MAX_SET:
            raise ValueError(f"random:N needs 1 <= N <= {MAX_SET}, got {spec!r}")
        return [name(REPORT_SEEDS + i) for i in range(count)]
    if match := _RANGE.match(spec):
        first, last = int(match.group(1)), int(match.group(2))
        if last < first:
            raise ValueError(f"random:A-B needs A <= B, got {spec!r}")
        if last - first + 1 > MAX_SET:
            raise ValueError(f"random:A-B names at most {MAX_SET} objects, got {spec!r}")
        return [name(seed) for seed in range(first, last + 1)]
    raise ValueError(
        f"generated objects are named 'random:N' (N objects from seed {REPORT_SEEDS}) or "
        f"'random:A-B' (seeds A to B), got {spec!r}"
    )


def generate(
    seed: int,
    mass: float = DEFAULT_MASS,
    extent: float | None = None,
    scale: float | None = None,
    collision: str = "hull",
) -> ObjectMesh:
    """The object of ``seed``, resting on its most likely stable face (z up), origin at its
    bounding-box centre.

    Args:
        seed: a non-negative integer (below :data:`REPORT_SEEDS` for tuning).
        mass: its mass [kg].
        extent: its largest extent [m]; default the seed's draw from :data:`EXTENT`.
        scale: factor on that drawn extent (not with ``extent``).
        collision: ``"hull"`` (default, as the paper's objects collide) or ``"auto"``: MuJoCo
            collides the hull of all parts; ``"parts"``: part by part.
    """
    if extent is not None and scale is not None:
        raise ValueError("extent and scale both set the object's size: give one of them")
    if collision not in COLLISIONS:
        raise ValueError(f"collision must be one of {COLLISIONS}, got {collision!r}")
    mass = _positive("mass", mass)
    rng = np.random.default_rng([GENERATOR_VERSION, _seed(seed)])
    count = int(rng.integers(PARTS[0], PARTS[1] + 1))
    parts = _parts(rng, count)
    shape = assemble(name(seed), parts, _box(rng), mass)
    sides = np.sort(_box(rng))

    def stretched(rested: ObjectMesh) -> ObjectMesh:  # its margin judged as it will stand
        return assemble(rested.name, rested.parts, _stretch(rested, sides), mass)

    rested = rest_on_stable_face(shape, stretched).obj
    largest = float(rng.uniform(*EXTENT))
    if extent is not None:
        largest = _positive("extent", extent)
    elif scale is not None:
        largest *= _positive("scale", scale)
    if largest > MAX_MESH_EXTENT:
        raise ValueError(
            f"extent (or scale) must make the object at most {MAX_MESH_EXTENT:g} m across, "
            f"got {largest:g} m"
        )
    obj = assemble(name(seed), rested.parts, _stretch(rested, sides) * largest, mass)
    hull = collision != "parts" and len(obj.parts) > 1
    return dataclasses.replace(obj, collide_hull=True) if hull else obj


def _positive(label: str, value: object) -> float:
    number = float(value) if isinstance(value, (int, float, np.number)) else float("nan")
    if not (np.isfinite(number) and number > 0):
        raise ValueError(f"{label} must be a positive finite number, got {value!r}")
    return number


def _seed(seed: object) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def _box(rng: np.random.Generator) -> np.ndarray:
    """Bounding-box sides (unit largest side) with the drawn aspect ratio, in random order."""
    aspect = float(np.exp(rng.uniform(np.log(ASPECT[0]), np.log(ASPECT[1]))))
    middle = float(rng.uniform(1.0 / aspect, 1.0))
    return rng.permutation(np.array([1.0, middle, 1.0 / aspect]))


def _parts(rng: np.random.Generator, count: int) -> list[trimesh.Trimesh]:
    """``count`` random convex primitives, each centred on a vertex of one before it (so the
    union is connected), in arbitrary units (the object is stretched to its box after)."""
    parts: list[trimesh.Trimesh] = []
    for _ in range(count):
        kind = PRIMITIVES[int(rng.integers(len(PRIMITIVES)))]
        dims = rng.uniform(0.3, 1.0, size=3)
        centre = np.zeros(3)
        if parts:
            anchor = parts[int(rng.integers(len(parts)))]
            centre = anchor.vertices[int(rng.integers(len(anchor.vertices)))]
        rotation = random_rotation_matrix(rng.random(3))[:3, :3]
        local = _primitive(kind, dims, rng)
        parts.append(convex(local @ rotation.T + centre))
    return parts


def _primitive(kind: str, dims: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Vertices of a primitive of half-sizes ``dims (3,)`` centred at the origin."""
    if kind == "box":
        return trimesh.creation.box(extents=2 * dims).vertices
    if kind == "ellipsoid":
        return trimesh.creation.icosphere(subdivisions=2).vertices * dims
    if kind == "cylinder":
        return trimesh.creation.cylinder(1.0, 2.0, sections=20).vertices * dims
    if kind == "capsule":
        sphere = trimesh.creation.icosphere(subdivisions=1).vertices * dims[0]
        axis = np.array([0.0, 0.0, dims[2] + dims[0]])
        return np.concatenate([sphere + axis, sphere - axis])
    cloud = rng.normal(size=(int(rng.integers(8, 25)), 3))
    return cloud / np.abs(cloud).max(0) * dims


def _stretch(rested: ObjectMesh, sides: np.ndarray) -> np.ndarray:
    """The drawn ``sides (3,)`` (sorted) by rank onto ``rested``'s axes: the bounding box that
    sets the aspect ratio exactly and keeps the longest side along the longest axis."""
    return sides[np.argsort(np.argsort(rested.size))]
