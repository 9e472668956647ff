"""The scenes transitions are collected in: a MuJoCo plant and the paper's model of it.

A :class:`Scene` pairs the simulated plant (which produces the data) with the quasi-dynamic
system, contact model, time step and joint layout of its environment's model (which the data
are fitted to). ``make_scene("trifinger", "cube")`` builds one from the registered
environment (:mod:`torchcontact.environments`), so the learned model is the MPC's model.
Collecting with MPC actions needs a planner, which the caller attaches (``scene.planner``):
learning does not depend on the MPC package.

``make_scene("box_pushing")`` is the paper's box-pushing scene (a bar pushing a row of 10
cubes, :mod:`torchcontact.sim.box_pushing`) as a data source: its plant drives the bar
kinematically (:class:`~torchcontact.sim.box_pushing.BoxPushingPlant`) and its model is the
experiment's quasi-dynamic system with the CF model at K = 1, exact ``max(·, 0)``. It has no
manipulation task and so no MPC: its actions are random pushes.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import torch

from torchcontact.environments import ENVIRONMENTS, environment
from torchcontact.environments.base import Environment
from torchcontact.integrate import JointLayout
from torchcontact.model import ComplementarityFree, paper_model
from torchcontact.sim import box_pushing as bp
from torchcontact.sim.box_pushing import BoxPushingPlant
from torchcontact.sim.hands import HandPlant
from torchcontact.sim.plant import Plant
from torchcontact.stiffness import Constant, Relative
from torchcontact.systems import QuasiDynamic

BOX_PUSHING = "box_pushing"
SCENES = (*ENVIRONMENTS, BOX_PUSHING)
"""Scene names: ``"fingertips"``, ``"trifinger"``, ``"allegro"`` and ``"box_pushing"``."""


@dataclass
class Scene:
    """A plant and its environment's model of it.

    Attributes:
        name: the scene (one of :data:`SCENES`).
        object: the manipulated object's name.
        task: the environment's task whose sampler gives initial and target poses.
        environment: the environment description.
        plant: the MuJoCo plant; one ``plant.step(u)`` is one model step.
        model: the paper's contact model (constant K, D = 0.1·K, γ = 100, 4 facets).
        planner: what plans MPC actions (``plan(q, contacts, target_p, target_quat)`` with
            a ``.control``, ``reset()``, ``dtype``), attached by the caller; None: none.
    """

    name: str
    object: str
    task: str
    environment: Environment
    plant: Plant
    model: ComplementarityFree
    planner: object | None = None

    @property
    def system(self) -> QuasiDynamic:
        """The quasi-dynamic system ``u ↦ (Q, b)`` of the model."""
        return self.environment.system(self.plant)

    @property
    def h(self) -> float:
        """The model's time step [s]."""
        return self.environment.h(self.plant)

    @property
    def layout(self) -> JointLayout:
        return self.environment.layout

    @property
    def paper_stiffness(self) -> float:
        """The paper's constant K of this scene."""
        return self.environment.stiffness

    @property
    def control_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(n_u,), (n_u,)`` lower and upper bound of one step's control."""
        bound = np.full(self.system.n_robot, self.environment.control_bound(self.plant))
        return -bound, bound

    @property
    def control_dt(self) -> float:
        """Simulated time per step [s] (MuJoCo substeps × their time step)."""
        plant = self.plant
        skip = plant.hand.frame_skip if isinstance(plant, HandPlant) else plant.frame_skip
        return skip * float(plant.model.opt.timestep)

    @property
    def pose_weights(self) -> tuple[float, float]:
        """The MPC's final-cost weights (position [1/m²], orientation) of the pose error."""
        cost = self.environment.cost(self.plant)
        return cost.position, cost.orientation

    @functools.cached_property
    def _fingertips(self) -> torch.nn.Module:
        return self.environment.fingertips(torch.float64)

    def fingertips(self, q: torch.Tensor) -> torch.Tensor:
        """Fingertip positions ``(..., n_tips, 3)`` [m] of states ``q (..., nq)`` (float64)."""
        return self._fingertips(q.to(torch.float64))

    def sample(self, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """Initial and target object poses ``(7,), (7,)`` of seed ``seed``."""
        return self.environment.sample(self.plant, self.task, seed)


@dataclass
class BoxPushingScene:
    """The box-pushing plant and the experiment's model of it (the attributes of
    :class:`Scene` that data collection and fitting read; there is no ``mpc``).

    Attributes:
        name: ``"box_pushing"``; object: ``"cube"``; task: ``"push"``.
        plant: the plant; one ``plant.step(u)`` moves the bar by ``u`` [m] in one model step.
        system: the quasi-dynamic system (ε = 40, Kᵣ = 500 N/m, the cubes' gravity).
        model: CF at the experiment's K = 1, D = 0.1·K (as the MPC scenes), exact max.
        layout: the cubes' free joints, then the bar's slide joint.
        h: the model's time step [s].
    """

    name: str
    object: str
    task: str
    plant: BoxPushingPlant
    system: QuasiDynamic
    model: ComplementarityFree
    layout: JointLayout
    h: float

    jitter = (0.002, 0.003, 0.1)
    """Half-widths of the uniform perturbation of each cube's x, y [m] and yaw [rad]."""
    pose_weights = (500.0, 5.0)
    """Position [1/m²] and orientation weights of the combined pose error (the MPC scenes')."""

    @property
    def paper_stiffness(self) -> float:
        """The box-pushing experiment's K."""
        return self.plant.config.contact_stiffness

    @property
    def control_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The bar moves towards the cubes by 0 to twice the experiment's push per step [m]."""
        return np.array([2 * min(self.plant.config.push, 0.0)]), np.array([0.0])

    @property
    def control_dt(self) -> float:
        return self.plant.frame_skip * float(self.plant.model.opt.timestep)

    def sample(self, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """The row of cubes, each shifted and turned at random (:attr:`jitter`), at rest; the
        second pose (unused: the scene has no goal) is the first cube's."""
        rng = np.random.default_rng(seed)
        q = self.plant.initial_state
        dx, dy, yaw = self.jitter
        for i in range(self.plant.config.cubes):
            at = 7 * i  # the cubes' free joints come first in q
            q[at : at + 2] += rng.uniform([-dx, -dy], [dx, dy])
            angle = rng.uniform(-yaw, yaw)
            q[at + 3 : at + 7] = [np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)]
        return q, q[:7].copy()


def box_pushing_scene(config: bp.BoxPushingConfig | None = None) -> BoxPushingScene:
    """The box-pushing scene of ``config`` (default: the experiment's 10 cubes)."""
    config = bp.BoxPushingConfig() if config is None else config
    built = bp.build_scene(config)
    model = ComplementarityFree(
        Constant(config.contact_stiffness, learnable=False),
        Relative(0.1, learnable=False),
        gamma=config.gamma,
        facets=config.facets,
    )
    return BoxPushingScene(
        name=BOX_PUSHING,
        object="cube",
        task="push",
        plant=BoxPushingPlant(config),
        system=built.system,
        model=model,
        layout=built.layout,
        h=config.h,
    )


def make_scene(name: str, obj: str = "cube", task: str | None = None) -> Scene | BoxPushingScene:
    """The plant of environment ``name`` with object ``obj`` and the paper's model of it, or
    the box-pushing scene (object ``"cube"``, task ``"push"``, no MPC).

    ``obj`` may also be a generated object ``"random-SEED"`` or a mesh file where the
    environment takes them (the hands). ``task`` defaults to the environment's first task
    defined for ``obj``.
    """
    if name == BOX_PUSHING:
        if obj != "cube" or task not in (None, "push"):
            raise ValueError(
                f"box_pushing has object 'cube' and task 'push' only, got {obj!r}, {task!r}"
            )
        return box_pushing_scene()
    if name not in ENVIRONMENTS:
        raise ValueError(f"name must be one of {SCENES}, got {name!r}")
    env = environment(name)
    try:  # a built-in object, or where the environment takes them a generated one or a mesh
        pairs = env.select("all", obj) if obj != "all" else []
    except ValueError:
        pairs = []
    tasks = [t for t, _ in pairs]
    if len({o for _, o in pairs}) != 1:
        extra = ", a generated object random-SEED or a mesh file" if env.user_meshes else ""
        raise ValueError(
            f"obj must be an object of the {name} suite {env.objects}{extra}, got {obj!r}"
        )
    if task is None:
        task = tasks[0]
    elif task not in tasks:
        raise ValueError(f"task must be one of {tasks} for {name} with {obj}, got {task!r}")
    plant = env.make_plant(obj)
    return Scene(name, obj, task, env, plant, paper_model(env.stiffness))
