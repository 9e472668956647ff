"""Robot-hand environments: a hand read from its MJCF manipulates one object (TriFinger in-hand,
Allegro on-palm, or a user's robot)."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import torch

from torchcontact.environments import tasks
from torchcontact.environments.base import BENCHMARK_COLLISION, Environment, ObjectModel
from torchcontact.environments.costs import Cost, HoldFirst, ManipulationCost
from torchcontact.environments.options import CostOptions
from torchcontact.environments.presets import MPCSettings
from torchcontact.integrate import JointLayout
from torchcontact.objects import ObjectOptions
from torchcontact.shapes import ObjectMesh, object_names
from torchcontact.sim.hands import ALLEGRO, MODEL_FRICTION, TRIFINGER, Hand, HandPlant

HAND_METRIC = (50.0, 50.0, 50.0, 0.1, 0.1, 0.1)
"""εMₒ/h² of a 10 g object in the hands' model (translation [N/m], rotation)."""

PAPER_OBJECT_MASS = 0.01
"""[kg] The object mass of the paper's hand models, whatever the plant's object weighs. Kept for
the built-in hands by measurement (docs/experiments.md, "Library structure"): a heavier modelled
object needs its K chosen with it."""


def tips_before_sliding(obj: ObjectMesh, mu: float = MODEL_FRICTION) -> bool:
    """Whether a push at ``obj``'s pose point tips it over before it slides on friction ``mu``
    (``mu · obj.tipping_ratio() > 1``)."""
    return mu * obj.tipping_ratio() > 1.0


@dataclass(frozen=True)
class HandModel:
    """The model and cost of one hand's MPC.

    Attributes:
        robot_stiffness: Kᵣ of the quasi-dynamic robot.
        stiffness: the paper's K.
        control_bound: |u| per joint and step [rad].
        cost: the cost (its ``tilt`` is set where :attr:`tilt` applies).
        metric: εMₒ/h² of a 10 g object (scaled by the modelled object's mass).
        h: the model's time step [s].
        tilt: weight of the cost's tilt term for objects that tip before they slide
            (:func:`tips_before_sliding`); 0 leaves every object without.
        object_mass: the mass [kg] the model gives an object whose mass the user did not set
            (the paper's hand models plan every object at 10 g, its 100 g cube and stick
            included); None: the plant's.
        contact_floor: whether the cost's contact and grasp terms draw the tips no lower than
            where a tip rests on the support (:attr:`ManipulationCost.contact_floor`, from the
            plant's geometry); off: toward the object's centre, the paper's.
        cost_defaults: the values of the cost's terms a user does not set
            (:class:`~.options.CostOptions`; the paper's cost: no hold, approached at 1).
    """

    robot_stiffness: float
    stiffness: float
    control_bound: float
    cost: Cost
    metric: tuple[float, ...] = HAND_METRIC
    h: float = 0.1
    tilt: float = 0.0
    object_mass: float | None = None
    contact_floor: bool = False
    cost_defaults: CostOptions = CostOptions.off()


Sampler = Callable[[HandPlant, str, int], tuple[np.ndarray, np.ndarray]]
"""``(plant, task, seed) ↦`` initial and target poses ``(7,), (7,)``."""


class HandEnvironment(Environment):
    """A hand (:class:`~torchcontact.sim.hands.Hand`) and one task on every object.

    Args:
        hand: the plant's hand, its MJCF and settings.
        model: the MPC's model of it (:class:`HandModel`).
        task: the task's name; criterion: its success criterion; sample: its sampler.
        presets: solver settings by preset name.
        objects: the environment's built-in objects.
        planner: the default planner's name.
    """

    def __init__(
        self,
        hand: Hand,
        model: HandModel,
        task: str,
        criterion: tasks.SuccessCriterion,
        sample: Sampler,
        presets: Mapping[str, MPCSettings],
        objects: tuple[str, ...] = (),
        planner: str = "lbfgs",
    ):
        self.hand, self.model, self._sample, self.planner = hand, model, sample, planner
        self.name = hand.name
        self.pairs = tuple((task, obj) for obj in objects) or ((task, "cube"),)
        self.criterion = criterion
        self.stiffness = self.default_stiffness = model.stiffness
        self.cost_defaults = model.cost_defaults
        self.presets = presets

    @functools.cached_property
    def layout(self) -> JointLayout:
        return JointLayout.manipulation(self.hand.robot().joint_types)

    def make_plant(
        self, obj, collision: str = BENCHMARK_COLLISION, options: ObjectOptions | None = None
    ) -> HandPlant:
        return HandPlant(self.hand, obj, options=options, overflow="deepest", collision=collision)

    def robot(self, dtype: torch.dtype = torch.float64) -> torch.nn.Module:
        return self.hand.robot(dtype)

    def object_model(self, plant: HandPlant) -> ObjectModel:
        # a mass the user gives is the model's; else the scene's modelled mass, if it has one
        mass = None if plant.options.mass is not None else self.model.object_mass
        return ObjectModel(self.model.metric, self.model.robot_stiffness, mass)

    def h(self, plant: HandPlant) -> float:
        return self.model.h

    def control_bound(self, plant: HandPlant) -> float:
        return self.model.control_bound

    def cost(self, plant: HandPlant, options: CostOptions | None = None) -> Cost:
        """The cost of ``plant``'s MPC with ``options``' terms (:class:`CostOptions`), those
        not set the model's (:attr:`HandModel.cost_defaults`)."""
        options = CostOptions() if options is None else options
        if not isinstance(options, CostOptions):
            raise TypeError(f"options must be CostOptions or None, got {type(options).__name__}")
        terms = options.resolved(self)
        cost = self.model.cost
        if terms.hold_first and not isinstance(cost, ManipulationCost):
            raise ValueError(f"hold_first: {type(cost).__name__} has no target to hold back")
        # every object gets the terms, switched off by an input where the object slides before
        # it tips, so all objects share one compiled graph
        tips = tips_before_sliding(plant.object)
        if terms.hold_first:
            hold = HoldFirst(terms.hold_first, terms.hold_approach, applies=tips)
            cost = dataclasses.replace(cost, hold=hold)
        if self.model.tilt > 0:
            gate = torch.tensor(float(tips), dtype=torch.float64)
            cost = dataclasses.replace(cost, tilt=self.model.tilt, tilt_applies=gate)
        if self.model.contact_floor and isinstance(cost, ManipulationCost):
            floor = plant.support_height + plant.tip_clearance
            cost = dataclasses.replace(cost, contact_floor=floor)
        return cost

    def sample(self, plant: HandPlant, task: str, seed: int):
        return self._sample(plant, task, seed)


def sample_in_hand(plant: HandPlant, task: str, seed: int):
    """TriFinger in-hand: :func:`~torchcontact.environments.tasks.sample_in_hand`."""
    return tasks.sample_in_hand(plant.resting_pose, seed)


def sample_on_palm(plant: HandPlant, task: str, seed: int):
    """Allegro on-palm: :func:`~torchcontact.environments.tasks.sample_on_palm` with the
    paper's per-object placements and yaw ranges (the palm centre for other objects)."""
    name = plant.object.name
    centre = (plant.support_centre, plant.support_centre)
    return tasks.sample_on_palm(
        plant.resting_pose,
        *tasks.ON_PALM_PLACEMENTS.get(name, centre),
        seed=seed,
        yaw_range=tasks.ON_PALM_OBJECT_YAW_RANGES.get(name, tasks.ON_PALM_YAW_RANGE),
    )


TRIFINGER_PRESETS = {
    "fast": MPCSettings(horizon=2),
    "balanced": MPCSettings(max_iter=15, dtype="float32", horizon=3),
    "accurate": MPCSettings(horizon=6),
}
"""TriFinger's solver presets on its measured front (README "Choosing settings"); ``balanced``
plans T = 3 steps ahead since its model carries the object's momentum (measured on tuning
objects, docs/experiments.md "TriFinger and Allegro MPC")."""

ALLEGRO_PRESETS = {**TRIFINGER_PRESETS, "balanced": MPCSettings(dtype="float32")}
"""The Allegro's presets: TriFinger's, ``balanced`` the paper's in float32 (the Allegro was not
in the MPC-level trade-off sweep)."""

TRIFINGER_ENV = HandEnvironment(
    TRIFINGER,
    HandModel(
        robot_stiffness=10.0,
        stiffness=0.5,
        control_bound=0.01,
        cost=ManipulationCost(contact=0.5, grasp=0.05, control=10.0),
        # objects that tip before they slide are charged for leaning (every object: less precise)
        tilt=100.0,
        object_mass=PAPER_OBJECT_MASS,
        # plates thinner than a tip's diameter are pressed down, not pushed at their rim
        contact_floor=True,
        # a lone push tips over objects that tip before they slide: two tips hold them first;
        # unheld, only the contact term draws the tips in: a stronger pull closes the grip
        cost_defaults=dataclasses.replace(CostOptions.off(), hold_first=2, hold_approach=4.0),
    ),
    "in-hand",
    tasks.TRIFINGER_SUCCESS,
    sample_in_hand,
    TRIFINGER_PRESETS,
    object_names(),
)

ALLEGRO_ENV = HandEnvironment(
    ALLEGRO,
    HandModel(
        robot_stiffness=1.0,
        stiffness=0.5,
        control_bound=0.2,
        # position weight 300, not the paper's 100: at 100 the MPC turned objects off the palm
        cost=ManipulationCost(contact=1.0, grasp=0.0, control=0.1, position=300.0),
        object_mass=PAPER_OBJECT_MASS,
    ),
    "on-palm",
    tasks.ALLEGRO_SUCCESS,
    sample_on_palm,
    ALLEGRO_PRESETS,
    object_names(),
)
