"""Robot-hand environments: a hand read from its MJCF manipulates one object (TriFinger in-hand,
Allegro on-palm, or a user's robot)."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import torch

from torchcontact.environments import tasks
from torchcontact.environments.base import BENCHMARK_COLLISION, Environment, ObjectModel
from torchcontact.environments.costs import Balance, Cost, HoldFirst, ManipulationCost
from torchcontact.environments.presets import MPCSettings
from torchcontact.integrate import JointLayout
from torchcontact.objects import ObjectOptions
from torchcontact.shapes import ObjectMesh, object_names
from torchcontact.sim.hands import ALLEGRO, MODEL_FRICTION, TRIFINGER, Hand, HandEnv

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


def balance_of(plant: HandEnv, metric, threshold: float) -> Balance | None:
    """The :class:`Balance` of ``plant``'s object on its support, from its geometry and the
    model's ``metric`` (εMₒ/h² of a 10 g object); None where its base has no area or its centre
    of mass does not stand over it."""
    obj = plant.object
    hull = obj.base()
    if hull is None:
        return None
    if not (obj.edge_distances(hull) > 0).all():
        return None
    return Balance.of_base(
        hull.points[hull.vertices],
        obj.centre_of_mass[:2],
        height=obj.resting_height(),
        friction=max(plant.object_friction, plant.ground_friction),
        lever=metric[3] / metric[0],
        weight=9.81 * PAPER_OBJECT_MASS / metric[0],
        threshold=threshold,
    )


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
        support_margin: with a plant that holds its object on a body (the Allegro's palm),
            how far [m] inside that body's footprint the cost keeps the object's planned
            centre (:attr:`ManipulationCost.support`); None: no such term.
        support_weight: that term's weight [1/m²].
        contact_floor: whether the cost's contact and grasp terms draw the tips no lower than
            where a tip rests on the support (:attr:`ManipulationCost.contact_floor`, from the
            plant's geometry); off: toward the object's centre, the paper's.
        contact_spread: how far along a long object the cost's contact term draws the tips:
            toward the segment of :func:`long_half_axis` at this spread
            (:attr:`ManipulationCost.contact_axis`), so a tip near an end pushes there, with a
            lever about the centre; 0: all toward the centre, the paper's.
        support_pass: whether the model resolves the object's contacts with the support
            after the fingers' (:attr:`~torchcontact.model.ComplementarityFree.support_pass`),
            so a push's friction torque at the base is in the plan.
        balance: weight of the cost's balance term (:func:`~.costs.balance_cost`), which
            charges plans whose push would tip the object over its base's edge, for every
            object that stands on a base (:func:`balance_of`); 0: none.
        balance_threshold: the share of the base's reach from the centre of mass at which
            that term starts to charge (:attr:`~.costs.Balance.threshold`).
        hold_first: for objects that tip before they slide (:func:`tips_before_sliding`),
            how many fingertip contacts must hold the object before the plan moves it toward
            its target (:class:`~.costs.HoldFirst`); 0: it moves it from the first touch.
        hold_upright: with :attr:`hold_first`, the lean from upright, as a fraction of the
            object's critical tilt (:meth:`~torchcontact.shapes.ObjectMesh.critical_tilt`),
            past which the plan stops moving a held object toward its target and rights it
            (:attr:`~.costs.HoldFirst.lean_limit`); 0: it moves it however it leans.
        hold_approach: with :attr:`hold_first`, the contact term's weight while the object
            is not yet held (:attr:`~.costs.HoldFirst.approach`); 1: the paper's throughout.
        pose_stage: the weight of the cost's pose terms on each planned state before the
            last, relative to theirs on the last (:attr:`~.costs.ManipulationCost.stage`);
            0: on the last alone, the paper's.
        pose_stage_radius: [m] with :attr:`pose_stage`, how near the target the object's
            centre must start a plan for the stage to apply
            (:attr:`~.costs.ManipulationCost.stage_radius`); inf: every plan.
    """

    robot_stiffness: float
    stiffness: float
    control_bound: float
    cost: Cost
    metric: tuple[float, ...] = HAND_METRIC
    h: float = 0.1
    tilt: float = 0.0
    object_mass: float | None = None
    support_margin: float | None = None
    support_weight: float = 1e5
    contact_floor: bool = False
    contact_spread: float = 0.0
    support_pass: bool = False
    balance: float = 0.0
    balance_threshold: float = 0.5
    hold_first: int = 0
    hold_upright: float = 0.0
    hold_approach: float = 1.0
    pose_stage: float = 0.0
    pose_stage_radius: float = math.inf


def long_half_axis(obj: ObjectMesh, spread: float) -> tuple[float, float, float] | None:
    """Half the segment [m], in ``obj``'s body frame, along its longest box side: ``spread ·
    (L₁ − L₂)/2`` with L₁ ≥ L₂ its two longest sides (vertex extents along the body axes), so
    an object with two equal longest sides (a cube, a disc) has none (None)."""
    if not (math.isfinite(spread) and spread >= 0):
        raise ValueError(f"spread must be a non-negative number, got {spread!r}")
    vertices = obj.vertices
    sides = vertices.max(0) - vertices.min(0)
    longest, second = np.argsort(sides)[::-1][:2]
    half = np.zeros(3)
    half[longest] = spread * (sides[longest] - sides[second]) / 2
    return tuple(float(x) for x in half) if half.any() else None


Sampler = Callable[[HandEnv, str, int], tuple[np.ndarray, np.ndarray]]
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
        self.support_pass = model.support_pass
        self.balance = model.balance
        self.hold_first = model.hold_first
        self.hold_upright = model.hold_upright
        self.hold_approach = model.hold_approach
        self.pose_stage = model.pose_stage
        self.pose_stage_radius = model.pose_stage_radius
        self.presets = presets

    @functools.cached_property
    def layout(self) -> JointLayout:
        return JointLayout.manipulation(self.hand.robot().joint_types)

    def make_plant(
        self, obj, collision: str = BENCHMARK_COLLISION, options: ObjectOptions | None = None
    ) -> HandEnv:
        return HandEnv(self.hand, obj, options=options, overflow="deepest", collision=collision)

    def robot(self, dtype: torch.dtype = torch.float64) -> torch.nn.Module:
        return self.hand.robot(dtype)

    def object_model(self, plant: HandEnv) -> ObjectModel:
        # a mass the user gives is the model's; else the scene's modelled mass, if it has one
        mass = None if plant.options.mass is not None else self.model.object_mass
        return ObjectModel(self.model.metric, self.model.robot_stiffness, mass)

    def h(self, plant: HandEnv) -> float:
        return self.model.h

    def control_bound(self, plant: HandEnv) -> float:
        return self.model.control_bound

    def cost(
        self,
        plant: HandEnv,
        support: bool | None = None,
        margin: float | None = None,
        spread: float | None = None,
        balance: float | None = None,
        hold_first: int | None = None,
        hold_upright: float | None = None,
        hold_approach: float | None = None,
        pose_stage: float | None = None,
        pose_stage_radius: float | None = None,
    ) -> Cost:
        """The cost of ``plant``'s MPC; ``support``: its support term on or off (None: on
        where the model has a :attr:`HandModel.support_margin`, or a ``margin`` is given; on
        needs a plant that holds its object on a body); ``margin`` [m]: the term's, instead of
        the model's; ``spread``: the contact term's, instead of
        :attr:`HandModel.contact_spread`; ``balance``: the balance term's weight, instead of
        :attr:`HandModel.balance` (0: off); ``hold_first``: the contacts that must hold an
        object that tips before it slides before the plan moves it, instead of
        :attr:`HandModel.hold_first` (0: none); ``hold_upright``: the lean, as a fraction of
        the object's critical tilt, past which a held object is righted before it moves on,
        instead of :attr:`HandModel.hold_upright` (0: none; a value needs a hold);
        ``hold_approach``: the contact term's weight while the object is not yet held,
        instead of :attr:`HandModel.hold_approach` (1: none; another value needs a hold);
        ``pose_stage``: the pose terms' weight on the planned states before the last,
        relative to theirs on the last, instead of :attr:`HandModel.pose_stage` (0: none);
        ``pose_stage_radius``: [m] how near the target a plan must start for the stage to
        apply, instead of :attr:`HandModel.pose_stage_radius` (inf: every plan)."""
        cost = self.model.cost
        hold_first = self.model.hold_first if hold_first is None else hold_first
        if isinstance(hold_first, bool) or not isinstance(hold_first, int) or hold_first < 0:
            raise ValueError(f"hold_first must be a whole number >= 0, got {hold_first!r}")
        if hold_first and not isinstance(cost, ManipulationCost):
            raise ValueError(f"hold_first: {type(cost).__name__} has no target to hold back")
        if hold_upright and not hold_first:
            raise ValueError("hold_upright: it rights objects the hold holds; set hold_first")
        hold_upright = self.model.hold_upright if hold_upright is None else hold_upright
        if not (math.isfinite(hold_upright) and hold_upright >= 0):
            raise ValueError(f"hold_upright must be a non-negative number, got {hold_upright!r}")
        if hold_approach is not None and hold_approach != 1 and not hold_first:
            raise ValueError("hold_approach: it weighs the approach to a hold; set hold_first")
        approach = self.model.hold_approach if hold_approach is None else hold_approach
        if not (math.isfinite(approach) and approach > 0):
            raise ValueError(f"hold_approach must be a positive number, got {approach!r}")
        if hold_first and tips_before_sliding(plant.object):
            lean = None
            if hold_upright:
                lean = min(hold_upright * plant.object.critical_tilt(), math.pi)
            cost = dataclasses.replace(cost, hold=HoldFirst(hold_first, lean, approach))
        stage = self.model.pose_stage if pose_stage is None else pose_stage
        if not (math.isfinite(stage) and stage >= 0):
            raise ValueError(f"pose_stage must be a non-negative number, got {stage!r}")
        if stage and not isinstance(cost, ManipulationCost):
            raise ValueError(f"pose_stage: {type(cost).__name__} has no pose terms to stage")
        radius = self.model.pose_stage_radius if pose_stage_radius is None else pose_stage_radius
        if not radius > 0:  # NaN included
            raise ValueError(f"pose_stage_radius must be a distance > 0 [m], got {radius!r}")
        if pose_stage_radius is not None and radius != math.inf and not stage:
            raise ValueError("pose_stage_radius: it confines the pose stage; set pose_stage")
        if stage:
            cost = dataclasses.replace(cost, stage=stage, stage_radius=radius)
        balance = self.model.balance if balance is None else balance
        if not (math.isfinite(balance) and balance >= 0):
            raise ValueError(f"balance must be a non-negative number, got {balance!r}")
        if balance and not isinstance(cost, ManipulationCost):
            raise ValueError(f"balance: {type(cost).__name__} has no balance term")
        found = balance and balance_of(plant, self.model.metric, self.model.balance_threshold)
        if found:  # objects with no base to stand on have no term
            cost = dataclasses.replace(cost, balance=found, balance_weight=balance)
        if self.model.tilt > 0 and tips_before_sliding(plant.object):
            cost = dataclasses.replace(cost, tilt=self.model.tilt)
        if self.model.contact_floor and isinstance(cost, ManipulationCost):
            floor = plant.support_height + plant.tip_clearance
            cost = dataclasses.replace(cost, contact_floor=floor)
        spread = self.model.contact_spread if spread is None else spread
        if spread and not isinstance(cost, ManipulationCost):
            raise ValueError(f"spread: {type(cost).__name__} has no contact term to spread")
        if spread:
            cost = dataclasses.replace(cost, contact_axis=long_half_axis(plant.object, spread))
        if (support or margin is not None) and plant.support_footprint is None:
            raise ValueError(f"support: {self.name}'s object rests on the ground, not on a body")
        margin = self.model.support_margin if margin is None else margin
        if support is None:
            support = margin is not None and plant.support_footprint is not None
        if not support:
            return cost
        x_min, y_min, x_max, y_max = plant.support_footprint
        margin = margin or 0.0
        region = (x_min + margin, y_min + margin, x_max - margin, y_max - margin)
        if not (margin >= 0 and region[0] < region[2] and region[1] < region[3]):
            raise ValueError(
                f"margin must be in [0, half the support's narrower side), got {margin!r}"
            )
        return dataclasses.replace(cost, support=region, support_weight=self.model.support_weight)

    def sample(self, plant: HandEnv, task: str, seed: int):
        return self._sample(plant, task, seed)


def sample_in_hand(plant: HandEnv, task: str, seed: int):
    """TriFinger in-hand: :func:`~torchcontact.environments.tasks.sample_in_hand`."""
    return tasks.sample_in_hand(plant.resting_pose, seed)


def sample_on_palm(plant: HandEnv, task: str, seed: int):
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
        # the binoculars tipped over when pushed; a tilt cost on every object costs precision
        tilt=100.0,
        object_mass=PAPER_OBJECT_MASS,
        # plates thinner than a tip's diameter: 4 → 14 of 14 tuning trials (docs/experiments.md)
        contact_floor=True,
        # a lone push tips them: 173 → 187 and 187 → 188 of 200 tuning trials (docs/experiments.md)
        hold_first=2,
        # unheld, only the contact term draws the tips in: 187 → 191 and 188 → 189 (same)
        hold_approach=4.0,
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
        # position weight 300, not the paper's 100: success counts orientation only, and with
        # 100 the MPC turned objects off the palm (docs/experiments.md, "TriFinger and Allegro MPC")
        cost=ManipulationCost(contact=1.0, grasp=0.0, control=0.1, position=300.0),
        object_mass=PAPER_OBJECT_MASS,
    ),
    "on-palm",
    tasks.ALLEGRO_SUCCESS,
    sample_on_palm,
    ALLEGRO_PRESETS,
    object_names(),
)
