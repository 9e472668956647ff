"""Full-dynamic quantities from MuJoCo, and the contact-free step against MuJoCo's own Euler."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from torchcontact import ComplementarityFree, Contacts, cf_velocity, full_dynamic, integrate
from torchcontact.sim import ContactDetector, bias_force, joint_layout, mass_matrix

XML = """
<mujoco>
  <option timestep="{h}" integrator="Euler" gravity="0 0 -9.81">
    <flag contact="{contact}"/>
  </option>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="object" pos="0 0 0.5"><freejoint/>
      <inertial pos="0.01 -0.02 0.005" mass="0.3" fullinertia="2e-3 3e-3 4e-3 2e-4 -1e-4 3e-4"/>
      <geom type="box" size="0.05 0.04 0.03"/>
    </body>
    <body name="arm" pos="1 0 1">
      <joint type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
      <body pos="0.3 0 0">
        <joint type="hinge" axis="0 1 0"/><joint type="slide" axis="1 0 0"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0.1" size="0.02"/>
        <body pos="0.2 0 0.1"><joint type="ball"/><geom type="box" size="0.02 0.03 0.01"/></body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
H = 0.01


def _model(contact: str = "disable", h: float = H) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(XML.format(h=h, contact=contact))


def _random_data(model: mujoco.MjModel, seed: int) -> mujoco.MjData:
    rng = np.random.default_rng(seed)
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    data.qpos[0:3] = rng.normal(size=3)
    for start in (3, model.nq - 4):  # the free joint's and the ball's quaternions
        quat = rng.normal(size=4)
        data.qpos[start : start + 4] = quat / np.linalg.norm(quat)
    data.qpos[7:10] = rng.normal(size=3)
    data.qvel[:] = rng.normal(size=model.nv) * 2
    data.qfrc_applied[:] = rng.normal(size=model.nv)
    data.xfrc_applied[1] = rng.normal(size=6)  # a force and torque on the object
    mujoco.mj_forward(model, data)
    return data


def _composite_inertia(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """M = Σ_bodies m JₚᵀJₚ + Jᵣᵀ I_world Jᵣ, from each body's centre-of-mass Jacobian."""
    M = np.zeros((model.nv, model.nv))
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    for body in range(1, model.nbody):
        mujoco.mj_jacBodyCom(model, data, jacp, jacr, body)
        R = data.ximat[body].reshape(3, 3)
        inertia = R @ np.diag(model.body_inertia[body]) @ R.T
        M += model.body_mass[body] * jacp.T @ jacp + jacr.T @ inertia @ jacr
    return M


def test_joint_layout_types():
    layout = joint_layout(_model())
    assert layout.joints == ("free", "hinge", "hinge", "slide", "ball")
    assert (layout.nq, layout.nv) == (14, 12)


@pytest.mark.parametrize("seed", range(3))
def test_mass_matrix_is_mujocos_inertia(seed):
    model = _model()
    data = _random_data(model, seed)
    M = mass_matrix(model, data)
    assert M.shape == (model.nv, model.nv)
    np.testing.assert_allclose(M, M.T, rtol=0, atol=1e-15)
    np.testing.assert_allclose(M, _composite_inertia(model, data), rtol=1e-10, atol=1e-14)
    product = np.zeros(model.nv)
    for i in range(model.nv):
        mujoco.mj_mulM(model, data, product, np.eye(model.nv)[i])
        np.testing.assert_allclose(M[:, i], product, rtol=0, atol=1e-14)
    assert np.linalg.eigvalsh(M).min() > 0


def test_bias_force_is_qfrc_bias_and_gravity_at_rest():
    model = _model()
    data = _random_data(model, 0)
    bias = bias_force(data)
    np.testing.assert_array_equal(bias, data.qfrc_bias)
    bias[:] = 0  # a copy: writing to it leaves data alone
    assert np.abs(data.qfrc_bias).sum() > 0
    data.qvel[:] = 0
    mujoco.mj_forward(model, data)
    gravity = np.zeros(model.nv)  # −Σ Jₚᵀ m g: no Coriolis at rest
    jacp = np.zeros((3, model.nv))
    for body in range(1, model.nbody):
        mujoco.mj_jacBodyCom(model, data, jacp, None, body)
        gravity -= jacp.T @ (model.body_mass[body] * model.opt.gravity)
    np.testing.assert_allclose(bias_force(data), gravity, rtol=1e-12, atol=1e-14)


def _generalized_force(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """τ = qfrc_applied + Jᵀ xfrc_applied − bias, the applied wrench mapped independently."""
    tau = data.qfrc_applied.copy()
    for body in range(1, model.nbody):
        force, torque = data.xfrc_applied[body, :3], data.xfrc_applied[body, 3:]
        mujoco.mj_applyFT(model, data, force, torque, data.xipos[body], body, tau)
    return tau - bias_force(data)


@pytest.mark.parametrize("seed", range(3))
def test_contact_free_step_matches_mujoco_euler(seed):
    """Q = M/h², b = Mv/h + τ with no contact rows gives MuJoCo's semi-implicit Euler step."""
    model = _model()
    data = _random_data(model, seed)
    layout = joint_layout(model)
    q, v = data.qpos.copy(), data.qvel.copy()
    M = torch.tensor(mass_matrix(model, data))
    tau = torch.tensor(_generalized_force(model, data))
    Q, b = full_dynamic(M, torch.tensor(v), tau, H)
    no_rows = torch.zeros(0, model.nv, dtype=torch.float64)
    v_next = cf_velocity(Q, b, no_rows, torch.zeros(0, dtype=torch.float64), H, 1.0, 0.1)
    q_next = integrate(torch.tensor(q), v_next, H, layout)
    mujoco.mj_step(model, data)
    assert data.ncon == 0
    np.testing.assert_allclose(v_next.numpy(), data.qvel, rtol=1e-10, atol=1e-10)
    sign = np.ones(model.nq)  # quaternions up to sign
    for start in (3, model.nq - 4):
        if q_next[start : start + 4].numpy() @ data.qpos[start : start + 4] < 0:
            sign[start : start + 4] = -1
    np.testing.assert_allclose(sign * q_next.numpy(), data.qpos, rtol=0, atol=1e-12)


def test_far_contacts_leave_the_free_step_unchanged():
    """Active but far contacts (exact max, large K) exert nothing: v⁺ = v + hM⁻¹τ."""
    plant = _model()
    data = _random_data(plant, 4)
    data.qpos[0:3] = [0, 0, 0.3]  # the object 30 cm above the floor, falling slowly
    data.qvel[0:3] = [0.1, 0, -0.2]
    mujoco.mj_forward(plant, data)
    detector = ContactDetector(
        _model(contact="enable"), ["object"], slots=8, margin=0.5, dtype=torch.float64
    )
    contacts = detector(data.qpos)
    assert int(contacts.n_active()) >= 4 and float(contacts.phi[contacts.active].min()) > 0.2
    M = torch.tensor(mass_matrix(plant, data))
    Q, b = full_dynamic(
        M, torch.tensor(data.qvel), torch.tensor(_generalized_force(plant, data)), H
    )
    model = ComplementarityFree(stiffness=1e4, gamma=None)
    v_next, beta = model.row_impulses(Q, b, contacts, H)
    assert torch.all(beta == 0)
    mujoco.mj_step(plant, data)
    np.testing.assert_allclose(v_next.detach().numpy(), data.qvel, rtol=1e-10, atol=1e-10)
    # The same contacts but close: the rows now push and the step changes.
    near = Contacts(
        phi=torch.where(contacts.active, torch.zeros_like(contacts.phi), contacts.phi),
        jac_normal=contacts.jac_normal,
        jac_tangent=contacts.jac_tangent,
        mu=contacts.mu,
        active=contacts.active,
    )
    with torch.no_grad():
        pushed, beta = model.row_impulses(Q, b, near, H)
    assert float(beta.max()) > 0
    assert float((pushed - v_next.detach()).abs().max()) > 1e-3
