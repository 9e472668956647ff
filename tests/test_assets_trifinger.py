"""The TriFinger model (assets/trifinger.xml): structure, fingertip FK against MuJoCo, PD hold."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from torchcontact.assets import asset_path
from torchcontact.sim.kinematics import FingertipKinematics

TIPS = ("tip0", "tip1", "tip2")
JOINTS = tuple(f"finger{i}_{j}" for i in range(3) for j in range(3))
INITIAL = np.array([0.0, -0.7, -1.1] * 3)
KP, KD = 10.0, 0.05  # the PD law applied in code: tau = KP (q_des - q) - KD qdot + bias


@pytest.fixture(scope="module")
def model():
    return mujoco.MjModel.from_xml_path(str(asset_path("trifinger.xml")))


@pytest.fixture(scope="module")
def fk():
    return FingertipKinematics(asset_path("trifinger.xml"), TIPS, dtype=torch.float64)


def site_positions(model, joints):
    """MuJoCo's tip sites after mj_kinematics, for joints (..., 9) -> (..., 3, 3)."""
    data = mujoco.MjData(model)
    flat = joints.reshape(-1, 9)
    out = np.empty((len(flat), 3, 3))
    sites = [model.site(name).id for name in TIPS]
    for k, q in enumerate(flat):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        out[k] = data.site_xpos[sites]
    return out.reshape(*joints.shape[:-1], 3, 3)


def random_joints(model, shape, seed=0):
    low, high = model.jnt_range[:, 0], model.jnt_range[:, 1]
    return np.random.default_rng(seed).uniform(low, high, size=(*shape, 9))


def test_structure(model):
    assert model.njnt == 9 and model.nq == 9 and model.nv == 9 and model.nu == 9
    assert tuple(model.joint(j).name for j in range(9)) == JOINTS
    assert (model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE).all()
    np.testing.assert_array_equal(model.jnt_qposadr, np.arange(9))
    assert not model.jnt_pos.any()  # offsets live in the bodies (pytorch-kinematics needs this)
    assert model.jnt_limited.all() and (model.jnt_range[:, 0] < model.jnt_range[:, 1]).all()
    assert ((model.jnt_range[:, 0] < INITIAL) & (INITIAL < model.jnt_range[:, 1])).all()
    assert tuple(model.actuator(a).name for a in range(9)) == JOINTS
    np.testing.assert_array_equal(model.actuator_trnid[:, 0], np.arange(9))
    np.testing.assert_array_equal(model.actuator_gear[:, 0], np.ones(9))
    assert not model.actuator_ctrllimited.any()
    assert model.nsite == 3
    for i, name in enumerate(TIPS):
        site, geom = model.site(name), model.geom(f"tip{i}_geom")
        assert geom.type[0] == mujoco.mjtGeom.mjGEOM_SPHERE and site.bodyid[0] == geom.bodyid[0]
        np.testing.assert_array_equal(site.pos, geom.pos)  # the site is the sphere's centre
        assert model.body(site.bodyid[0]).name.startswith(f"finger{i}_")
        assert geom.friction[0] == pytest.approx(0.9)
    for b in range(1, model.nbody):
        assert model.body(b).name.startswith(("finger0_", "finger1_", "finger2_"))
    assert model.body_mass.sum() == pytest.approx(3 * (0.26689 + 0.27163 + 0.05569 + 0.0092))


def test_collision_filters(model):
    """Every geom touches an object with contype = conaffinity = 1; links never touch links."""
    geoms = [model.geom(g) for g in range(model.ngeom)]
    assert all(g.type[0] != mujoco.mjtGeom.mjGEOM_MESH for g in geoms)
    for g in geoms:
        assert (g.contype[0] & 1) or (g.conaffinity[0] & 1), g.name
    links = [g for g in geoms if not g.name.startswith("tip")]
    for a in links:
        for b in links:
            assert not (a.contype[0] & b.conaffinity[0] or b.contype[0] & a.conaffinity[0])
    data = mujoco.MjData(model)
    data.qpos[:] = INITIAL
    mujoco.mj_forward(model, data)
    assert data.ncon == 0  # nothing of the robot touches itself at the initial configuration


def test_fk_matches_mujoco_sites(model, fk):
    joints = random_joints(model, (5, 10))
    joints[0, 0] = INITIAL
    expected = site_positions(model, joints)
    got = fk(torch.from_numpy(joints))
    assert got.shape == (5, 10, 3, 3) and got.dtype == torch.float64
    np.testing.assert_allclose(got.numpy(), expected, rtol=0, atol=1e-6)

    fk32 = FingertipKinematics(asset_path("trifinger.xml"), TIPS, dtype=torch.float32)
    got32 = fk32(torch.from_numpy(joints).float())
    assert got32.dtype == torch.float32
    np.testing.assert_allclose(got32.double().numpy(), expected, rtol=0, atol=1e-4)


def test_fk_gradient_matches_finite_differences(model, fk):
    joints = torch.from_numpy(random_joints(model, (3,), seed=1)).requires_grad_(True)
    assert torch.autograd.gradcheck(fk, (joints,), eps=1e-6, atol=1e-7, rtol=1e-5)


def test_initial_configuration_puts_tips_low_around_the_centre(model, fk):
    tips = fk(torch.from_numpy(INITIAL)).numpy()
    np.testing.assert_allclose(tips, site_positions(model, INITIAL), atol=1e-9)
    radius = model.geom("tip0_geom").size[0]
    print(f"\ninitial tips [m]:\n{np.array2string(tips, precision=4)}\ntip radius {radius} m")
    assert (tips[:, 2] > radius - 1e-4).all()
    assert (np.linalg.norm(tips[:, :2], axis=1) < 0.1).all()
    # 120-degree symmetry: equal heights and distances from the centre axis
    np.testing.assert_allclose(tips[:, 2], tips[0, 2], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(tips[:, :2], axis=1), np.hypot(*tips[0, :2]))


@pytest.mark.parametrize("offset", [0.0, 0.03])
def test_pd_law_holds_the_initial_configuration(model, offset):
    """tau = 10 (q_des - q) - 0.05 qdot + qfrc_bias, q_des = initial, 1 s at dt 0.002."""
    data = mujoco.MjData(model)
    assert model.opt.timestep == pytest.approx(0.002) and model.opt.gravity[2] < 0
    data.qpos[:] = INITIAL + offset * np.array([1, -1, 1, -1, 1, -1, 1, -1, 1])
    mujoco.mj_forward(model, data)
    errors = []
    for _ in range(500):
        data.ctrl[:] = KP * (INITIAL - data.qpos) - KD * data.qvel + data.qfrc_bias
        mujoco.mj_step(model, data)
        errors.append(np.abs(data.qpos - INITIAL).max())
    errors = np.array(errors)
    assert np.isfinite(errors).all() and errors.max() < 0.05
    assert errors[-250:].max() < 0.01  # settles within half a second
    assert np.abs(data.qvel).max() < 0.1
