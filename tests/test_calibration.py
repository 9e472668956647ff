"""The system's learnable factors: positive, in state_dict, used by the MPC, recoverable."""

import dataclasses

import pytest
import torch

from torchcontact import ComplementarityFree
from torchcontact.calibration import PARTS, SystemCalibration
from torchcontact.checkpoint import FitConfig, build_model, load_checkpoint, save_checkpoint
from torchcontact.environments import environment
from torchcontact.environments.presets import MPCSettings
from torchcontact.integrate import JointLayout, integrate
from torchcontact.learn.data import affine_system, collect, load
from torchcontact.learn.fit import (
    StepData,
    carried,
    fit_steps,
    object_indices,
    predict_poses,
    step_terms,
)
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.systems import QuasiDynamic


def _calibration(n_robot=3, **logs) -> SystemCalibration:
    calibration = SystemCalibration(n_robot).double()
    with torch.no_grad():
        for name, value in logs.items():
            getattr(calibration, f"log_{name}").copy_(torch.as_tensor(value).log())
    return calibration


def test_factors_are_positive_and_apply_equals_terms():
    system = QuasiDynamic(
        torch.full((6,), 2.0), 3.0, torch.arange(6.0), n_robot=3, object_dofs=range(3, 9)
    ).double()
    calibration = _calibration(
        command_gain=[0.5, 1.2, 2.0], robot_stiffness=[3.0, 1.0, 0.2], object_metric=0.1
    )
    for name in PARTS:
        assert (calibration.factor(name) > 0).all()
    u = torch.randn(5, 3, dtype=torch.float64)
    Q, b = calibration.apply(system)(u)
    Q0, b0, B = affine_system(system)
    Q2, b2 = calibration.terms(Q0, b0, B, u, torch.arange(3, 9))
    torch.testing.assert_close((Q, b), (Q2.expand_as(Q), b2))
    # Unopposed, the robot moves gain · u; the object rows' metric is scaled, not their force.
    torch.testing.assert_close((b / Q)[:, :3], u * calibration.factor("command_gain"))
    torch.testing.assert_close(Q[3:], torch.full((6,), 0.2, dtype=torch.float64))
    torch.testing.assert_close(b[:, 3:], torch.arange(6.0, dtype=torch.float64).expand(5, 6))
    assert set(calibration.state_dict()) == {f"log_{name}" for name in PARTS}


def test_only_the_named_factors_learn_and_bad_names_are_refused():
    calibration = SystemCalibration(4, ("command_gain", "friction"))
    assert calibration.learned == ("command_gain", "friction")
    with pytest.raises(ValueError, match="learn must name factors of"):
        SystemCalibration(4, ("inertia",))
    with pytest.raises(ValueError, match="n_robot must be a positive integer"):
        SystemCalibration(0)
    with pytest.raises(ValueError, match="calibrate must name distinct factors"):
        FitConfig(calibrate=("command_gain", "command_gain"))
    with pytest.raises(ValueError, match="command_gain must be positive"):
        QuasiDynamic(torch.ones(6), 1.0, torch.zeros(6), n_robot=2, command_gain=[1.0, -1.0])


@pytest.fixture(scope="module")
def transitions(tmp_path_factory):
    directory = tmp_path_factory.mktemp("calibration")
    collect(directory, "trifinger", trajectories=6, steps=12, progress=False)
    return load(directory)


TRUE = {"command_gain": 1.3, "robot_stiffness": 0.5, "object_metric": 2.0}


def _synthetic(transitions, stiffness: float, factors: dict):
    """The dataset with q_next replaced by a calibrated model's own prediction."""
    meta = transitions.meta
    config = FitConfig(stiffness="constant", damping="paper", calibrate=tuple(factors))
    model = build_model(config, {**meta, "paper_stiffness": stiffness}).double()
    with torch.no_grad():
        for name, value in factors.items():
            getattr(model.calibration, f"log_{name}").fill_(float(value)).log_()
    Q0, b0, B = (torch.tensor(meta["system"][k], dtype=torch.float64) for k in ("Q", "b0", "B"))
    _, v_index = object_indices(meta["joints"])
    rows = v_index.flatten()
    Q, b = model.calibration.terms(Q0, b0, B, transitions.u, rows)
    Q, b = carried(model, Q, b, transitions.previous_displacement()[:, rows], rows)
    with torch.no_grad():
        v = model(Q, b, transitions.contacts.to(torch.float64), meta["h"])
    q_next = integrate(transitions.q, v, meta["h"], JointLayout(meta["joints"]))
    return dataclasses.replace(transitions, q_next=q_next), model


def test_fit_recovers_known_stiffness_command_gain_and_object_metric(transitions):
    synthetic, _ = _synthetic(transitions, 2.5, TRUE)
    train, val, _ = synthetic.split(seed=0)
    meta = synthetic.meta
    config = FitConfig(
        stiffness="constant",
        damping="paper",
        calibrate=tuple(TRUE),
        epochs=300,
        batch_size=32,
        lr=0.03,
        patience=300,
        robot_weight=100.0,
    )
    steps = [StepData.from_transitions(part, dtype=torch.float64) for part in (train, val)]
    result = fit_steps(build_model(config, meta), *steps, meta["pose_weights"], config, False)
    model = result.model
    assert model.stiffness.value == pytest.approx(2.5, rel=0.05)
    assert model.calibration.factor("command_gain").detach() == pytest.approx(1.3, rel=0.05)
    assert model.calibration.factor("object_metric").item() == pytest.approx(2.0, rel=0.1)
    assert model.calibration.factor("robot_stiffness").detach() == pytest.approx(0.5, rel=0.25)


def test_fit_recovers_a_known_object_momentum(transitions):
    """The object carries m = 1.5 of its previous step's motion; the fit finds m and ε."""
    true = {"object_metric": 2.0, "object_momentum": 1.5}
    synthetic, _ = _synthetic(transitions, 2.5, true)
    train, val, _ = synthetic.split(seed=0)
    meta = {**synthetic.meta, "paper_stiffness": 2.5}
    config = FitConfig(
        stiffness="constant", damping="paper", calibrate=tuple(true), epochs=300,
        batch_size=32, lr=0.03, patience=300,
    )  # fmt: skip
    model = build_model(config, meta)
    model.stiffness.requires_grad_(False)
    steps = [StepData.from_transitions(part, dtype=torch.float64) for part in (train, val)]
    model = fit_steps(model, *steps, meta["pose_weights"], config, False).model
    assert model.calibration.momentum.item() == pytest.approx(1.5, rel=0.1)
    assert model.calibration.factor("object_metric").item() == pytest.approx(2.0, rel=0.1)


def test_a_checkpoint_with_momentum_round_trips_and_the_mpc_carries_it(transitions, tmp_path):
    factors = {**TRUE, "object_momentum": 0.7}
    config = FitConfig(stiffness="constant", damping="paper", calibrate=tuple(factors))
    _, model = _synthetic(transitions, 2.5, factors)
    path = save_checkpoint(tmp_path / "model.pt", model.float(), config, transitions.meta)
    loaded = load_checkpoint(path)[0]
    assert loaded.calibration.learned == tuple(factors)
    assert loaded.calibration.summary()["object_momentum"] == pytest.approx([0.7])
    env = environment("trifinger")
    mpc = ContactImplicitMPC.from_env(
        env, env.make_plant("cube"), loaded, settings=MPCSettings(compile=False)
    )
    assert mpc.carries_momentum and float(mpc.system.object_momentum) == pytest.approx(0.7)
    plain = ComplementarityFree(2.5, calibration=SystemCalibration(9))
    settings = MPCSettings(compile=False)
    plain_mpc = ContactImplicitMPC.from_env(env, env.make_plant("cube"), plain, settings=settings)
    assert not plain_mpc.carries_momentum


def test_multi_step_loss_rolls_out_the_frozen_contacts_as_the_mpc_does(transitions):
    """A window's H-step prediction is H frozen steps of the model, the object integrated."""
    _, model = _synthetic(transitions, 2.5, TRUE)
    data = StepData.from_transitions(transitions, horizon=4, dtype=torch.float64, stride=4)
    poses = predict_poses(model, data)
    assert poses.shape == (len(data), 4, 1, 7)
    frozen = model.freeze(data.contacts[0], data.h, data.q[0])
    Q, b = step_terms(model, data)
    pose = data.pose[0].flatten()
    for t in range(4):
        v = frozen.velocity(Q[0, 0], b[0, t])
        pose = integrate(pose, v[data.object_rows], data.h, JointLayout(["free"]))
        torch.testing.assert_close(poses[0, t, 0], pose)


def test_a_calibrated_checkpoint_round_trips_and_drives_the_mpc(transitions, tmp_path):
    meta = transitions.meta
    config = FitConfig(stiffness="constant", damping="paper", calibrate=tuple(TRUE))
    _, model = _synthetic(transitions, 2.5, TRUE)
    path = save_checkpoint(tmp_path / "model.pt", model.float(), config, meta)
    loaded, loaded_config, _ = load_checkpoint(path)
    assert loaded_config.calibrate == tuple(TRUE)
    for name in PARTS:
        torch.testing.assert_close(loaded.calibration.factor(name), model.calibration.factor(name))
    env = environment("trifinger")
    plant = env.make_plant("cube")
    mpc = ContactImplicitMPC.from_env(env, plant, loaded, settings=MPCSettings(compile=False))
    base = env.system(plant)
    torch.testing.assert_close(
        mpc.system.command_gain, torch.full((9,), 1.3, dtype=mpc.system.command_gain.dtype)
    )
    torch.testing.assert_close(
        mpc.system.robot_stiffness, 0.5 * base.robot_stiffness.to(mpc.system.robot_stiffness)
    )
    initial, target = env.sample(plant, "in-hand", 0)
    plant.reset(initial, target)
    q = torch.as_tensor(plant.state())
    target = torch.as_tensor(target)
    plan = mpc.plan(q, plant.detector(q), target[:3], target[3:])
    assert torch.isfinite(plan.control).all() and plan.control.abs().max() > 0
