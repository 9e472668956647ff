"""Robot-hand plants: scenes for every object, resting poses, servos, contacts, FK agreement."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
import torch
import trimesh
from conftest import render_or_skip

from torchcontact.objects import ObjectOptions
from torchcontact.shapes import object_names
from torchcontact.sim.hands import (
    ALLEGRO,
    CONTACTS_PER_TIP,
    HANDS,
    TRIFINGER,
    HandPlant,
    scene_contact_slots,
)


@pytest.fixture(scope="module", params=sorted(HANDS))
def cube_env(request):
    env = HandPlant(request.param, "cube")
    yield env
    env.close()


@pytest.mark.parametrize("hand", sorted(HANDS))
@pytest.mark.parametrize("name", object_names())
def test_every_object_builds_and_rests_on_its_support(hand, name):
    env = HandPlant(hand, name, overflow="deepest")
    n = HANDS[hand].n_joints
    assert env.nq == 7 + n and env.nv == 6 + n and env.nu == n
    pose = env.resting_pose(env.support_centre, [1.0, 0.0, 0.0, 0.0])
    tips = len(HANDS[hand].tips)
    qpos = np.concatenate([pose, HANDS[hand].initial_joints])
    assert env.detector.slots == scene_contact_slots(env.model, qpos, tips)
    env.reset(pose)
    env.contacts()
    assert env.detector.found + CONTACTS_PER_TIP * tips <= env.detector.slots  # room for tips
    env.reset(pose)
    assert pose[2] == pytest.approx(env.support_height + env.object.resting_height())
    if hand == "trifinger":  # on the ground, touching it without penetrating
        env.model.geom_margin[:] = 1e-3  # see touching contacts whose distance is +0.0
        env.reset(pose)
        ground = env.model.geom("ground").id
        contacts = [env.data.contact[i] for i in range(env.data.ncon)]
        on_ground = [c.dist for c in contacts if ground in (c.geom1, c.geom2)]
        assert on_ground and abs(min(on_ground)) < 1e-6
    for _ in range(5):
        env.step(np.zeros(n))
    assert env.state()[2] > env.support_height, "the object stays on its support"
    active = int(env.contacts().active.sum())
    assert active == min(env.detector.found, env.detector.slots)


@pytest.mark.parametrize("name", ["cup", "torus"])
def test_resting_decomposed_object_is_not_lifted_by_the_papers_model(name):
    """Dozens of part–ground contacts each carry a softplus floor force: kept per body pair to
    a spanning four, the paper's model predicts a resting object to stay within 1 mm a step."""
    from torchcontact.environments.hands import TRIFINGER_ENV
    from torchcontact.environments.presets import MPCSettings
    from torchcontact.model import paper_model
    from torchcontact.mpc.controller import ContactImplicitMPC

    env = HandPlant("trifinger", name, overflow="deepest")
    model = paper_model(TRIFINGER_ENV.default_stiffness)
    settings = MPCSettings(compile=False)
    mpc = ContactImplicitMPC.from_env(TRIFINGER_ENV, env, model, settings=settings)
    for _ in range(10):  # settle into the ground
        env.step(np.zeros(env.nu))
    contacts = env.contacts(torch.float64)
    assert env.detector.found == 4
    q = torch.as_tensor(env.state())
    still = torch.zeros(1, mpc.horizon, env.nu, dtype=torch.float64)
    states = mpc.rollout(q, still, mpc.freeze(q, contacts))
    rise = (states[0, 1:, 2] - states[0, :-1, 2]).abs()
    assert float(rise.max()) < 1e-3


def test_allegro_objects_use_the_papers_masses_and_sizes():
    cube = HandPlant("allegro", "cube")
    np.testing.assert_allclose(cube.object.size, [0.05] * 3, rtol=1e-6)
    assert cube.object.mass == 0.1 and HandPlant("allegro", "stick").object.mass == 0.1
    assert HandPlant("allegro", "bunny").object.mass == 0.01
    assert HandPlant("trifinger", "cube").object.mass == 0.01
    airplane = HandPlant("allegro", "airplane").object.size
    np.testing.assert_allclose(airplane, 0.9 * HandPlant("trifinger", "airplane").object.size)


def _sliding_friction(env, geom_body: int) -> float:
    geoms = np.flatnonzero(env.model.geom_bodyid == geom_body)
    return float(env.model.geom_friction[geoms[0], 0])


def test_per_object_friction_of_the_reference_scenes():
    """TriFinger: a 0.9 table under the cube, 0.5 under the meshes; Allegro: the binoculars
    have friction 0.9. Read back from the compiled MuJoCo models."""
    for obj, expected in (("cube", 0.9), ("stick", 0.5)):
        env = HandPlant("trifinger", obj)
        ground_geom = env.model.geom("ground").id
        assert env.model.geom_friction[ground_geom, 0] == pytest.approx(expected)
        assert env.ground_friction == pytest.approx(expected)
    obj_body = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_BODY, "object")
    assert _sliding_friction(env, obj_body) == pytest.approx(0.5)
    binoculars = HandPlant("allegro", "binoculars")
    obj_body = mujoco.mj_name2id(binoculars.model, mujoco.mjtObj.mjOBJ_BODY, "object")
    assert _sliding_friction(binoculars, obj_body) == pytest.approx(0.9)


def test_state_layout_reset_and_target(cube_env):
    hand = cube_env.hand
    pose = cube_env.resting_pose(cube_env.support_centre + 0.005, [0.0, 0.0, 0.0, 1.0])
    target = cube_env.resting_pose(cube_env.support_centre, [1.0, 0.0, 0.0, 0.0])
    state = cube_env.reset(pose, target)
    np.testing.assert_array_equal(state[:7], pose)
    np.testing.assert_array_equal(state[7:], hand.initial_joints)
    np.testing.assert_allclose(cube_env.target, target)
    with pytest.raises(ValueError, match="joints"):
        cube_env.reset(pose, joints=np.zeros(3))


def test_fingertip_sites_match_the_hands_robot_in_the_scene(cube_env):
    hand = cube_env.hand
    fk = hand.robot()
    rng = np.random.default_rng(0)
    for _ in range(3):
        joints = np.array(hand.initial_joints) + rng.uniform(-0.2, 0.2, hand.n_joints)
        cube_env.reset(cube_env.state()[:7], joints=joints)
        tips = fk(torch.as_tensor(joints)).numpy()
        np.testing.assert_allclose(tips, cube_env.fingertips(), atol=1e-6)


def test_hands_read_their_joints_and_tips_from_the_mjcf():
    assert TRIFINGER.n_joints == 9 and TRIFINGER.tips == ("tip0", "tip1", "tip2")
    assert ALLEGRO.tip_sites is None  # the file's *tip sites, in its order
    assert ALLEGRO.tips == ("ff_tip", "mf_tip", "rf_tip", "th_tip")
    assert ALLEGRO.n_joints == 16 == ALLEGRO.robot().n_joints
    robot = TRIFINGER.robot(torch.float32)
    assert robot.mjcf == TRIFINGER.mjcf and robot(torch.zeros(9)).dtype == torch.float32
    with pytest.raises(ValueError, match="initial_joints must have 9"):
        HandPlant(dataclasses.replace(TRIFINGER, initial_joints=(0.0,) * 3), "cube")


def test_the_servo_moves_free_joints_toward_the_command(cube_env):
    far = cube_env.resting_pose(cube_env.support_centre + 1.0, [1.0, 0.0, 0.0, 0.0])
    start = cube_env.reset(far)  # object out of reach: the hand moves freely
    command = np.zeros(cube_env.nu)
    command[1] = -0.05
    state = cube_env.step(command)
    moved = state[7:] - start[7:]
    assert moved[1] < -0.01, "the commanded joint moves the commanded way"
    others = np.delete(moved, 1)
    assert np.abs(others).max() < 0.5 * abs(moved[1])


def test_contacts_keep_only_the_object_pairs(cube_env):
    cube_env.reset(cube_env.resting_pose(cube_env.support_centre, [1.0, 0.0, 0.0, 0.0]))
    cube_env.data.qpos[7:] = 0.0  # a configuration where links may touch each other
    contacts = cube_env.contacts()
    assert contacts.phi.shape == (cube_env.detector.slots,)
    assert cube_env.detector.found == int(contacts.active.sum())
    assert cube_env.detector.found >= 1


def test_a_user_mesh_is_scaled_and_placed(tmp_path):
    path = tmp_path / "box.stl"
    trimesh.creation.box([2.0, 1.0, 0.5]).export(path)
    env = HandPlant("trifinger", path, options=ObjectOptions(size=0.08))
    np.testing.assert_allclose(env.object.size, [0.08, 0.04, 0.02], rtol=1e-6)
    assert env.object.name == "mesh_box"  # apart from the built-in names


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="hand"):
        HandPlant("shadow", "cube")
    with pytest.raises(ValueError, match="overflow"):
        HandPlant(TRIFINGER, "cube", overflow="drop")
    with pytest.raises(ValueError, match="obj"):
        HandPlant(ALLEGRO, "spoon")
    env = HandPlant(TRIFINGER, "cube")
    with pytest.raises(ValueError, match="u must have shape"):
        env.step(np.zeros(4))


def test_render_shows_the_scene():
    env = HandPlant("trifinger", "cube")
    try:
        image = render_or_skip(env, 64, 48)
    finally:
        env.close()
    assert image.shape == (48, 64, 3) and image.std() > 1.0


def test_the_trifinger_sees_a_tip_within_its_contact_margin_as_an_open_gap():
    gap = 0.003  # [m], inside the TriFinger's 5 mm margin
    seen, blind = HandPlant("trifinger", "cube"), HandPlant("trifinger", "cube", contact_margin=0.0)
    assert TRIFINGER.contact_margin == 0.005 and ALLEGRO.contact_margin == 0.0
    model, tip = seen.model, seen.fingertips()[0]
    (tip_geom,) = np.flatnonzero(model.geom_bodyid == model.site_bodyid[seen.tip_sites[0]])
    # the cube's −x face `gap` from the tip sphere, its bottom 8 mm above the ground
    offset = model.geom_size[tip_geom][0] + 0.03 + gap
    pose = [tip[0] + offset, tip[1], 0.038, 1.0, 0.0, 0.0, 0.0]
    for env in (seen, blind):
        env.reset(pose)
    contacts = seen.contacts()
    assert seen.detector.found == 1 and blind.contacts().active.sum() == 0
    assert float(contacts.phi[contacts.active][0]) == pytest.approx(gap, abs=1e-5)
    with pytest.raises(ValueError, match="contact_margin"):
        HandPlant("trifinger", "cube", contact_margin=-0.001)


def test_the_plant_collides_its_object_as_asked():
    """By default the airplane collides as its hull, as the paper's one mesh geom did."""
    for collision, hull in (("auto", True), ("hull", True), ("parts", False)):
        env = HandPlant("allegro", "airplane", collision=collision)
        assert env.object.collide_hull is hull
    assert not HandPlant("trifinger", "mug").object.collide_hull  # its cavity stays open
    with pytest.raises(ValueError, match="collision"):
        HandPlant("trifinger", "cube", collision="convex")


def test_the_allegro_palm_footprint_is_its_collision_box_in_the_world():
    """The palm box spans x ∈ [−0.095, 0] (fingers towards +x) and y ∈ ±0.0565 (the MJCF)."""
    plant = HandPlant("allegro", "cube")
    torch.testing.assert_close(
        torch.tensor(plant.support_footprint), torch.tensor((-0.095, -0.0565, 0.0, 0.0565))
    )
    assert HandPlant("trifinger", "cube").support_footprint is None  # resting on the ground
