"""The three-fingertip plant: rest, tip servo, pushing, contacts, goal marker and rendering."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from conftest import render_or_skip

from torchcontact.objects import ObjectOptions
from torchcontact.sim.fingertips import INITIAL_TIPS, TIP_RADIUS, FingertipsPlant

CUBE_REST = np.array([0.0, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0])
RAISED_TIPS = np.array([0.2, 0.0, 0.05, 0.0, 0.2, 0.05, -0.2, 0.0, 0.05])


@pytest.fixture(scope="module")
def cube_env():
    env = FingertipsPlant("cube", contact_slots=8)
    yield env
    env.close()


def test_state_layout_and_reset(cube_env):
    target = [0.05, -0.02, 0.03, 0.0, 0.0, 0.0, 2.0]  # quaternion normalised on reset
    state = cube_env.reset(CUBE_REST, target)
    assert state.shape == (16,) and cube_env.model.nq == 16 and cube_env.model.nv == 15
    np.testing.assert_array_equal(state[:7], CUBE_REST)
    np.testing.assert_array_equal(state[7:], INITIAL_TIPS)
    np.testing.assert_allclose(cube_env.target, [0.05, -0.02, 0.03, 0, 0, 0, 1])
    state[0] = 1.0
    assert cube_env.state()[0] == 0.0  # a copy
    cube_env.reset(CUBE_REST)
    np.testing.assert_allclose(cube_env.target, [0.05, -0.02, 0.03, 0, 0, 0, 1])  # kept


@pytest.mark.parametrize("name", ["cube", "foam_brick", "stick", "bunny"])
def test_a_resting_object_stays_put_under_zero_actions(name):
    env = FingertipsPlant(name, contact_slots=12)
    start = env.reset([0.01, -0.01, env.object.resting_height(), 1, 0, 0, 0])
    for _ in range(50):
        env.step(np.zeros(9))
    drift = np.abs(env.state() - start)
    assert drift[:3].max() < 1e-3
    assert drift[7:].max() < 1e-3


def test_a_free_tip_tracks_its_command(cube_env):
    """Over-damped servo (kp = 100, kd = 2, 4.2 g tip): ≈ 0.65 u per 20 ms step, no overshoot."""
    cube_env.reset(CUBE_REST, tips=RAISED_TIPS)
    command = np.zeros(9)
    command[0] = 0.005
    x = [cube_env.state()[7]]
    for _ in range(10):
        x.append(cube_env.step(command)[7])
    per_step = np.diff(x) / 0.005
    np.testing.assert_allclose(per_step, 0.65, atol=0.02)
    np.testing.assert_allclose(cube_env.state()[8:], RAISED_TIPS[1:], atol=1e-6)  # others hold
    for _ in range(10):
        cube_env.step(np.zeros(9))
    assert abs(cube_env.state()[7] - x[-1]) < 0.006  # stops within a step's worth


def test_pushing_the_cube_with_a_tip_moves_it(cube_env):
    tips = RAISED_TIPS.copy()
    tips[6:9] = [-0.045, 0.0, 0.02]
    cube_env.reset(CUBE_REST, tips=tips)
    command = np.zeros(9)
    command[6] = 0.005
    for _ in range(20):
        cube_env.step(command)
    state = cube_env.state()
    assert state[0] > 0.02  # pushed along +x
    assert abs(state[1]) < 0.005
    assert state[6 + 7] - state[0] == pytest.approx(-0.04, abs=0.003)  # tip stays at the face


def test_contacts_show_the_touching_tip_and_nothing_when_apart(cube_env):
    tips = RAISED_TIPS.copy()
    tips[0:3] = [0.03 + TIP_RADIUS - 0.001, 0.0, 0.03]  # 1 mm into the +x face
    cube_env.reset(CUBE_REST + [0, 0, -1e-4, 0, 0, 0, 0], tips=tips)
    contacts = cube_env.contacts()
    assert contacts.slots == 8 and contacts.nv == 15
    active = contacts.active.numpy()
    tip_rows = contacts.jac_normal[:, 6:9].abs().sum(-1).numpy() > 0
    touching = active & tip_rows
    assert touching.sum() == 1
    assert contacts.phi[touching].item() == pytest.approx(-0.001, abs=1e-4)
    assert contacts.mu[touching].item() == 0.5
    assert (active & ~tip_rows).sum() == 4  # the bottom face's corners on the ground
    # the tip moving into the object (−x) closes the gap: Jⁿ·v < 0
    v = torch.zeros(15, dtype=contacts.jac_normal.dtype)
    v[6] = -1.0
    assert (contacts.jac_normal[touching] @ v).item() < 0
    cube_env.reset(CUBE_REST + [0, 0, 0.1, 0, 0, 0, 0], tips=RAISED_TIPS)
    apart = cube_env.contacts(dtype=torch.float32)
    assert not apart.active.any() and apart.phi.dtype == torch.float32


def test_overflow_raises_unless_deepest_is_chosen():
    tips = np.array([0.0395, 0, 0.03, 0, 0.0395, 0.03, -0.0395, 0, 0.03])
    pose = CUBE_REST + [0, 0, -1e-4, 0, 0, 0, 0]
    strict = FingertipsPlant("cube", contact_slots=5)
    strict.reset(pose, tips=tips)
    with pytest.raises(ValueError, match="slots"):
        strict.contacts()
    lenient = FingertipsPlant("cube", contact_slots=5, overflow="deepest")
    lenient.reset(pose, tips=tips)
    assert lenient.contacts().active.all()


def test_user_mesh_object(tmp_path):
    path = tmp_path / "puck.stl"
    trimesh.creation.cylinder(radius=1.0, height=0.5).export(path)
    env = FingertipsPlant(path, options=ObjectOptions(size=0.06))
    np.testing.assert_allclose(env.object.size, [0.06, 0.06, 0.015], atol=1e-3)
    start = env.reset([0, 0, env.object.resting_height(), 1, 0, 0, 0])
    for _ in range(10):
        env.step(np.zeros(9))
    assert np.abs(env.state()[:3] - start[:3]).max() < 1e-3


def test_render_returns_an_image(cube_env):
    cube_env.reset(CUBE_REST, [0.05, 0.05, 0.03, 1, 0, 0, 0])
    image = render_or_skip(cube_env, 64, 48)
    assert image.shape == (48, 64, 3) and image.dtype == np.uint8
    assert image.std() > 1.0  # not a blank frame


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda env: env.step(np.zeros(8)), "u"),
        (lambda env: env.step([np.nan] * 9), "u"),
        (lambda env: env.reset(np.zeros(7)), "object_pose"),
        (lambda env: env.reset(CUBE_REST, tips=np.zeros(3)), "tips"),
        (lambda env: env.set_target(np.zeros(6)), "target_pose"),
        (lambda env: env.render(0, 10), "width"),
        (lambda env: env.render(10, 10, camera="nope"), "camera"),
    ],
)
def test_bad_input_names_the_argument(cube_env, call, message):
    with pytest.raises(ValueError, match=message):
        call(cube_env)


def test_bad_constructor_arguments_name_themselves():
    with pytest.raises(ValueError, match="obj"):
        FingertipsPlant("spoon")
    with pytest.raises(ValueError, match="overflow"):
        FingertipsPlant("cube", overflow="drop")
    with pytest.raises(ValueError, match="frame_skip"):
        FingertipsPlant("cube", frame_skip=0)


def test_the_bunny_collides_as_its_hull_unless_told_otherwise():
    assert FingertipsPlant("bunny", contact_slots=12).object.collide_hull
    assert not FingertipsPlant("bunny", contact_slots=12, collision="parts").object.collide_hull
