"""An object turned onto a stable face computed from its centre of mass: how generated objects
and a user's meshes come to rest before a trial.

The candidates are the convex hull's faces with their quasi-static rest probabilities about the
centre of mass (``trimesh.poses.compute_stable_poses``), most likely first; the first whose
edges lie at least :data:`BASE_MARGIN` of the largest extent from below the centre of mass is
kept (a point or a sliver face rocks off), else the face of the widest such margin.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh

from torchcontact.shapes import ObjectMesh, assemble, convex

BASE_MARGIN = 0.05
"""Least distance from the centre of mass to the resting face's edges, as a fraction of the
largest extent, for a face to count as stable."""


@dataclass(frozen=True)
class Rest:
    """An object on its chosen face.

    Attributes:
        obj: the object turned onto the face (z up), re-centred on its bounding box.
        rank: the face's place among the hull's stable faces by rest probability (0: the most
            likely); faces: how many there are.
        probability: its quasi-static rest probability.
        turn_deg: the angle [°] of the turn from the object's own pose onto the face.
    """

    obj: ObjectMesh
    rank: int
    faces: int
    probability: float
    turn_deg: float

    def describe(self) -> str:
        """``"rests on stable face 1 of 6 (probability 0.42), turned 90.0° from its file"``."""
        return (
            f"rests on stable face {self.rank + 1} of {self.faces} (probability "
            f"{self.probability:.2f}), turned {self.turn_deg:.1f}° from its file"
        )


def base_margin(obj: ObjectMesh) -> float:
    """Distance [m] from the centre of mass, seen from above, to the nearest edge of the base
    (0 where it is not over the base)."""
    base = obj.base()
    return 0.0 if base is None else max(float(obj.edge_distances(base).min()), 0.0)


def extents(parts) -> np.ndarray:
    """``(3,)`` bounding-box sides [m] of the union of ``parts``."""
    vertices = np.concatenate([part.vertices for part in parts])
    return vertices.max(0) - vertices.min(0)


def rest_on_stable_face(
    obj: ObjectMesh, judged: Callable[[ObjectMesh], ObjectMesh] | None = None
) -> Rest:
    """``obj`` turned onto its stable face (see the module docstring).

    ``judged`` maps a candidate resting object to the one whose margin decides (a generated
    object is judged after its final stretch); None: the candidate itself. ``RuntimeError``
    when no face has the centre of mass over it."""
    hull = convex(obj.vertices)
    transforms, probabilities = trimesh.poses.compute_stable_poses(hull, obj.centre_of_mass)
    candidates = []
    for rank, index in enumerate(np.argsort(-probabilities, kind="stable")):
        rotation = transforms[index][:3, :3]
        parts = tuple(convex(part.vertices @ rotation.T) for part in obj.parts)
        rested = assemble(obj.name, parts, extents(parts), obj.mass)
        judge = rested if judged is None else judged(rested)
        margin = base_margin(judge)
        angle = np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1.0, 1.0)))
        rest = Rest(rested, rank, len(probabilities), float(probabilities[index]), float(angle))
        if margin >= BASE_MARGIN * float(judge.size.max()):
            return rest
        candidates.append((margin, rest))
    margin, rest = max(candidates, key=lambda candidate: candidate[0])
    if not margin > 0:
        raise RuntimeError(f"{obj.name}: no face has its centre of mass over it")
    return rest
