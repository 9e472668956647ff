"""The evaluation suites: for each environment, its tasks, objects, plant, MPC and sampler.

``torchcontact run ENV`` looks its suite up here by name, so the evaluation loop
(:mod:`torchcontact.mpc.evaluate`) is written once for the fingertips and both hands.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from torchcontact.environments import tasks
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.fingertips import PAPER_STIFFNESS, STIFFNESS, fingertips_mpc
from torchcontact.mpc.hands import MPC_SETTINGS, hand_mpc
from torchcontact.sim.fingertips import FingertipsEnv
from torchcontact.sim.hands import HANDS, HandEnv
from torchcontact.sim.objects import ObjectMesh, object_names

BENCHMARK_COLLISION = "hull"
"""How the suites' objects collide by default: as their convex hulls, as the paper's objects
do (each is one mesh geom in its reference scenes, which MuJoCo collides through its hull).
With the cavities of the bowl, cup, mug and torus open (``"auto"``), the TriFinger sampler can
set such an object down around a resting fingertip, which then stays caught in the cup or
the torus' tube: each of their failed trials started so (docs/journal.md, session 9)."""

SCENES_VERSION = 7
"""Version of the plants, samplers and MPC costs, stored with every trial record so that a
resumed sweep reruns trials from older versions. 2: object poses at the box centre (bunny and
cup lower, as the reference's meshes), the reference scenes' per-object friction, Allegro sizes
and placements. 3: the rubber duck and the teapot stand on flat bases (their round bottoms
rolled them off the upright resting pose the samplers assume); the TriFinger MPC's tilt
cost on objects that tip before they slide. 4: the Allegro MPC's final position weight 300
(the paper's 100 let it turn objects off the palm); the TriFinger's contacts are detected
5 mm before touch (``Hand.contact_margin``). 5: the Allegro's links collide with each other
and with the palm, as on the real hand (Menagerie's and the reference's models). 6: the MPC
plans toward :func:`~torchcontact.environments.tasks.aim_pose`, flip targets raised out of the
ground.
7: the stick is a rod with an elliptic section and rounded ends, as the paper's mesh."""


@dataclass(frozen=True)
class Suite:
    """One environment's experiments.

    Attributes:
        name: the environment (``torchcontact run NAME``).
        pairs: the paper's (task, object) pairs.
        criterion: success criterion of its tasks.
        stiffness: the paper's K for its MPC (``learn-k`` collects its data with it).
        default_stiffness: the K ``torchcontact run`` plans with unless told otherwise.
        user_meshes: whether ``--object`` may be a mesh file (run on every task).
        make_env: ``(obj, collision=BENCHMARK_COLLISION) ↦`` plant, with contacts beyond the
            slots truncated to the deepest; ``collision`` how the object collides (see
            :func:`torchcontact.sim.objects.make_object`).
        make_mpc: ``(obj, stiffness, plant=None, **options) ↦`` :class:`ContactImplicitMPC`;
            ``plant``, the :attr:`make_env` plant it will control, lends the hands' MPC its
            object (else built once more, cached per process); ``options`` are ``model`` and
            ``relaxation`` (see :func:`torchcontact.mpc.controller.mpc_model`) and the
            controller's.
        sample: ``(env, task, obj, seed) ↦`` initial and target poses ``(7,), (7,)``.
    """

    name: str
    pairs: tuple[tuple[str, str], ...]
    criterion: tasks.SuccessCriterion
    stiffness: float
    default_stiffness: float
    user_meshes: bool
    make_env: Callable
    make_mpc: Callable[..., ContactImplicitMPC]
    sample: Callable[..., tuple[np.ndarray, np.ndarray]]

    @property
    def tasks(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(task for task, _ in self.pairs))

    @property
    def objects(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(obj for _, obj in self.pairs))

    def aim(self, env, target: np.ndarray) -> np.ndarray:
        """The ``(7,)`` pose the MPC plans toward for ``target (7,)`` in plant ``env``:
        :func:`~torchcontact.environments.tasks.aim_pose` with the plant's resting height and the
        suite's position tolerance."""
        resting = env.resting_height(target[3:])
        return tasks.aim_pose(target, resting, self.criterion.position_tolerance)

    def select(self, task: str, obj: str) -> list[tuple[str, str]]:
        """The pairs matching ``task`` and ``obj`` (each a name or ``"all"``; ``obj`` may be a
        mesh path where :attr:`user_meshes`). Raises ``ValueError`` naming the bad option."""
        if task not in ("all", *self.tasks):
            raise ValueError(f"--task must be one of {self.tasks} or 'all', got {task!r}")
        if self.user_meshes and obj not in self.objects and Path(obj).suffix:
            if not Path(obj).is_file():
                raise ValueError(f"--object must be an existing mesh file, got {obj!r}")
            return [(t, obj) for t in self.tasks if task in ("all", t)]
        if obj not in ("all", *self.objects):
            raise ValueError(f"--object must be one of {self.objects} or 'all', got {obj!r}")
        pairs = [(t, o) for t, o in self.pairs if task in ("all", t) and obj in ("all", o)]
        if not pairs:
            raise ValueError(f"the paper has no task {task!r} with object {obj!r}")
        return pairs


def _fingertips_env(obj: str, collision: str = BENCHMARK_COLLISION) -> FingertipsEnv:
    settings = tasks.OBJECT_SETTINGS[obj]
    return FingertipsEnv(
        obj,
        object_friction=settings.object_friction,
        contact_slots=settings.contact_slots,
        overflow="deepest",
        collision=collision,
    )


@functools.lru_cache(maxsize=4)
def _hand_object(hand: str, obj: str) -> ObjectMesh:
    """The object as the suite's :class:`HandEnv` builds it, for an MPC made without its
    plant (cached per process: a user mesh is loaded and decomposed again)."""
    return HANDS[hand].object_mesh(obj)


def _fingertips_mpc(obj: str, stiffness, plant=None, **options) -> ContactImplicitMPC:
    """:func:`fingertips_mpc`, whose settings come from the object's name alone (no plant)."""
    return fingertips_mpc(obj, stiffness, **options)


def _hand_suite(hand: str, task: str, criterion: tasks.SuccessCriterion, sample) -> Suite:
    """The suite of ``hand``: its one ``task`` on each of the 17 objects or a user mesh."""

    def make_mpc(
        obj: str, stiffness: float | None, plant: HandEnv | None = None, **options
    ) -> ContactImplicitMPC:
        mesh = _hand_object(hand, obj) if plant is None else plant.object
        return hand_mpc(hand, stiffness=stiffness, obj=mesh, **options)

    return Suite(
        name=hand,
        pairs=tuple((task, obj) for obj in object_names()),
        criterion=criterion,
        stiffness=MPC_SETTINGS[hand].stiffness,
        default_stiffness=MPC_SETTINGS[hand].stiffness,
        user_meshes=True,
        make_env=lambda obj, collision=BENCHMARK_COLLISION: HandEnv(
            hand, obj, overflow="deepest", collision=collision
        ),
        make_mpc=make_mpc,
        sample=sample,
    )


SUITES: dict[str, Suite] = {
    "fingertips": Suite(
        name="fingertips",
        pairs=tasks.PAPER_PAIRS,
        criterion=tasks.FINGERTIPS_SUCCESS,
        stiffness=PAPER_STIFFNESS,
        default_stiffness=STIFFNESS,
        user_meshes=False,
        make_env=_fingertips_env,
        make_mpc=_fingertips_mpc,
        sample=lambda env, task, obj, seed: tasks.sample(task, obj, seed),
    ),
    "trifinger": _hand_suite(
        "trifinger",
        "in-hand",
        tasks.TRIFINGER_SUCCESS,
        lambda env, task, obj, seed: tasks.sample_in_hand(env.resting_pose, seed),
    ),
    "allegro": _hand_suite(
        "allegro",
        "on-palm",
        tasks.ALLEGRO_SUCCESS,
        lambda env, task, obj, seed: tasks.sample_on_palm(
            env.resting_pose,
            *tasks.ON_PALM_PLACEMENTS.get(obj, (env.support_centre, env.support_centre)),
            seed=seed,
            yaw_range=tasks.ON_PALM_OBJECT_YAW_RANGES.get(obj, tasks.ON_PALM_YAW_RANGE),
        ),
    ),
}
