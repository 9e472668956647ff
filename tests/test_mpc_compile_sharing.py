"""One compiled MPC graph per environment: every object's contacts are padded to the plant's
slot capacity, so objects of other detected slot counts reuse the graph compiled first."""

import warnings

import numpy as np
import pytest
import torch

from torchcontact.environments import environment
from torchcontact.environments.presets import MPCSettings
from torchcontact.mpc.controller import CONTACT_BUCKET, ContactImplicitMPC
from torchcontact.sim.fingertips import INITIAL_TIPS, TIP_RADIUS

DT = torch.float64
SMALL = {"horizon": 2, "max_iter": 8}
"""A short solve: the settings of the controller tests' compiled plans, whose graph they share."""


def _mpc(env, plant, compile: bool = False, **options) -> ContactImplicitMPC:
    """``env``'s MPC of ``plant`` through the paper's model, with the :data:`SMALL` solve."""
    settings = MPCSettings(compile=compile, dtype="float64", **{**SMALL, **options})
    return ContactImplicitMPC.from_env(env, plant, "paper", settings=settings)


def _target(plant) -> tuple[torch.Tensor, torch.Tensor]:
    """A target 2 cm beside the object, turned a quarter about z."""
    position = torch.as_tensor(plant.state()[:3]) + torch.tensor([0.02, 0.01, 0.0])
    return position.to(DT), torch.tensor([0.7071, 0.0, 0.0, 0.7071], dtype=DT)


@pytest.mark.parametrize(
    ("name", "objects"),
    [
        ("fingertips", ("cube", "bunny")),  # 8 and 12 detected slots
        ("trifinger", ("stick", "random-16")),  # 10 and 11, both held first
        ("allegro", ("cube", "stick")),  # 16 and 20
    ],
)
def test_objects_of_other_slot_counts_share_one_graph_key(name, objects):
    """Objects whose detections differ in slot count are padded to the plant's capacity, so
    their solves have one shape and one graph key (what a background compile is marked by),
    where rounding each to a multiple of CONTACT_BUCKET gave the Allegro's two their own."""
    env = environment(name)
    plants = [env.make_plant(obj) for obj in objects]
    detected = [plant.detector.slots for plant in plants]
    assert len(set(detected)) == 2
    mpcs = [_mpc(env, plant) for plant in plants]
    capacity = plants[0].contact_capacity
    assert capacity == plants[1].contact_capacity and capacity >= max(detected)
    assert [mpc.padded_slots(n) for mpc, n in zip(mpcs, detected, strict=True)] == [capacity] * 2
    shapes = [plant.contacts(DT).padded(capacity) for plant in plants]
    keys = {mpc._graph_key(contacts) for mpc, contacts in zip(mpcs, shapes, strict=True)}
    assert len(keys) == 1


def test_contacts_over_the_capacity_take_their_bucket_with_a_warning():
    """A user's object that needs more slots than the capacity still plans, padded to its
    multiple of CONTACT_BUCKET (a graph of its own), with a warning once per slot count."""
    env = environment("fingertips")
    plant = env.make_plant("cube")
    mpc = _mpc(env, plant)
    assert mpc.contact_slots == plant.contact_capacity == 12
    assert mpc.padded_slots(3) == mpc.padded_slots(12) == 12
    with pytest.warns(UserWarning, match="13 contact slots exceed the MPC's capacity of 12"):
        assert mpc.padded_slots(13) == 16
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert mpc.padded_slots(13) == 16  # no second warning
    unbounded = ContactImplicitMPC(
        mpc.system, mpc.model, mpc.layout, mpc.fingertips, mpc.cost, -0.01, 0.01
    )
    assert unbounded.contact_slots is None
    assert [unbounded.padded_slots(n) for n in (8, 10, 13)] == [8, 12, 16]
    for bad in (0, 2.0, True):
        with pytest.raises(ValueError, match="contact_slots"):
            ContactImplicitMPC(
                mpc.system, mpc.model, mpc.layout, mpc.fingertips, mpc.cost, -0.01, 0.01,
                contact_slots=bad,
            )  # fmt: skip


def _states(env, plant, seed: int, steps: int = 2) -> list[np.ndarray]:
    """States ``(nq,)`` with contacts: for the fingertips, the object 0.5 mm into the ground
    with tip 0, then also tip 1, pressed 1 mm into its +x and +y sides; for a hand, the sampled
    start of a trial (the object on the palm) and the states after ``steps`` MPC steps."""
    if env.name == "fingertips":
        low, high = plant.object.vertices.min(0), plant.object.vertices.max(0)
        pose = np.array([0.0, 0.0, plant.object.resting_height() - 5e-4, 1.0, 0.0, 0.0, 0.0])
        z = max(0.5 * (low[2] + high[2]) + pose[2], TIP_RADIUS)
        press = TIP_RADIUS - 1e-3
        tips = INITIAL_TIPS.copy()
        tips[:3] = (high[0] + press, 0.0, z)
        first = np.concatenate([pose, tips])
        tips[3:6] = (0.0, high[1] + press, z)
        return [first, np.concatenate([pose, tips])]
    initial, target = env.sample(plant, env.pairs[0][0], seed)
    plant.reset(initial, target)
    mpc = _mpc(env, plant)
    states = [plant.state()]
    for _ in range(steps):
        q = torch.as_tensor(plant.state())
        plan = mpc.plan(q, plant.contacts(DT), *_target(plant))
        plant.step(plan.control.numpy())
        states.append(plant.state())
    return states


@pytest.mark.parametrize(
    ("name", "obj"),
    [("fingertips", "cube"), ("fingertips", "stick"), ("allegro", "cube"), ("allegro", "stick")],
)
def test_padding_to_the_capacity_leaves_the_plan_unchanged(name, obj):
    """Plans padded to the capacity (the fingertips' 8-slot cube and stick to 12, the
    Allegro's 16- and 20-slot cube and stick to 36) equal those padded to the slots' multiple
    of CONTACT_BUCKET, as before, up to rounding (float64), warm start after warm start: a
    padding row is zero in J̃ and Jⁿ, so it changes no velocity, and the costs read no rows."""
    env = environment(name)
    plant = env.make_plant(obj)
    capacity, detected = plant.contact_capacity, plant.detector.slots
    assert capacity > -(-detected // CONTACT_BUCKET) * CONTACT_BUCKET
    padded, bucketed = _mpc(env, plant), _mpc(env, plant)
    bucketed.contact_slots = None  # each solve to its multiple of CONTACT_BUCKET, as before
    for state in _states(env, plant, seed=1):
        robot = {"tips" if name == "fingertips" else "joints": state[7:]}
        plant.reset(state[:7], **robot)
        contacts = plant.contacts(DT)
        assert int(contacts.n_active()) > 0
        q, target = torch.as_tensor(state), _target(plant)
        for _ in range(2):  # the second warm-started from the first
            expected, plan = bucketed.plan(q, contacts, *target), padded.plan(q, contacts, *target)
            torch.testing.assert_close(plan.controls, expected.controls, rtol=0, atol=1e-12)
            assert plan.iterations == expected.iterations > 0


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
def test_a_second_object_of_another_slot_count_reuses_the_compiled_graph():
    """Counted compiles: the fingertips' cube (8 detected slots) compiles the MPC's graphs;
    the bunny (12 slots, a second MPC) then plans compiled from its first step with no graph
    compiled for it (Dynamo's count of compiled graphs is unchanged), as the same plan eager."""
    from torch._dynamo.utils import counters

    env = environment("fingertips")
    cube, bunny = env.make_plant("cube"), env.make_plant("bunny")
    assert (cube.detector.slots, bunny.detector.slots) == (8, 12)
    plan = _mpc(env, cube, compile=True).plan(
        torch.as_tensor(cube.state()), cube.contacts(DT), *_target(cube)
    )
    assert plan.compiled
    compiled_graphs = counters["stats"]["unique_graphs"]
    assert compiled_graphs > 0
    mpc, eager = _mpc(env, bunny, compile=True), _mpc(env, bunny)
    q, contacts = torch.as_tensor(bunny.state()), bunny.contacts(DT)
    for _ in range(2):
        plan, expected = (
            mpc.plan(q, contacts, *_target(bunny)),
            eager.plan(q, contacts, *_target(bunny)),
        )
        assert plan.compiled
        torch.testing.assert_close(plan.controls, expected.controls, rtol=0, atol=1e-10)
    assert counters["stats"]["unique_graphs"] == compiled_graphs


def test_objects_that_tip_and_objects_that_slide_share_one_graph_key():
    """The TriFinger's tilt term and hold switch per object by tensor inputs, not by the cost's
    settings: the cube (slides) and the stick (tips before it slides) plan through one graph,
    and the switches say which terms apply."""
    env = environment("trifinger")
    plants = [env.make_plant(obj) for obj in ("cube", "stick")]
    mpcs = [_mpc(env, plant) for plant in plants]
    pairs = zip(mpcs, plants, strict=True)
    keys = {mpc._graph_key(plant.contacts(DT).padded(12)) for mpc, plant in pairs}
    assert len(keys) == 1
    (cube, stick) = (mpc.cost for mpc in mpcs)
    assert repr(cube) == repr(stick)
    assert (float(cube.hold.applies), float(stick.hold.applies)) == (0.0, 1.0)
    assert (float(cube.tilt_applies), float(stick.tilt_applies)) == (0.0, 1.0)


def test_a_worker_drops_its_graphs_for_other_settings_not_for_another_object(monkeypatch):
    """Another object runs the graph the worker has (re-tracing it costs tens of seconds an
    object); other settings bring other graphs, so the old ones are dropped."""
    from torchcontact.mpc import trials

    resets = []
    monkeypatch.setattr(torch._dynamo, "reset", lambda: resets.append(1))
    monkeypatch.setattr(trials, "_CACHE", {})
    fast = MPCSettings(max_iter=2, compile=False)
    pairs = [("in-hand", "cube"), ("in-hand", "random-401")]
    cube, other = trials.trial_configs("trifinger", pairs, [0], fast, max_steps=1)
    (deeper,) = trials.trial_configs(
        "trifinger", pairs[:1], [0], MPCSettings(max_iter=2, compile=False, horizon=2), max_steps=1
    )
    for config, expected in ((cube, 1), (other, 1), (deeper, 2)):
        trials._run_job(trials._Job(config, None, None, trials.trial_inputs(config)))
        assert len(resets) == expected, config.object
