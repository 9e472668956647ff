"""Fitting K and D: the precomputed step is the model's, a known K is recovered, checkpoints."""

import dataclasses
import json

import pytest
import torch

from torchcontact.checkpoint import (
    STIFFNESS_KINDS,
    FitConfig,
    build_model,
    constant_model,
    load_checkpoint,
    load_model,
    save_checkpoint,
    save_model,
)
from torchcontact.cli import main
from torchcontact.cli.run import parse_args
from torchcontact.digests import file_sha256
from torchcontact.integrate import JointLayout, integrate
from torchcontact.learn.data import collect, load
from torchcontact.learn.evaluate import one_step_error, rollout_error, sweep_constant
from torchcontact.learn.fit import StepData, fit, fit_steps, predict_poses, system_terms
from torchcontact.learn.scenes import make_scene
from torchcontact.mpc.models import load_learned


@pytest.fixture(scope="module")
def transitions(tmp_path_factory):
    directory = tmp_path_factory.mktemp("fit")
    collect(directory, "trifinger", trajectories=4, steps=12, progress=False)
    return load(directory)


@pytest.mark.parametrize("kind", STIFFNESS_KINDS)
def test_precomputed_step_equals_the_model(transitions, kind):
    meta = transitions.meta
    model = build_model(FitConfig(stiffness=kind, damping=kind), meta).double()
    data = StepData.from_transitions(transitions, dtype=torch.float64)
    Q, b = system_terms(meta, transitions.u)
    v = model(Q, b, transitions.contacts.to(torch.float64), meta["h"], q=transitions.q)
    expected = integrate(transitions.q, v, meta["h"], JointLayout(meta["joints"]))[:, :7]
    order = torch.argsort(transitions.trajectory * 100 + transitions.step)
    torch.testing.assert_close(predict_poses(model, data)[:, 0, 0], expected[order])


def _synthetic(transitions, stiffness):
    """The dataset with q_next replaced by the paper model's prediction at K = stiffness."""
    meta = transitions.meta
    model = constant_model(stiffness, meta).double()
    Q, b = system_terms(meta, transitions.u)
    with torch.no_grad():
        v = model(Q, b, transitions.contacts.to(torch.float64), meta["h"])
    q_next = integrate(transitions.q, v, meta["h"], JointLayout(meta["joints"]))
    return dataclasses.replace(transitions, q_next=q_next)


def test_fit_recovers_a_known_constant_stiffness(transitions):
    synthetic = _synthetic(transitions, 2.5)
    train, val, _ = synthetic.split(seed=0)
    meta = synthetic.meta
    config = FitConfig(
        stiffness="constant", damping="paper", epochs=150, batch_size=64, lr=0.05, patience=150
    )
    model = build_model(config, meta)
    assert model.stiffness.log_value.detach().exp().item() == pytest.approx(0.5)
    result = fit_steps(
        model,
        StepData.from_transitions(train),
        StepData.from_transitions(val),
        tuple(meta["pose_weights"]),
        config,
        progress=False,
    )
    assert result.model.stiffness.log_value.detach().exp().item() == pytest.approx(2.5, rel=0.03)
    assert result.val_loss <= min(row["val_loss"] for row in result.history)


def test_plain_tensors_give_the_datasets_step_and_recover_a_known_stiffness(transitions):
    """``fit`` needs no dataset folder or manifest: the scene's system and the rows."""
    meta = transitions.meta
    system = make_scene("trifinger", "cube").system
    order = torch.argsort(transitions.trajectory * 100 + transitions.step)
    rows = (transitions.q, transitions.u, transitions.q_next, transitions.contacts)
    plain = StepData.from_tensors(*(row[order] for row in rows), system, meta["h"], meta["joints"])
    stored = StepData.from_transitions(transitions)
    for field in ("q", "u", "metric", "bias", "B", "pose", "target", "object_rows"):
        torch.testing.assert_close(getattr(plain, field), getattr(stored, field))
    moved = transitions.previous_displacement()[order]
    with_motion = StepData.from_tensors(
        *(row[order] for row in rows), system, meta["h"], meta["joints"], displacement=moved
    )
    torch.testing.assert_close(with_motion.displacement, stored.displacement)
    assert bool((plain.displacement == 0).all())  # no displacement given: at rest
    assert bool((plain.objects == 0).all())  # plain rows: one object
    torch.testing.assert_close(plain.objects, stored.objects)
    with pytest.raises(ValueError, match="displacement"):
        StepData.from_tensors(*rows, system, 0.1, meta["joints"], displacement=moved[:, :3])
    synthetic = _synthetic(transitions, 2.5)
    config = FitConfig(
        stiffness="constant", damping="paper", epochs=150, batch_size=64, lr=0.05, patience=150
    )
    result = fit(
        build_model(config, meta),
        synthetic.q,
        synthetic.u,
        synthetic.q_next,
        synthetic.contacts,
        system,
        meta["h"],
        meta["joints"],
        config,
        tuple(meta["pose_weights"]),
        progress=False,
    )
    assert result.model.stiffness.value == pytest.approx(2.5, rel=0.03)
    with pytest.raises(ValueError, match="u must have"):
        StepData.from_tensors(transitions.q, transitions.u[:3], *rows[2:], system, 0.1, ["free"])
    with pytest.raises(ValueError, match="loss_horizon must be 1"):
        fit(
            build_model(config, meta), *rows, system, 0.1, meta["joints"], FitConfig(loss_horizon=2)
        )


def test_learned_network_beats_the_initial_model_on_its_training_loss(transitions):
    meta = transitions.meta
    config = FitConfig(stiffness="contact_network", damping="relative", epochs=5, patience=5)
    data = StepData.from_transitions(transitions)
    weights = tuple(meta["pose_weights"])
    result = fit_steps(build_model(config, meta), data, data, weights, config, progress=False)
    initial = one_step_error(build_model(config, meta), data, meta["pose_weights"])
    learned = one_step_error(result.model, data, meta["pose_weights"])
    assert learned["combined"] <= initial["combined"]


def test_checkpoint_round_trip_and_bad_file(transitions, tmp_path):
    meta = transitions.meta
    config = FitConfig(stiffness="object_network", damping="contact_network", hidden=8)
    model = build_model(config, meta)
    with torch.no_grad():
        for parameter in model.parameters():
            parameter.add_(0.1 * torch.randn_like(parameter))
    path = save_checkpoint(tmp_path / "model.pt", model, config, meta)
    loaded, loaded_config, loaded_meta = load_checkpoint(path)
    assert loaded_config == config and loaded_meta == meta
    data = StepData.from_transitions(transitions)
    torch.testing.assert_close(predict_poses(loaded, data), predict_poses(model, data))
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(ValueError, match="model.pt: not a readable checkpoint"):
        load_checkpoint(path)


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="stiffness must be one of"):
        FitConfig(stiffness="spline")
    with pytest.raises(ValueError, match="damping must be one of"):
        FitConfig(damping="relative_to_nothing")
    with pytest.raises(ValueError, match="epochs must be a positive integer"):
        FitConfig(epochs=0)


def test_one_step_rollout_equals_the_one_step_error(transitions):
    """A 1-step rollout re-detects contacts at the recorded states: the same prediction."""
    meta = transitions.meta
    detector = make_scene("trifinger", "cube").plant.detector
    model = constant_model(0.5, meta)
    rollout = rollout_error(model, transitions, detector, horizon=1, stride=1)
    data = StepData.from_transitions(transitions, dtype=torch.float64)
    one_step = one_step_error(model, data, meta["pose_weights"])
    assert rollout["windows"] == len(transitions)
    for key in ("pos_mm", "angle_deg", "combined"):
        assert rollout[key] == pytest.approx(one_step[key], rel=1e-4, abs=1e-6)
    recorded = rollout_error(model, transitions, detector, horizon=1, stride=1, robot="recorded")
    assert recorded == rollout  # after one step only the next step would see the robot reset
    with pytest.raises(ValueError, match="robot must be"):
        rollout_error(model, transitions, detector, robot="teleported")
    sweep = sweep_constant([0.1, 1.0], transitions, detector, horizon=3, stride=3)
    assert [row["stiffness"] for row in sweep] == [0.1, 1.0]
    assert all(row["windows"] == 16 for row in sweep)  # steps 0, 3, 6, 9 of 4 trajectories


def test_fit_on_tensors_saves_loads_and_plans_with_learned(transitions, tmp_path, capsys):
    """fit(None, ...) builds its model from the config; save_model writes it with a manifest
    of the fit; load_model and ``run trifinger --learned`` read it; another scene refuses it."""
    meta = transitions.meta
    system = make_scene("trifinger", "cube").system
    rows = (transitions.q, transitions.u, transitions.q_next, transitions.contacts)
    config = FitConfig(stiffness="per_row", damping="relative", epochs=3, batch_size=16)
    result = fit(
        None, *rows, system, meta["h"], meta["joints"], config, progress=False, scene="trifinger"
    )
    assert result.config == config and result.meta["scene"] == "trifinger"
    assert result.meta["slots"] == transitions.contacts.slots and result.meta["nu"] == 9
    path = save_model(tmp_path / "mine.pt", result)
    manifest = json.loads(path.with_suffix(".json").read_text())
    n = len(transitions.q)
    assert manifest["dataset"] == {
        "transitions": n,
        "train": n - round(0.2 * n),
        "val": round(0.2 * n),
    }
    assert manifest["fit"]["stiffness"] == "per_row" and manifest["fit"]["epochs_run"] <= 3
    assert manifest["sha256"] == file_sha256(path) and manifest["environment"] == "trifinger"
    assert set(manifest["versions"]) == {"torchcontact", "torch", "mujoco"}
    validation = manifest["validation"]
    assert validation["val_loss"] == result.val_loss
    assert validation["position_error_mm"] >= 0 and validation["hold_still_position_error_mm"] > 0
    loaded = load_model(path)
    for a, b in zip(result.model.state_dict().values(), loaded.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert load_learned(str(path), "trifinger").stiffness.__class__.__name__ == "PerRow"
    assert parse_args(["trifinger", "--learned", str(path)]).learned == str(path.resolve())
    argv = ["run", "fingertips", "--trials", "1", "--learned", str(path), "--no-progress"]
    with pytest.raises(SystemExit) as info:
        main(argv)
    err = capsys.readouterr().err.strip()
    assert info.value.code == 2 and len(err.splitlines()) == 1, err
    assert "learned in the 'trifinger' environment, not 'fingertips'" in err
    mismatched = FitConfig(stiffness="constant", damping="relative", epochs=1)
    given = fit(build_model(FitConfig(), meta), *rows, system, 0.1, meta["joints"], mismatched,
                progress=False)  # fmt: skip
    with pytest.raises(ValueError, match="^model is not the architecture config and meta"):
        save_model(tmp_path / "other.pt", given)
    with pytest.raises(TypeError, match="^model must be a ComplementarityFree or None"):
        fit("per_row", *rows, system, 0.1, meta["joints"], config)
