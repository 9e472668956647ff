"""The three-fingertip environment: three free spheres on slide joints push an object on the
ground (the paper's rotation, flip and in-air tasks)."""

from __future__ import annotations

import torch

from torchcontact.environments import tasks
from torchcontact.environments.base import BENCHMARK_COLLISION, Environment, ObjectModel
from torchcontact.environments.costs import ManipulationCost
from torchcontact.environments.options import CostOptions
from torchcontact.environments.presets import MPCSettings
from torchcontact.integrate import JointLayout
from torchcontact.objects import ObjectOptions
from torchcontact.sim.fingertips import FingertipsPlant
from torchcontact.sim.robot import Robot

TRANSLATION_METRIC = 50.0
"""εMₒ/h² on the object's translation [N/m] (the rotation's is per object, see
:data:`~torchcontact.environments.tasks.OBJECT_SETTINGS`)."""

ROBOT_STIFFNESS = 100.0
"""Kᵣ [N/m] of the quasi-dynamic tips."""

CONTROL_BOUND = 0.005
"""|u| per element [m of tip displacement per step]."""

PAPER_STIFFNESS = 1.0
"""The paper's K."""

STIFFNESS = 4.64
"""The default K: ``torchcontact learn-k --scene fingertips --object cube``'s best constant K
on the cube's MPC rollouts, chosen by measurement (docs/experiments.md, "Three-fingertip MPC")."""

PRESETS = {
    "fast": MPCSettings(max_iter=5),
    "balanced": MPCSettings(max_iter=20, dtype="float32", gaps="propagated"),
    "accurate": MPCSettings(memory=16),
}
"""Solver presets on the measured front (README "Choosing settings")."""


class FingertipsEnvironment(Environment):
    """Three fingertip spheres (9 slide joints) and one object on the ground."""

    name = "fingertips"
    pairs = tasks.PAPER_PAIRS
    criterion = tasks.FINGERTIPS_SUCCESS
    stiffness = PAPER_STIFFNESS
    default_stiffness = STIFFNESS
    presets = PRESETS
    user_meshes = False
    layout = JointLayout.manipulation(["slide"] * 9)

    def make_plant(
        self, obj, collision: str = BENCHMARK_COLLISION, options: ObjectOptions | None = None
    ) -> FingertipsPlant:
        if options is not None and not options.is_default:
            raise ValueError(
                "options must be empty for fingertips: its objects are the paper's three "
                "scenes, each with its own per-object model settings"
            )
        if not isinstance(obj, str) or obj not in tasks.OBJECT_SETTINGS:
            raise ValueError(
                f"obj must be one of fingertips' objects {sorted(tasks.OBJECT_SETTINGS)}, "
                f"got {obj!r}"
            )
        settings = tasks.OBJECT_SETTINGS[obj]
        return FingertipsPlant(
            obj,
            object_friction=settings.object_friction,
            contact_slots=settings.contact_slots,
            overflow="deepest",
            collision=collision,
        )

    def robot(self, dtype: torch.dtype = torch.float64) -> Robot:
        return Robot.point_tips(3)

    def object_model(self, plant: FingertipsPlant) -> ObjectModel:
        rotation = tasks.OBJECT_SETTINGS[plant.object.name].rotational_metric
        return ObjectModel((TRANSLATION_METRIC,) * 3 + (rotation,) * 3, ROBOT_STIFFNESS)

    def h(self, plant: FingertipsPlant) -> float:
        return tasks.OBJECT_SETTINGS[plant.object.name].model_step

    def control_bound(self, plant: FingertipsPlant) -> float:
        return CONTROL_BOUND

    def cost(self, plant: FingertipsPlant, options: CostOptions | None = None) -> ManipulationCost:
        (CostOptions() if options is None else options).resolved(self)  # the paper's: no terms
        return ManipulationCost()

    def sample(self, plant: FingertipsPlant, task: str, seed: int):
        return tasks.sample(task, plant.object.name, seed)


FINGERTIPS = FingertipsEnvironment()
