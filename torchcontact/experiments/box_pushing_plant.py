"""MuJoCo plant of the box-pushing scene: the bar driven kinematically, the cubes simulated.

The experiment's MJCF (:func:`~torchcontact.experiments.box_pushing.scene_xml`) at a MuJoCo
time step of ``h/substeps``, every geom's sliding friction set to the experiment's μ. One
:meth:`BoxPushingPlant.step` is one model step h: before every substep the bar's x is set on
the straight line from its start to ``x + u`` and its velocity to ``u/h``, so the cubes meet a
bar that moves exactly as commanded (the quasi-dynamic model's robot, ``Kᵣ → ∞``); the cubes
answer through MuJoCo's contact dynamics. Data collection (:mod:`torchcontact.learn`) and the
trade-off benchmark's reference rollouts use it.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from torchcontact.contacts import Contacts
from torchcontact.experiments.box_pushing import BoxPushingConfig, scene_xml
from torchcontact.sim import ContactDetector


class BoxPushingPlant:
    """The box-pushing scene simulated by MuJoCo, one model step per :meth:`step`.

    Args:
        config: the scene's constants (cubes, h, μ, detection margin, ...).
        substeps: MuJoCo steps per model step.

    Attributes:
        model, data: the MuJoCo scene (q: the cubes' free joints, then the bar's x).
        detector: cube contacts (ground, neighbours, bar) in ``config.slots`` slots, the
            deepest kept if more are found (predicted states may interpenetrate).
        frame_skip: ``substeps``.
    """

    def __init__(self, config: BoxPushingConfig | None = None, substeps: int = 10):
        config = BoxPushingConfig() if config is None else config
        if not isinstance(substeps, int) or substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
        self.config, self.frame_skip = config, substeps
        self.model = mujoco.MjModel.from_xml_string(scene_xml(config))
        self.model.opt.timestep = config.h / substeps
        self.model.geom_friction[:, 0] = config.mu
        self.data = mujoco.MjData(self.model)
        joint = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, "bar")
        self.bar_q = int(self.model.jnt_qposadr[joint])
        self.bar_v = int(self.model.jnt_dofadr[joint])
        self.detector = ContactDetector(
            self.model,
            bodies=[f"cube{i}" for i in range(config.cubes)],
            slots=config.slots,
            mu=config.mu,
            margin=config.margin,
            overflow="deepest",
        )

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    @property
    def initial_state(self) -> np.ndarray:
        """``(nq,)`` the MJCF's configuration: the cubes at rest in a row, the bar behind."""
        return self.model.qpos0.copy()

    def reset(self, initial, target=None) -> None:
        """Start from the configuration ``initial (nq,)`` at rest (``target`` is unused: the
        scene has no goal)."""
        q = np.asarray(initial, dtype=np.float64)
        if q.shape != (self.nq,) or not np.all(np.isfinite(q)):
            raise ValueError(f"initial must be {self.nq} finite numbers, got shape {q.shape}")
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = q
        mujoco.mj_forward(self.model, self.data)

    def state(self) -> np.ndarray:
        """``(nq,)`` copy of q."""
        return self.data.qpos.copy()

    def step(self, u) -> np.ndarray:
        """Move the bar by ``u (1,)`` [m] over one model step; returns the new ``q (nq,)``."""
        u = np.asarray(u, dtype=np.float64).reshape(-1)
        if u.shape != (1,) or not np.isfinite(u[0]):
            raise ValueError(f"u must be one finite bar displacement [m], got {u!r}")
        x0, push = float(self.data.qpos[self.bar_q]), float(u[0])
        for sub in range(self.frame_skip):
            self.data.qpos[self.bar_q] = x0 + push * sub / self.frame_skip
            self.data.qvel[self.bar_v] = push / self.config.h
            mujoco.mj_step(self.model, self.data)
        self.data.qpos[self.bar_q] = x0 + push  # exactly where it was sent
        self.data.qvel[self.bar_v] = 0.0
        mujoco.mj_forward(self.model, self.data)
        return self.state()

    def contacts(self, dtype: torch.dtype | None = None) -> Contacts:
        """The cubes' contacts at the current state."""
        contacts = self.detector(self.data.qpos)
        return contacts if dtype is None else contacts.to(dtype)
