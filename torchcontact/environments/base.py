"""What an environment is: a plant factory and everything the MPC needs to model that plant.

An :class:`Environment` holds, for one robot: the plant of an object (MuJoCo), the robot's
fingertip kinematics, the joint layout of q (object block, robot block), the quasi-dynamic
system, the model's time step and control box, the cost, the tasks (pairs, sampler, success
criterion) and the solver presets. The built-in ones (``fingertips``, ``trifinger``,
``allegro``) are registered instances; :func:`~torchcontact.environments.custom.from_mjcf`
builds one for a user's robot the same way.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from torchcontact.environments import tasks
from torchcontact.environments.costs import Cost
from torchcontact.environments.options import CostOptions
from torchcontact.environments.presets import DEFAULT_PRESET, NAMES, MPCSettings
from torchcontact.integrate import JointLayout
from torchcontact.object_sources import expand_objects, sources_about
from torchcontact.objects import ObjectOptions
from torchcontact.shipped import shipped_environments
from torchcontact.sim.plant import Plant
from torchcontact.systems import GRAVITY, QuasiDynamic

BENCHMARK_COLLISION = "hull"
"""How the suites' objects collide by default: as their convex hulls, as the paper's objects
do (each is one mesh geom in its reference scenes, which MuJoCo collides through its hull).
With the cavities of the bowl, cup, mug and torus open, the TriFinger sampler can set such an
object down around a resting fingertip, which then stays caught (docs/experiments.md)."""

REFERENCE_MASS = 0.01
"""[kg] The object mass the paper's metrics εMₒ/h² are stated for (its 10 g objects)."""


@dataclass(frozen=True)
class ObjectModel:
    """The quasi-dynamic model of the object at its reference mass.

    Attributes:
        metric: diagonal of εMₒ/h² (translation [N/m] ×3, rotation [N·m/rad] ×3) for a
            :data:`REFERENCE_MASS` object; an object of mass m gets it scaled by
            m / :data:`REFERENCE_MASS`, and the weight m·g in b.
        robot_stiffness: Kᵣ of the quasi-dynamic robot.
        mass: the mass [kg] the model gives the object; None: the plant's object's.
    """

    metric: tuple[float, ...]
    robot_stiffness: float
    mass: float | None = None

    def system(self, plant_mass: float, n_robot: int) -> QuasiDynamic:
        """The system of a robot of ``n_robot`` joints and the object, whose mass is
        :attr:`mass` or else ``plant_mass`` [kg]."""
        mass = plant_mass if self.mass is None else self.mass
        scale = mass / REFERENCE_MASS
        return QuasiDynamic(
            object_metric=[value * scale for value in self.metric],
            robot_stiffness=self.robot_stiffness,
            object_force=[0.0, 0.0, -mass * GRAVITY, 0.0, 0.0, 0.0],
            n_robot=n_robot,
        )


class RobotTips(torch.nn.Module):
    """Fingertip positions ``(..., n_tips, 3)`` [m] of whole states ``q (..., nq)``: the robot's
    forward kinematics applied to the layout's robot block."""

    def __init__(self, robot: torch.nn.Module, layout: JointLayout):
        super().__init__()
        self.robot, self.layout = robot, layout

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        return self.robot(self.layout.robot(q))


class Environment:
    """One robot's experiments; subclasses define the plant and the per-plant model.

    Attributes:
        name: the environment (``torchcontact run NAME``).
        pairs: its (task, object) pairs.
        criterion: the success criterion of its tasks.
        stiffness: the paper's K (``learn-k`` collects its data with it).
        default_stiffness: the K ``torchcontact run`` plans with unless told otherwise.
        planner: the planner it plans with unless told otherwise (a name of
            :data:`~torchcontact.mpc.planners.PLANNERS`), the measured best.
        cost_defaults: the values of its cost's terms (:class:`~.options.CostOptions`) that
            a user does not set; None for a term its cost does not have (none by default).
        presets: solver settings by preset name (:data:`~.presets.NAMES`).
        user_meshes: whether an object may be a mesh file or a generated object.
        layout: the joints of q: the object's free joint (block ``object``), then the
            robot's (block ``robot``).
    """

    name: str
    pairs: tuple[tuple[str, str], ...]
    criterion: tasks.SuccessCriterion
    stiffness: float
    default_stiffness: float
    planner: str = "lbfgs"
    cost_defaults: CostOptions = CostOptions()
    presets: Mapping[str, MPCSettings]
    user_meshes: bool = True
    layout: JointLayout

    # --- what subclasses define ----------------------------------------------------------

    def make_plant(
        self, obj, collision: str = BENCHMARK_COLLISION, options: ObjectOptions | None = None
    ) -> Plant:
        """The MuJoCo plant of object ``obj`` (a built-in name, or where :attr:`user_meshes` a
        generated object ``"random-SEED"`` or a mesh file), colliding as ``collision``, with
        the size, mass and friction ``options`` set (None: the scene's)."""
        raise NotImplementedError

    def robot(self, dtype: torch.dtype = torch.float64) -> torch.nn.Module:
        """Forward kinematics ``joints (..., n_joints) ↦ tips (..., n_tips, 3)`` [m]."""
        raise NotImplementedError

    def object_model(self, plant: Plant) -> ObjectModel:
        """The object's metric and the robot's stiffness in the model of ``plant``."""
        raise NotImplementedError

    def h(self, plant: Plant) -> float:
        """The model's time step [s] for ``plant``."""
        raise NotImplementedError

    def control_bound(self, plant: Plant) -> float:
        """|u| per control element and step (rad or m)."""
        raise NotImplementedError

    def cost(self, plant: Plant, options: CostOptions | None = None) -> Cost:
        """The MPC cost for ``plant`` (see :class:`~torchcontact.environments.costs.Cost`)
        with the terms ``options`` sets (:class:`~torchcontact.environments.options.
        CostOptions`, hands only; None or a None field: the environment's)."""
        raise NotImplementedError

    def describe(self, plant: Plant) -> list[str]:
        """Lines for a run's header on what the environment derived for ``plant`` (none)."""
        return []

    def sample(self, plant: Plant, task: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """Initial and target object poses ``(7,), (7,)`` of trial ``seed`` of ``task``."""
        raise NotImplementedError

    # --- derived -------------------------------------------------------------------------

    def system(self, plant: Plant) -> QuasiDynamic:
        """The quasi-dynamic system of ``plant`` (with its object's mass, unless the
        environment's model fixes one)."""
        n_robot = self.layout.nv - 6
        return self.object_model(plant).system(float(plant.object.mass), n_robot)

    def fingertips(self, dtype: torch.dtype = torch.float64) -> RobotTips:
        """Fingertip positions ``(..., n_tips, 3)`` [m] of states ``q (..., nq)``."""
        return RobotTips(self.robot(dtype), self.layout)

    def aim(self, plant: Plant, target: np.ndarray) -> np.ndarray:
        """The ``(7,)`` pose the MPC plans toward for ``target (7,)``:
        :func:`~torchcontact.environments.tasks.aim_pose` with the plant's resting height."""
        resting = plant.resting_height(target[3:])
        return tasks.aim_pose(target, resting, self.criterion.position_tolerance)

    @property
    def ships_model(self) -> bool:
        """Whether the package ships a learned model of this environment, the MPC's default
        (:mod:`torchcontact.shipped`)."""
        return self.name in shipped_environments()

    @property
    def tasks(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(task for task, _ in self.pairs))

    @property
    def objects(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(obj for _, obj in self.pairs))

    def preset(self, name: str = DEFAULT_PRESET) -> MPCSettings:
        """The solver settings of preset ``name`` (one of :data:`~.presets.NAMES`)."""
        if name not in NAMES:
            raise ValueError(f"preset must be one of {NAMES}, got {name!r}")
        return self.presets[name]

    def select(self, task: str, obj: str) -> list[tuple[str, str]]:
        """The pairs matching ``task`` and ``obj`` (each a name or ``"all"``; where
        :attr:`user_meshes`, ``obj`` may also name objects of a registered source, see
        :mod:`torchcontact.object_sources`: a mesh path, a generated object ``"random-SEED"``
        or a set of them, ``"random:N"`` or ``"random:A-B"``, a user's ``"PREFIX:NAME"``);
        a comma-separated list of these takes their union in order
        (``"cube,random-7,random:0-9"``). Raises ``ValueError`` naming the bad option."""
        if "," in obj and not Path(obj).is_file():  # a mesh file's name may hold a comma
            parts = [self.select(task, part.strip()) for part in obj.split(",")]
            return list(dict.fromkeys(pair for part in parts for pair in part))
        if task not in ("all", *self.tasks):
            raise ValueError(f"--task must be one of {self.tasks} or 'all', got {task!r}")
        if self.user_meshes and obj not in self.objects:
            objects = self._user_objects(obj)
            if objects:
                return [(t, o) for o in objects for t in self.tasks if task in ("all", t)]
        if obj not in ("all", *self.objects):
            also = f"; {sources_about()}" if self.user_meshes else ""
            raise ValueError(f"--object must be one of {self.objects}, 'all'{also}, got {obj!r}")
        pairs = [(t, o) for t, o in self.pairs if task in ("all", t) and obj in ("all", o)]
        if not pairs:
            raise ValueError(f"{self.name} has no task {task!r} with object {obj!r}")
        return pairs

    @staticmethod
    def _user_objects(obj: str) -> list[str]:
        """The objects ``obj`` names through a registered source; none where no source claims
        it."""
        try:
            return expand_objects(obj) or []
        except ValueError as error:
            message = str(error)  # named as the option, as select's other refusals are
            named = message.startswith("object ")
            raise ValueError(f"--{message}" if named else f"--object: {message}") from None

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"
