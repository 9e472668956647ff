"""The box-pushing scene and plant: a kinematically driven bar and MuJoCo cubes."""

import numpy as np
import pytest

from torchcontact.sim.box_pushing import BoxPushingConfig, BoxPushingPlant, build_scene


def test_scene_system_weighs_the_cubes_and_springs_the_bar():
    config = BoxPushingConfig(cubes=3)
    scene = build_scene(config)
    assert scene.layout.nq == 3 * 7 + 1 and scene.q0.shape == (scene.layout.nq,)
    gravity = float(scene.model.opt.gravity[2])
    cube_z = scene.linear_v[2:-1:3]  # each cube's vertical velocity, then the bar's
    assert scene.b[cube_z].tolist() == pytest.approx([config.mass * gravity] * 3)
    assert float(scene.b[scene.linear_v[-1]]) == pytest.approx(config.robot_stiffness * config.push)
    assert float(scene.Q[scene.linear_v[-1]]) == pytest.approx(config.robot_stiffness)
    metric = config.epsilon / config.h**2 * config.mass
    assert scene.Q[scene.linear_v[:-1]].tolist() == pytest.approx([metric] * 9)
    heights = scene.q0[scene.cube_q[:, 2]]
    assert heights.tolist() == pytest.approx([config.edge / 2] * 3)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("cubes", 0, "cubes must be a positive integer"),
        ("mass", -1.0, "mass must be a positive finite number"),
    ],
)
def test_invalid_config_raises(field, value, message):
    with pytest.raises(ValueError, match=message):
        BoxPushingConfig(**{field: value})


def test_the_bar_moves_as_commanded_and_pushes_the_first_cube():
    plant = BoxPushingPlant(BoxPushingConfig(cubes=2))
    plant.reset(plant.initial_state)
    start = plant.state()
    for _ in range(30):
        q = plant.step([-0.001])
    assert q[-1] == pytest.approx(start[-1] - 0.03, abs=1e-12)
    # the bar starts 1 cm behind the first cube: the cube has moved by about 2 cm, not more
    assert -0.025 < q[0] - start[0] < -0.012
    assert abs(q[2] - start[2]) < 1e-3  # still on the ground
    assert int(plant.contacts().active.sum()) >= 4


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda p: p.step([np.nan]), "u must be"),
        (lambda p: p.step([0.1, 0.2]), "u must be"),
        (lambda p: p.reset(np.zeros(3)), "initial must be"),
        (lambda p: BoxPushingPlant(substeps=0), "substeps"),
    ],
)
def test_bad_input_is_refused_by_name(call, message):
    plant = BoxPushingPlant(BoxPushingConfig(cubes=1))
    with pytest.raises(ValueError, match=message):
        call(plant)
