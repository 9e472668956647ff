"""The multi-step training loss with each object's contact geometry re-evaluated along it."""

import dataclasses
import pickle

import pytest
import torch

from torchcontact.calibration import MOMENTUM, PARTS
from torchcontact.checkpoint import FitConfig, build_model, load_checkpoint, save_checkpoint
from torchcontact.integrate import JointLayout, integrate, object_indices
from torchcontact.learn.data import collect, load_objects
from torchcontact.learn.fit import (
    StepData,
    carried,
    fit_steps,
    predict,
    step_terms,
    window_loss,
)
from torchcontact.learn.scenes import make_scene
from torchcontact.sim.geometry import scene_geometry

OBJECTS = ("cube", "foam_brick")
"""Two Allegro objects whose detectors keep 16 and 17 slots: the dataset pads to 17."""


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """Two objects' random-action windows of 3 steps (float64) and their geometries."""
    directories = []
    for obj in OBJECTS:
        directories.append(tmp_path_factory.mktemp(obj))
        collect(directories[-1], "allegro", obj, trajectories=2, steps=8, progress=False)
    transitions = load_objects(directories)
    detectors = [make_scene("allegro", obj).plant.detector for obj in OBJECTS]
    geometries = [scene_geometry(d, dtype=torch.float64) for d in detectors]
    data = StepData.from_transitions(transitions, horizon=3, dtype=torch.float64)
    return transitions, data, geometries


def _model(meta, horizon=3, contacts="geometry"):
    config = FitConfig(
        calibrate=(*PARTS, MOMENTUM), loss_horizon=horizon, loss_contacts=contacts, hidden=8
    )
    model = build_model(config, meta).double()
    with torch.no_grad():  # away from the initial state, where every factor is 1
        for parameter in model.parameters():
            parameter.add_(0.05 * torch.randn_like(parameter))
    return model, config


def test_windows_know_their_objects(scene):
    transitions, data, geometries = scene
    assert [g.slots for g in geometries] == [16, 17] and data.contacts.slots == 17
    assert sorted(torch.unique(data.objects).tolist()) == [0, 1]
    first = transitions.windows(3)[:, 0]
    assert torch.equal(data.objects, transitions.object[first])
    part = data.select(data.objects == 1)
    assert bool((part.objects == 1).all()) and torch.equal(part.object_q, data.object_q)
    q_index, _ = object_indices(transitions.meta["joints"])
    torch.testing.assert_close(data.q[:, data.object_q], data.pose.flatten(-2))
    torch.testing.assert_close(data.q[:, data.robot_q], data.robot)
    assert data.object_q.tolist() == q_index.flatten().tolist()


def test_geometry_rollout_is_the_model_at_each_predicted_state(scene):
    """Each window stepped alone by the full model from the loss's predicted full state, with
    contacts of its own object's geometry there after the first step: the loss's next
    prediction, for windows of both objects mixed. The geometry sees each object's states
    together, as the loss does, and each step starts from the loss's own state: a patch point
    at a switch (``SPREAD``, a tie between a box face's corners) may be kept or not by a
    rounding, so a rollout of its own would part from the loss's without a fault in either."""
    transitions, data, geometries = scene
    meta = transitions.meta
    torch.manual_seed(0)
    model, _ = _model(meta)
    order = torch.randperm(len(data))[:6]
    mixed = data.select(order)
    objects = mixed.objects.tolist()
    assert len(set(objects)) == 2
    with torch.no_grad():
        poses, robot = predict(model, mixed, geometries)
        Q, b = step_terms(model, mixed)
        layout = JointLayout(meta["joints"])
        q, moved = mixed.q.clone(), mixed.displacement.clone()
        for t in range(mixed.horizon):
            contacts = [mixed.contacts[row] for row in range(len(mixed))]
            if t > 0:  # the loss's state after step t - 1
                q[:, mixed.object_q] = poses[:, t - 1].flatten(-2)
                q[:, mixed.robot_q] = robot[:, t - 1]
                for k in set(objects):
                    rows = [row for row, obj in enumerate(objects) if obj == k]
                    found = geometries[k](q[rows]).padded(17)
                    for i, row in enumerate(rows):
                        contacts[row] = found[i]
            for row in range(len(mixed)):
                Qt, bt = carried(model, Q[row, 0], b[row, t], moved[row], mixed.object_rows)
                v = model(Qt, bt, contacts[row], meta["h"], q=q[row])
                moved[row] = meta["h"] * v[mixed.object_rows]
                after = integrate(q[row], v, meta["h"], layout)
                torch.testing.assert_close(poses[row, t].flatten(), after[mixed.object_q])
                torch.testing.assert_close(robot[row, t], after[mixed.robot_q])


def test_geometry_changes_the_loss_and_its_gradient_is_finite(scene):
    transitions, data, geometries = scene
    meta = transitions.meta
    torch.manual_seed(1)
    model, config = _model(meta)
    weights = tuple(meta["pose_weights"])
    frozen = window_loss(model, data, weights, 1.0)
    geometry = window_loss(model, data, weights, 1.0, geometries)
    assert torch.isfinite(geometry)
    assert abs(geometry.item() - frozen.item()) > 1e-6 * frozen.item()
    grads = torch.autograd.grad(geometry, list(model.stiffness.parameters()))
    frozen_grads = torch.autograd.grad(frozen, list(model.stiffness.parameters()))
    assert all(bool(g.isfinite().all()) for g in grads)
    assert any(bool(g.abs().sum() > 0) for g in grads)
    assert not all(torch.allclose(a, b) for a, b in zip(grads, frozen_grads, strict=True))
    # the first step of a window is the recorded contacts' in both
    with torch.no_grad():
        first_frozen = predict(model, data)[0][:, 0]
        first_geometry = predict(model, data, geometries)[0][:, 0]
    assert torch.equal(first_frozen, first_geometry)


def test_one_step_losses_are_equal(scene):
    transitions, data, geometries = scene
    meta = transitions.meta
    model, _ = _model(meta, horizon=2)
    first = data.first_steps()
    weights = tuple(meta["pose_weights"])
    frozen = window_loss(model, first, weights, 1.0)
    assert torch.equal(window_loss(model, first, weights, 1.0, geometries), frozen)


def test_fit_steps_with_the_geometry(scene):
    """A short fit moves K with the geometry in the loss; the geometries must match the
    config and hold every window's object."""
    transitions = scene[0]
    meta = transitions.meta
    data = StepData.from_transitions(transitions, horizon=3)  # float32, as learn-k fits
    train, val = data.select(data.objects == 0), data.select(data.objects == 1)
    config = FitConfig(
        stiffness="constant", damping="paper", loss_horizon=3, loss_contacts="geometry",
        epochs=2, lr=0.1, batch_size=64,
    )  # fmt: skip
    weights = tuple(meta["pose_weights"])
    singles = [
        scene_geometry(make_scene("allegro", obj).plant.detector, dtype=torch.float64)
        for obj in OBJECTS
    ]
    result = fit_steps(build_model(config, meta), train, val, weights, config, False, singles)
    assert all(g.tree.offset_position.dtype == torch.float32 for g in singles)  # the fit's
    assert len(result.history) == 2
    assert all(torch.isfinite(torch.tensor(row["train_loss"])) for row in result.history)
    assert result.model.stiffness.value != pytest.approx(build_model(config, meta).stiffness.value)
    with pytest.raises(ValueError, match="geometries must give each object's contact geometry"):
        fit_steps(build_model(config, meta), train, val, weights, config, False)
    with pytest.raises(ValueError, match="geometries must hold object 1"):
        fit_steps(build_model(config, meta), train, val, weights, config, False, singles[:1])
    frozen = dataclasses.replace(config, loss_contacts="frozen")
    with pytest.raises(ValueError, match="only with config.loss_contacts 'geometry'"):
        fit_steps(build_model(frozen, meta), train, val, weights, frozen, False, singles)


def test_loss_contacts_is_validated_and_old_configs_load_frozen(scene, tmp_path):
    with pytest.raises(ValueError, match=r"loss_contacts must be one of \('frozen', 'geometry'\)"):
        FitConfig(loss_contacts="detector", loss_horizon=4)
    with pytest.raises(ValueError, match="loss_contacts 'geometry' needs a loss_horizon above 1"):
        FitConfig(loss_contacts="geometry")
    assert FitConfig().loss_contacts == "frozen"
    assert FitConfig(loss_horizon=2, loss_contacts="geometry").loss_contacts == "geometry"
    # a checkpoint written before the field: its config has no loss_contacts
    meta = scene[0].meta
    config = FitConfig(loss_horizon=2, hidden=8)
    path = save_checkpoint(tmp_path / "model.pt", build_model(config, meta), config, meta)
    payload = torch.load(path, weights_only=True)
    del payload["config"]["loss_contacts"]
    torch.save(payload, path)
    assert load_checkpoint(path)[1].loss_contacts == "frozen"
    # a split record's config pickled before the field
    old = FitConfig(loss_horizon=2)
    object.__delattr__(old, "loss_contacts")
    assert "loss_contacts" not in vars(old)
    assert pickle.loads(pickle.dumps(old)).loss_contacts == "frozen"
    assert dataclasses.asdict(pickle.loads(pickle.dumps(old)))["loss_contacts"] == "frozen"
