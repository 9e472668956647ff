"""A user's own MJCF (a two-joint pusher and a free box) turned into the contact model's pieces."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from torchcontact import ComplementarityFree, integrate
from torchcontact.sim.user_scene import DEFAULT_EPSILON, describe_scene

# the box first (its free joint leads q), then a carriage on x with an arm turning about z
PUSHER = """
<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <geom name="ground" type="plane" size="1 1 0.1"/>
    <body name="box" pos="0 0 0.03">
      <freejoint/>
      <geom type="box" size="0.03 0.02 0.03" mass="0.1"/>
    </body>
    <body name="carriage" pos="-0.1 0 0.03">
      <joint name="x" type="slide" axis="1 0 0" range="-0.05 0.1" damping="5"/>
      <geom type="sphere" size="0.005" mass="0.05" contype="0" conaffinity="0"/>
      <body name="arm">
        <joint name="turn" type="hinge" axis="0 0 1" range="-1 1" armature="1e-3" damping="0.02"/>
        <geom type="capsule" fromto="0 0 0 0.03 0 0" size="0.004" mass="0.02"/>
        <geom name="pusher" type="sphere" pos="0.04 0 0" size="0.01" mass="0.01"/>
        <site name="pusher_tip" pos="0.04 0 0"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position joint="x" kp="50"/>
    <position joint="turn" kp="0.02" gear="2"/>
  </actuator>
</mujoco>
"""

MASS, HALF = 0.1, (0.03, 0.02, 0.03)


def _write(directory, text, name="pusher.xml"):
    path = directory / name
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return describe_scene(_write(tmp_path_factory.mktemp("scene"), PUSHER), "box")


def test_the_object_metric_and_weight_come_from_mujoco(scene):
    a, b, c = (2 * x for x in HALF)
    inertia = [
        MASS * (b * b + c * c) / 12,
        MASS * (a * a + c * c) / 12,
        MASS * (a * a + b * b) / 12,
    ]
    scale = DEFAULT_EPSILON / scene.h**2
    expected = torch.tensor([MASS] * 3 + inertia, dtype=torch.float64) * scale
    torch.testing.assert_close(scene.system.object_metric, expected)
    assert scene.object_mass == pytest.approx(MASS)
    Q, b_term = scene.system(torch.tensor([0.01, -0.02], dtype=torch.float64))
    torch.testing.assert_close(Q[6:], torch.full((2,), 10.0, dtype=torch.float64))
    expected_b = [0.0, 0.0, -MASS * 9.81, 0.0, 0.0, 0.0, 0.1, -0.2]
    torch.testing.assert_close(b_term, torch.tensor(expected_b, dtype=torch.float64))


def test_layout_robot_and_detector(scene):
    assert scene.layout.joints == ("free", "slide", "hinge")
    assert (scene.layout.nq, scene.layout.nv, scene.system.nv) == (9, 8, 8)
    assert scene.robot.joint_names == ("x", "turn") and scene.robot.tips == ("pusher_tip",)
    assert scene.robot_qpos == (7, 8)
    contacts = scene.detector(scene.model.qpos0)  # the box resting on the ground
    assert scene.detector.found >= 1 and int(contacts.active.sum()) == scene.detector.found
    assert contacts.position[contacts.active][:, 2].abs().max() < 1e-6, "box-ground contacts"
    assert contacts.jac_normal.shape == (scene.detector.slots, 8)
    np.testing.assert_allclose(
        scene.robot(torch.zeros(1, 2, dtype=torch.float64))[0, 0].numpy(), [-0.06, 0.0, 0.03]
    )


def test_a_batched_step_of_the_model_runs_on_the_pieces(scene):
    """50 states: the box jittered, the pusher from far to pressing into it, a push along x."""
    rng = np.random.default_rng(0)
    q = np.tile(scene.model.qpos0, (50, 1))
    q[:, :2] += rng.uniform(-0.005, 0.005, (50, 2))
    q[:, 7] = np.linspace(0.0, 0.025, 50)  # the pusher's surface reaches the box at x ≈ 0.02
    q = torch.tensor(q)
    contacts = scene.detector(q)
    assert contacts.phi.shape == (50, scene.detector.slots)
    u = torch.tensor([[0.005, 0.0]], dtype=torch.float64).expand(50, 2)
    Q, b = scene.system(u)
    model = ComplementarityFree(stiffness=1.0)
    v = model(Q, b, contacts, scene.h)
    q_next = integrate(q, v, scene.h, scene.layout)
    assert q_next.shape == (50, 9) and torch.isfinite(q_next).all()
    free_fall = 9.81 * scene.h**2 / DEFAULT_EPSILON  # g·h²/ε: the step's fall without support
    assert (q[:, 2] - q_next[:, 2]).max() < 0.9 * free_fall, "the ground's rows slow the fall"
    free = q[:, 7] < 0.005  # the pusher ≥ 1 cm from the box
    torch.testing.assert_close(q_next[free, 7:] - q[free, 7:], u[free], atol=1e-6, rtol=0)
    pushed = q[:, 7] > 0.024
    assert (q_next[pushed, 0] - q[pushed, 0]).min() > 0, "the pushed box moves along +x"


def test_control_servos_the_plant_by_u(scene):
    data = mujoco.MjData(scene.model)
    mujoco.mj_forward(scene.model, data)
    u = np.array([0.01, 0.2])
    ctrl = scene.control(data.qpos, u)
    np.testing.assert_array_equal(ctrl, [0.01, 2 * 0.2])  # gear 2 on the hinge
    torch.testing.assert_close(
        scene.control(torch.tensor(data.qpos), torch.tensor(u)), torch.tensor(ctrl)
    )
    data.qpos[:3] = [0.3, 0.0, 0.03]  # the box out of the way
    data.ctrl[:] = ctrl
    mujoco.mj_step(scene.model, data, nstep=1000)
    np.testing.assert_allclose(data.qpos[7:], u, atol=2e-3)
    with pytest.raises(ValueError, match="u must have shape"):
        scene.control(data.qpos, np.zeros(3))


def test_bad_scenes_are_named(tmp_path):
    robot_first = PUSHER.replace('<body name="box"', '<body name="boxx"').replace(
        "</worldbody>",
        '<body name="box" pos="0.2 0 0.03"><freejoint/><geom type="box" size="0.02 0.02 0.02"/>'
        "</body></worldbody>",
    )
    with pytest.raises(ValueError, match="free joint must be the first joint.*before the robot"):
        describe_scene(_write(tmp_path, robot_first, "order.xml"), "box")
    with pytest.raises(ValueError, match="object_body"):
        describe_scene(_write(tmp_path, PUSHER), "carriage")
    with pytest.raises(ValueError, match="object_body must name a body"):
        describe_scene(_write(tmp_path, PUSHER), "ball")
    with pytest.raises(ValueError, match="epsilon"):
        describe_scene(_write(tmp_path, PUSHER), "box", epsilon=0.0)
    motors = PUSHER.replace('<position joint="x" kp="50"/>', '<motor joint="x"/>')
    scene = describe_scene(_write(tmp_path, motors, "motors.xml"), "box")
    with pytest.raises(ValueError, match="position actuators only.*motor"):
        scene.control(np.zeros(9), np.zeros(2))
