"""Robots read from MJCF: our hands unchanged to the bit, point fingertips as the identity, the
example gripper against MuJoCo and in a scene, torch.func and torch.compile."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import pytorch_kinematics as pk
import torch

from torchcontact.assets import asset_path
from torchcontact.shapes import make_object
from torchcontact.sim.hands import ALLEGRO, HANDS, TRIFINGER
from torchcontact.sim.robot import Actuator, Robot
from torchcontact.sim.scene import scene_spec

GRIPPER = Path(__file__).parents[1] / "examples" / "two_finger_gripper.xml"

BUILT_IN = {
    "trifinger.xml": ("tip0", "tip1", "tip2"),
    "allegro_right_hand.xml": ("ff_tip", "mf_tip", "rf_tip", "th_tip"),
}

# three point fingertips after a free object, as the three-fingertip plant builds them
POINT_TIPS = """
<mujoco>
  <worldbody>
    <body name="object" pos="0 0 0.03">
      <freejoint/>
      <geom type="box" size="0.03 0.03 0.03" mass="0.01"/>
    </body>
    {tips}
  </worldbody>
</mujoco>
"""
POINT_TIP = """
    <body name="tip{i}" pos="{pos}">
      <joint name="tip{i}_x" type="slide" axis="1 0 0"/>
      <joint name="tip{i}_y" type="slide" axis="0 1 0"/>
      <joint name="tip{i}_z" type="slide" axis="0 0 1"/>
      <geom type="sphere" size="0.01"/>
      <site name="finger{i}_tip"/>
    </body>
"""


def _point_tips_file(directory: Path, offset: str = "0 0 0") -> Path:
    tips = "".join(POINT_TIP.format(i=i, pos=offset if i == 1 else "0 0 0") for i in range(3))
    path = directory / "point_tips.xml"
    path.write_text(POINT_TIPS.format(tips=tips))
    return path


def _fingertips_before(mjcf: Path, tips, joints: torch.Tensor) -> torch.Tensor:
    """The fingertips as FingertipKinematics computed them before robots were read from files:
    pytorch-kinematics' own parser, the chain cast to the joints' dtype, MuJoCo's joint order
    permuted to the chain's, tensor FK without the analytical gradient."""
    chain = pk.build_chain_from_mjcf(mjcf.read_text()).to(dtype=joints.dtype)
    model = mujoco.MjModel.from_xml_path(str(mjcf))
    names = [model.joint(j).name for j in range(model.njnt)]
    permutation = torch.tensor([names.index(n) for n in chain.get_joint_parameter_names()])
    flat = joints.reshape(-1, len(names))[:, permutation]
    transforms = chain.forward_kinematics_tensor(flat, analytical_grad=False)
    positions = transforms[chain.get_frame_indices(*tips), :, :3, 3]
    return positions.transpose(0, 1).reshape(*joints.shape[:-1], len(tips), 3)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("asset", sorted(BUILT_IN))
def test_built_in_hands_are_bit_identical_to_before(asset, dtype):
    mjcf, tips = asset_path(asset), BUILT_IN[asset]
    robot = Robot.from_mjcf(mjcf, tips, dtype=dtype)
    joints = torch.randn(5, 7, robot.n_joints, dtype=dtype)
    before = _fingertips_before(mjcf, tips, joints)
    assert torch.equal(robot(joints), before)
    hand = next(h for h in HANDS.values() if h.asset == asset)
    assert torch.equal(hand.robot(dtype)(joints), before)


def test_built_in_descriptions_come_from_the_files():
    trifinger = TRIFINGER.robot()
    assert trifinger.joint_names == tuple(f"finger{i}_{j}" for i in range(3) for j in range(3))
    assert trifinger.joint_types == ("hinge",) * 9 and trifinger.tips == ("tip0", "tip1", "tip2")
    assert trifinger.joint_ranges.shape == (9, 2)
    assert trifinger.joint_ranges[1].tolist() == pytest.approx([-1.3526301702956054, 4.4942228])
    assert {a.kind for a in trifinger.actuators} == {"motor"}
    allegro = Robot.from_mjcf(asset_path("allegro_right_hand.xml"))  # tips from the *tip sites
    assert allegro.tips == BUILT_IN["allegro_right_hand.xml"] == ALLEGRO.tips
    assert allegro.n_joints == 16 and allegro.mjcf == ALLEGRO.mjcf
    assert allegro.actuators[0] == Actuator("ff_0", "ff_0", "position", 1.0, 1.0)


def test_point_fingertips_are_their_joints(tmp_path):
    q = torch.randn(6, 16, dtype=torch.float64)
    expected = q[..., 7:16].unflatten(-1, (3, 3))  # the fingertip MPC's fingertip_positions
    point = Robot.point_tips(3)
    assert point.kinematics is None and point.mjcf is None
    assert point.joint_names[:3] == ("tip0_x", "tip0_y", "tip0_z") and point.n_tips == 3
    assert torch.equal(point(q[..., 7:16]), expected)
    from_file = Robot.from_mjcf(_point_tips_file(tmp_path))
    assert from_file.kinematics is None and from_file.tips == tuple(
        f"finger{i}_tip" for i in range(3)
    )
    assert from_file.joint_names == point.joint_names
    assert torch.equal(from_file(q[..., 7:16]), expected)
    compiled = torch.compile(lambda q: from_file(q[..., 7:16]), backend="aot_eager", fullgraph=True)
    assert torch.equal(compiled(q), expected)


def test_an_offset_point_body_is_evaluated_as_a_chain(tmp_path):
    robot = Robot.from_mjcf(_point_tips_file(tmp_path, offset="0.1 0 0"))
    assert robot.kinematics is not None
    joints = torch.randn(4, 9, dtype=torch.float64)
    expected = joints.unflatten(-1, (3, 3)).clone()
    expected[:, 1, 0] += 0.1
    torch.testing.assert_close(robot(joints), expected, rtol=0, atol=1e-15)


def _gripper_sites(joints: np.ndarray) -> np.ndarray:
    model = mujoco.MjModel.from_xml_path(str(GRIPPER))
    data = mujoco.MjData(model)
    sites = [model.site("left_tip").id, model.site("right_tip").id]
    out = []
    for q in joints:
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        out.append(data.site_xpos[sites].copy())
    return np.array(out)


def test_the_example_gripper_is_read_from_its_file():
    robot = Robot.from_mjcf(GRIPPER)
    assert robot.joint_names == ("left_close", "left_lift", "right_close", "right_lift")
    assert robot.joint_types == ("slide",) * 4 and robot.tips == ("left_tip", "right_tip")
    assert robot.joint_ranges.tolist() == [[0.0, 0.07], [0.0, 0.12]] * 2
    assert all(a.kind == "position" and a.kp == 100 for a in robot.actuators)
    assert [a.joint for a in robot.actuators] == list(robot.joint_names)
    low, high = robot.joint_ranges.T.numpy()
    joints = np.random.default_rng(0).uniform(low, high, (32, 4))
    np.testing.assert_allclose(
        robot(torch.tensor(joints)).numpy(), _gripper_sites(joints), atol=1e-12
    )


def test_robots_compose_with_torch_func_and_compile():
    robot = Robot.from_mjcf(GRIPPER)
    joints = torch.tensor([0.01, 0.02, 0.03, 0.04], dtype=torch.float64)
    grad = torch.func.grad(lambda q: robot(q)[:, 1].sum())(joints)  # d(sum of tip y)/dq
    assert grad.tolist() == pytest.approx([-1.0, 0.0, 1.0, 0.0])
    compiled = torch.compile(robot, backend="aot_eager", fullgraph=True)
    batch = joints.expand(3, 4) * torch.rand(3, 1, dtype=torch.float64)
    assert torch.equal(compiled(batch), robot(batch))


def test_to_moves_ranges_and_kinematics():
    robot = Robot.from_mjcf(GRIPPER).to(torch.float32)
    assert robot.joint_ranges.dtype == torch.float32
    assert robot(torch.zeros(2, 4)).dtype == torch.float32
    unlimited = Robot.from_mjcf(asset_path("allegro_right_hand.xml"))
    assert unlimited.joint_ranges is not None  # every Allegro joint is limited


def test_the_example_gripper_grasps_and_lifts_a_cube_in_a_scene():
    """Attached under a prefix into the shared scene, as HandPlant attaches our hands."""
    cube = make_object("cube", mass=0.01, size=(0.05, 0.05, 0.05))
    spec = scene_spec(
        "gripper_cube",
        cube,
        object_friction=0.5,
        ground_friction=0.5,
        condim=6,
        camera_position=(0.3, -0.3, 0.3),
    )
    spec.attach(
        mujoco.MjSpec.from_file(str(GRIPPER)), prefix="robot/", frame=spec.worldbody.add_frame()
    )
    model = spec.compile()
    data = mujoco.MjData(model)
    assert model.nq == 7 + 4 and model.nu == 4
    data.qpos[:7] = [0.0, 0.0, cube.resting_height(), 1.0, 0.0, 0.0, 0.0]
    mujoco.mj_forward(model, data)
    robot = Robot.from_mjcf(GRIPPER)
    tips = [model.site(f"robot/{name}").id for name in robot.tips]
    np.testing.assert_allclose(
        data.site_xpos[tips], robot(torch.zeros(4, dtype=torch.float64)).numpy(), atol=1e-12
    )
    data.ctrl[:] = [0.07, 0.0, 0.07, 0.0]  # close on the cube
    mujoco.mj_step(model, data, nstep=500)
    assert data.qpos[7] == pytest.approx(0.055, abs=1e-3), "the pads stop at the cube's faces"
    for lift in np.linspace(0.01, 0.08, 8):  # raise both fingers, 1 cm per 0.2 s
        data.ctrl[[1, 3]] = lift
        mujoco.mj_step(model, data, nstep=100)
    assert data.qpos[2] - cube.resting_height() > 0.06, "the cube is lifted with the fingers"


def test_bad_robot_files_and_tips_are_named(tmp_path):
    with pytest.raises(ValueError, match="mjcf"):
        Robot.from_mjcf(tmp_path / "missing.xml")
    bare = tmp_path / "bare.xml"
    bare.write_text(
        '<mujoco><worldbody><body><joint/><geom size="0.01"/></body></worldbody></mujoco>'
    )
    with pytest.raises(ValueError, match="tips must name the fingertip sites"):
        Robot.from_mjcf(bare)
    with pytest.raises(ValueError, match="tips must be a sequence"):
        Robot.from_mjcf(GRIPPER, "left_tip")
    with pytest.raises(ValueError, match="n_tips"):
        Robot.point_tips(0)
    with pytest.raises(ValueError, match=r"joints must have shape \(\.\.\., 9\)"):
        Robot.point_tips(3)(torch.zeros(8))
