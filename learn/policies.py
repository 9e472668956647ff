"""Action sources for data collection: a random reach-and-push policy and the paper's MPC
(the manipulation scenes), random pushes (box pushing).

A policy is called as ``policy(q, contacts) -> u`` with the plant state ``q (nq,)`` and the
contacts detected there, and returns ``u (n_u,)`` inside the scene's control box. Both draw
from ``np.random.default_rng(seed)`` only, so a trajectory is reproducible from its seed.
"""

from __future__ import annotations

import numpy as np
import torch

from torchcontact.contacts import Contacts
from torchcontact.learn.scenes import BoxPushingScene, Scene
from torchcontact.rotations import quaternion_to_matrix

ACTIONS = ("random", "mpc", "mixed")
"""Action sources of a dataset; ``"mixed"`` alternates random (even ids) and MPC (odd ids)."""


class CorrelatedNoise:
    """Ornstein–Uhlenbeck exploration noise of standard deviation ``noise`` × the larger bound
    and step correlation ``correlation``, one value per control.

    Args:
        rng: the policy's random generator.
        lower, upper: ``(n_u,)`` the control box.
        noise: standard deviation as a fraction of the control bound.
        correlation: correlation between consecutive steps, in [0, 1).
    """

    def __init__(self, rng, lower: np.ndarray, upper: np.ndarray, noise: float, correlation: float):
        if not noise >= 0.0:
            raise ValueError(f"noise must be non-negative, got {noise!r}")
        if not 0.0 <= correlation < 1.0:
            raise ValueError(f"correlation must be in [0, 1), got {correlation!r}")
        self.rng, self.correlation = rng, correlation
        self.sigma = noise * np.maximum(np.abs(lower), np.abs(upper))
        self.state = np.zeros_like(lower, dtype=float)

    def __call__(self) -> np.ndarray:
        """The next noise sample ``(n_u,)``."""
        shock = self.rng.standard_normal(self.state.shape)
        self.state = self.correlation * self.state + np.sqrt(1 - self.correlation**2) * shock
        return self.sigma * self.state


class ReachPolicy:
    """Random reach and push: each fingertip heads for a random point of the object.

    Every 10–30 steps each fingertip gets a new goal fixed in the object's frame: with
    probability ``push`` a point inside the object's bounding box (the tip cannot reach it, so
    it keeps pushing the object, following it as it moves), otherwise a point 1.5 extents from
    the object's centre (the tip lets go). The joint step towards the goals is damped least
    squares through the fingertip Jacobian, plus Ornstein–Uhlenbeck noise of standard
    deviation ``noise`` × bound and step correlation ``correlation``, clipped to the box.

    Args:
        scene: the scene (its fingertip kinematics, control box and object shape).
        seed: seed of the policy's random draws.
        push: probability that a goal lies inside the object.
        noise: noise standard deviation as a fraction of the control bound.
        correlation: noise correlation between consecutive steps, in [0, 1).
    """

    segment = (10, 30)
    damping = 1e-4  # [m²] of the damped least squares

    def __init__(
        self,
        scene: Scene,
        seed: int,
        push: float = 0.8,
        noise: float = 0.3,
        correlation: float = 0.8,
    ):
        if not 0.0 <= push <= 1.0:
            raise ValueError(f"push must be in [0, 1], got {push!r}")
        self.scene, self.push = scene, push
        self.rng = np.random.default_rng(seed)
        self.lower, self.upper = scene.control_bounds
        self.noise = CorrelatedNoise(self.rng, self.lower, self.upper, noise, correlation)
        vertices = scene.plant.object.vertices
        self.box = vertices.min(0), vertices.max(0)
        self.n_tips = scene.fingertips(torch.as_tensor(scene.plant.state())).shape[-2]
        self.steps_left = 0
        self.goals = np.zeros((self.n_tips, 3))

    def _new_goals(self) -> None:
        low, high = self.box
        inside = self.rng.uniform(low, high, (self.n_tips, 3))
        direction = self.rng.standard_normal((self.n_tips, 3))
        direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
        outside = 0.5 * (low + high) + 1.5 * (high - low).max() * direction
        pushing = self.rng.uniform(size=(self.n_tips, 1)) < self.push
        self.goals = np.where(pushing, inside, outside)
        self.steps_left = int(self.rng.integers(*self.segment, endpoint=True))

    def __call__(self, q: np.ndarray, contacts: Contacts) -> np.ndarray:
        if self.steps_left == 0:
            self._new_goals()
        self.steps_left -= 1
        state = torch.as_tensor(q, dtype=torch.float64)
        rotation = quaternion_to_matrix(state[3:7]).numpy()
        goals = q[:3] + self.goals @ rotation.T  # (n_tips, 3) world [m]
        tips = self.scene.fingertips(state).detach().numpy()
        jac = torch.func.jacrev(lambda x: self.scene.fingertips(x).reshape(-1))(state)
        jac = jac[:, 7:].detach().numpy()  # (3·n_tips, n_u): robot coordinates only
        error = (goals - tips).reshape(-1)
        gram = jac @ jac.T + self.damping * np.eye(len(error))
        step = jac.T @ np.linalg.solve(gram, error)
        return np.clip(step + self.noise(), self.lower, self.upper)


class MPCPolicy:
    """The paper's MPC driving the object towards ``target``, plus Gaussian exploration noise.

    Args:
        scene: the scene whose MPC plans (its warm start is reset here).
        seed: seed of the noise.
        target: ``(7,)`` target object pose.
        noise: noise standard deviation as a fraction of the control bound (0: none).
    """

    def __init__(self, scene: Scene, seed: int, target: np.ndarray, noise: float = 0.1):
        if not noise >= 0.0:
            raise ValueError(f"noise must be non-negative, got {noise!r}")
        if scene.planner is None:
            raise ValueError("scene.planner must be set to collect MPC actions (see collect)")
        self.mpc = scene.planner
        self.mpc.reset()
        self.rng = np.random.default_rng(seed)
        self.lower, self.upper = scene.control_bounds
        self.sigma = noise * np.maximum(np.abs(self.lower), np.abs(self.upper))
        target = torch.as_tensor(target, dtype=self.mpc.dtype)
        self.target_p, self.target_quat = target[:3], target[3:]

    def __call__(self, q: np.ndarray, contacts: Contacts) -> np.ndarray:
        state = torch.as_tensor(q, dtype=self.mpc.dtype)
        plan = self.mpc.plan(state, contacts.to(self.mpc.dtype), self.target_p, self.target_quat)
        u = plan.control.numpy() + self.sigma * self.rng.standard_normal(self.sigma.shape)
        return np.clip(u, self.lower, self.upper)


class PushPolicy:
    """Random bar pushes: the experiment's push plus Ornstein–Uhlenbeck noise, in the box.

    Args:
        scene: the box-pushing scene (its nominal push and control box).
        seed: seed of the noise.
        noise: noise standard deviation as a fraction of the control bound.
        correlation: noise correlation between consecutive steps, in [0, 1).
    """

    def __init__(
        self, scene: BoxPushingScene, seed: int, noise: float = 0.3, correlation: float = 0.8
    ):
        self.lower, self.upper = scene.control_bounds
        self.nominal = np.array([scene.plant.config.push])
        rng = np.random.default_rng(seed)
        self.noise = CorrelatedNoise(rng, self.lower, self.upper, noise, correlation)

    def __call__(self, q: np.ndarray, contacts: Contacts) -> np.ndarray:
        return np.clip(self.nominal + self.noise(), self.lower, self.upper)


def make_policy(
    kind: str, scene: Scene | BoxPushingScene, seed: int, target: np.ndarray, noise=None
):
    """The policy of action source ``kind`` (``"random"`` or ``"mpc"``) for one trajectory.

    ``noise`` overrides the policy's default exploration noise (fraction of the bound).
    Box pushing has no MPC task: its only source is ``"random"`` (:class:`PushPolicy`).
    """
    options = {} if noise is None else {"noise": noise}
    if isinstance(scene, BoxPushingScene):
        if kind != "random":
            raise ValueError(f"box_pushing has no MPC task: actions must be 'random', got {kind!r}")
        return PushPolicy(scene, seed, **options)
    if kind == "random":
        return ReachPolicy(scene, seed, **options)
    if kind == "mpc":
        return MPCPolicy(scene, seed, target, **options)
    raise ValueError(f"kind must be 'random' or 'mpc', got {kind!r}")
