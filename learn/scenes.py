"""The scenes transitions are collected in: a MuJoCo plant and the paper's model of it.

A :class:`Scene` pairs the simulated plant (which produces the data) with the quasi-dynamic
system, contact model, time step and joint layout the paper's MPC uses for that plant (which
the data are fitted to). ``make_scene("trifinger", "cube")`` builds one from the evaluation
suites of :mod:`torchcontact.mpc.suites`, so the learned model is the MPC's model.

The box-pushing scene (:mod:`torchcontact.experiments.box_pushing`) is not one of them: its
MuJoCo model is geometry for contact detection only (the bar has no actuator and MuJoCo never
steps it), so it has no plant whose transitions could be recorded. A bar servo plant in
:mod:`torchcontact.sim` would make it a scene here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchcontact.integrate import JointLayout
from torchcontact.model import ComplementarityFree
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.suites import SUITES
from torchcontact.sim.hands import HandEnv
from torchcontact.sim.plant import Plant
from torchcontact.systems import QuasiDynamic

SCENES = tuple(SUITES)
"""Scene names: ``"fingertips"``, ``"trifinger"`` and ``"allegro"``."""


@dataclass
class Scene:
    """A plant and the paper's MPC model of it.

    Attributes:
        name: the scene (one of :data:`SCENES`).
        object: the manipulated object's name.
        task: the suite task whose sampler gives initial and target poses.
        env: the MuJoCo plant; one ``env.step(u)`` is one model step.
        mpc: the paper's MPC for this plant (K, D, γ, facets, h, control box, cost).
    """

    name: str
    object: str
    task: str
    env: Plant
    mpc: ContactImplicitMPC

    @property
    def system(self) -> QuasiDynamic:
        """The quasi-dynamic system ``u ↦ (Q, b)`` of the model."""
        return self.mpc.system

    @property
    def model(self) -> ComplementarityFree:
        """The paper's contact model (constant K, D = 0.1·K, γ = 100, 4 facets)."""
        return self.mpc.model

    @property
    def h(self) -> float:
        """The model's time step [s]."""
        return self.mpc.h

    @property
    def layout(self) -> JointLayout:
        return self.mpc.layout

    @property
    def paper_stiffness(self) -> float:
        """The paper's constant K of this scene."""
        return SUITES[self.name].stiffness

    @property
    def control_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(n_u,), (n_u,)`` lower and upper bound of one step's control."""
        n_u = self.system.n_robot
        return self.mpc.lower[0, :n_u].numpy(), self.mpc.upper[0, :n_u].numpy()

    @property
    def control_dt(self) -> float:
        """Simulated time per step [s] (MuJoCo substeps × their time step)."""
        skip = self.env.hand.frame_skip if isinstance(self.env, HandEnv) else self.env.frame_skip
        return skip * float(self.env.model.opt.timestep)

    @property
    def pose_weights(self) -> tuple[float, float]:
        """The MPC's final-cost weights (position [1/m²], orientation) of the pose error."""
        return self.mpc.cost.position, self.mpc.cost.orientation

    def fingertips(self, q: torch.Tensor) -> torch.Tensor:
        """Fingertip positions ``(..., n_tips, 3)`` [m] of states ``q (..., nq)``."""
        return self.mpc.fingertips(q.to(self.mpc.dtype))

    def sample(self, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """Initial and target object poses ``(7,), (7,)`` of seed ``seed`` (the suite's)."""
        return SUITES[self.name].sample(self.env, self.task, self.object, seed)


def make_scene(name: str, obj: str = "cube", task: str | None = None, **mpc_options) -> Scene:
    """The plant of suite ``name`` with object ``obj`` and the paper's MPC of it.

    ``task`` defaults to the suite's first task defined for ``obj``; ``mpc_options`` go to
    the MPC (``max_iter``, ``compile``, ...).
    """
    if name not in SUITES:
        raise ValueError(f"name must be one of {SCENES}, got {name!r}")
    suite = SUITES[name]
    tasks = [t for t, o in suite.pairs if o == obj]
    if not tasks:
        raise ValueError(f"obj must be an object of the {name} suite {suite.objects}, got {obj!r}")
    if task is None:
        task = tasks[0]
    elif task not in tasks:
        raise ValueError(f"task must be one of {tasks} for {name} with {obj}, got {task!r}")
    env = suite.make_env(obj)
    mpc = suite.make_mpc(obj, suite.stiffness, **mpc_options)
    return Scene(name=name, object=obj, task=task, env=env, mpc=mpc)
