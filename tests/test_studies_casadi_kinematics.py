"""The hands' fingertips in CasADi, built from the MJCF, agree with MuJoCo's sites."""

import mujoco
import numpy as np
import pytest

from studies.casadi_kinematics import casadi_fingertips
from torchcontact.sim.hands import HANDS


@pytest.mark.parametrize("hand", sorted(HANDS))
def test_casadi_fingertips_agree_with_mujoco_sites(hand):
    hand = HANDS[hand]
    forward = casadi_fingertips(hand.mjcf, hand.tips)
    model = mujoco.MjModel.from_xml_path(str(hand.mjcf))
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    for _ in range(10):
        data.qpos[:] = rng.uniform(model.jnt_range[:, 0], model.jnt_range[:, 1])
        mujoco.mj_kinematics(model, data)
        sites = np.stack([data.site(name).xpos for name in hand.tips])
        np.testing.assert_allclose(np.asarray(forward(data.qpos)), sites, atol=1e-12)


def test_casadi_fingertips_refuse_bad_input(tmp_path):
    hand = HANDS["trifinger"]
    with pytest.raises(ValueError, match="mjcf"):
        casadi_fingertips(tmp_path / "missing.xml", hand.tips)
    with pytest.raises(ValueError, match="tips"):
        casadi_fingertips(hand.mjcf, [])
    with pytest.raises(ValueError, match="nail"):
        casadi_fingertips(hand.mjcf, ["nail"])
    ball = tmp_path / "ball.xml"
    ball.write_text(
        '<mujoco><worldbody><body><joint type="ball"/><geom size="0.01"/>'
        '<site name="tip"/></body></worldbody></mujoco>'
    )
    with pytest.raises(ValueError, match="hinges or slides"):
        casadi_fingertips(ball, ["tip"])
