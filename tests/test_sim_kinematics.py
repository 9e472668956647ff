"""Fingertip kinematics of files pytorch-kinematics' own parser cannot take: a free-jointed
object in the robot's file, several joints in one body, joints off their body's origin."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from torchcontact.sim.kinematics import FingertipKinematics, robot_joints

# a free box first; a base with three joints (two hinges off the origin, one with a reference
# angle, and a slide) under a turned frame; a link with one offset hinge; sites off the origin
ARM = """
<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <body name="box" pos="0.3 0 0.05">
      <freejoint name="box_free"/>
      <geom type="box" size="0.03 0.03 0.03" mass="0.05"/>
      <site name="box_tip"/>
    </body>
    <body name="base" pos="0.1 0.2 0.3" quat="0.9 0.1 0.3 0.2">
      <joint name="yaw" type="hinge" axis="0 0 1" pos="0.01 0.02 0" ref="0.3"/>
      <joint name="pitch" type="hinge" axis="0 1 0" pos="0 0 0.05"/>
      <joint name="reach" type="slide" axis="1 0 0" range="0 0.1"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.01"/>
      <site name="base_tip" pos="0.1 0 0.02" quat="0.7 0.7 0 0"/>
      <body name="link" pos="0.2 0 0" euler="0.1 0.2 0.3">
        <joint name="elbow" type="hinge" axis="0 1 1" pos="0.03 0 0.01" range="-1 1"/>
        <geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.01"/>
        <body name="pad" pos="0.15 0 0">
          <geom type="sphere" size="0.01"/>
          <site name="link_tip" pos="0.01 0.01 0"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

TIPS = ("link_tip", "base_tip")


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    path = tmp_path_factory.mktemp("arm") / "arm.xml"
    path.write_text(ARM)
    return path


def _mujoco_tips(path, joints: np.ndarray, tips=TIPS) -> tuple[np.ndarray, np.ndarray]:
    """Sites ``(B, n_tips, 3)`` and their Jacobians ``(B, n_tips, 3, n_joints)`` by MuJoCo, the
    robot's joints after the box's free joint."""
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    sites = [model.site(name).id for name in tips]
    positions, jacobians = [], []
    jac = np.zeros((3, model.nv))
    for q in joints:
        data.qpos[:] = model.qpos0
        data.qpos[7:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        positions.append(data.site_xpos[sites].copy())
        rows = []
        for site in sites:
            mujoco.mj_jacSite(model, data, jac, None, site)
            rows.append(jac[:, 6:].copy())
        jacobians.append(rows)
    return np.array(positions), np.array(jacobians)


def test_a_free_object_and_multi_joint_bodies_match_mujoco(arm):
    fk = FingertipKinematics(arm, TIPS)
    assert fk.joint_names == ("yaw", "pitch", "reach", "elbow")
    joints = np.random.default_rng(0).uniform(-1.0, 1.0, (16, 4))
    expected, expected_jac = _mujoco_tips(arm, joints)
    q = torch.tensor(joints)
    np.testing.assert_allclose(fk(q).numpy(), expected, atol=1e-12)
    jac = torch.stack([torch.func.jacrev(fk)(x) for x in q])  # (B, n_tips, 3, n_joints)
    np.testing.assert_allclose(jac.numpy(), expected_jac, atol=1e-12)


def test_the_chain_moves_with_the_module(arm):
    fk = FingertipKinematics(arm, TIPS).to(torch.float32)
    joints = np.random.default_rng(1).uniform(-1.0, 1.0, (4, 4))
    tips = fk(torch.tensor(joints, dtype=torch.float32))
    assert tips.dtype == torch.float32
    np.testing.assert_allclose(tips.numpy(), _mujoco_tips(arm, joints)[0], atol=1e-6)


def test_robot_joints_leave_the_object_out(arm):
    model = mujoco.MjModel.from_xml_path(str(arm))
    assert [model.joint(j).name for j in robot_joints(model)] == ["yaw", "pitch", "reach", "elbow"]


def test_what_the_chain_cannot_take_is_named(arm, tmp_path):
    with pytest.raises(ValueError, match="tips must be sites of the robot.*box_tip"):
        FingertipKinematics(arm, ["box_tip"])
    with pytest.raises(ValueError, match="tips must name sites.*nope"):
        FingertipKinematics(arm, ["nope"])
    with pytest.raises(ValueError, match="mjcf"):
        FingertipKinematics(tmp_path / "missing.xml", TIPS)
    ball = tmp_path / "ball.xml"
    ball.write_text(
        '<mujoco><worldbody><body name="b"><joint name="shoulder" type="ball"/>'
        '<geom size="0.01"/><site name="b_tip"/></body></worldbody></mujoco>'
    )
    with pytest.raises(ValueError, match="ball joints.*shoulder"):
        FingertipKinematics(ball, ["b_tip"])
