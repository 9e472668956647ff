"""The object residual: zero until fitted, shapes and dtypes, a known correction recovered,
checkpoints, and the MPC's refusal."""

import dataclasses
import io

import pytest
import torch

from torchcontact import ComplementarityFree
from torchcontact.checkpoint import FitConfig, build_model, load_checkpoint, save_checkpoint
from torchcontact.integrate import JointLayout, integrate, object_indices
from torchcontact.learn.data import collect, load
from torchcontact.learn.fit import StepData, system_terms
from torchcontact.learn.residual_fit import fit_residual, residual_examples
from torchcontact.residual import UNITS, ObjectResidual

DRIFT = 0.5
"""The synthetic plant's extra object motion: up to DRIFT cm a step along x, in proportion to
the first command (as a fraction of its largest)."""


@pytest.fixture(scope="module")
def transitions(tmp_path_factory):
    directory = tmp_path_factory.mktemp("residual")
    collect(directory, "trifinger", trajectories=12, steps=20, progress=False)
    return load(directory)


def _residual(meta, hidden=8):
    return ObjectResidual(*object_indices(meta["joints"]), meta["nq"], meta["nv"], hidden)


def _step(model, transitions):
    meta = transitions.meta
    Q, b = system_terms(meta, transitions.u)
    contacts = transitions.contacts.to(torch.float64)
    return model(Q, b, contacts, meta["h"], q=transitions.q), (Q, b, contacts)


def test_an_unfitted_residual_changes_nothing(transitions):
    meta = transitions.meta
    model = build_model(FitConfig(stiffness="constant", damping="paper"), meta).double()
    with_residual = dataclasses.replace(FitConfig(stiffness="constant", damping="paper"))
    with_residual = build_model(dataclasses.replace(with_residual, residual=8), meta).double()
    assert isinstance(with_residual.residual, ObjectResidual)
    torch.testing.assert_close(_step(with_residual, transitions)[0], _step(model, transitions)[0])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_any_batch_shape_and_dtype_with_finite_gradients(transitions, dtype):
    meta = transitions.meta
    residual = _residual(meta).to(dtype)
    with torch.no_grad():
        for parameter in residual.parameters():
            parameter.add_(torch.randn_like(parameter))
    q = transitions.q[:6].to(dtype).reshape(2, 3, -1)
    b = torch.randn(2, 3, meta["nv"], dtype=dtype)
    v = torch.randn(2, 3, meta["nv"], dtype=dtype, requires_grad=True)
    out = residual(q, b, v, meta["h"])
    assert out.shape == (2, 3, meta["nv"]) and out.dtype == dtype
    robot = torch.ones(meta["nv"], dtype=torch.bool)
    robot[residual.object_rows] = False
    assert torch.equal(out[..., robot], v[..., robot])  # only the objects' rows move
    out.square().sum().backward()
    assert torch.isfinite(v.grad).all()
    assert all(torch.isfinite(p.grad).all() for p in residual.parameters())


def test_gradcheck_in_float64(transitions):
    meta = transitions.meta
    residual = _residual(meta, hidden=4).double()
    with torch.no_grad():
        residual.net[-1].weight.normal_()
    q = transitions.q[:2].double()
    b = torch.randn(2, meta["nv"], dtype=torch.float64, requires_grad=True)
    v = torch.randn(2, meta["nv"], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda b, v: residual(q, b, v, 0.1), (b, v))


def test_a_known_correction_is_recovered(transitions):
    """Data made by the model plus a known drift of the object: the residual fitted on them
    leaves a small fraction of the drift's error, and the fitted model predicts the data."""
    meta = transitions.meta
    config = FitConfig(stiffness="constant", damping="paper", residual=16, epochs=300, patience=300)
    model = build_model(dataclasses.replace(config, residual=0), meta).double()
    v, _ = _step(model, transitions)
    drift = torch.zeros_like(v)
    command = transitions.u[:, 0] / transitions.u[:, 0].abs().max()
    drift[:, 0] = DRIFT * UNITS[0] * command / meta["h"]
    q_next = integrate(transitions.q, v.detach() + drift, meta["h"], JointLayout(meta["joints"]))
    synthetic = dataclasses.replace(transitions, q_next=q_next)
    train, val, _ = synthetic.split(seed=0)
    data = [StepData.from_transitions(part, dtype=torch.float64) for part in (train, val)]
    before = residual_examples(model, data[1], _residual(meta).double())[1].square().mean()
    result = fit_residual(model, *data, meta["joints"], config, progress=False)
    assert result.val_loss < 0.1 * float(before)
    assert model.residual is not None and result.best_epoch > 0
    fitted, _ = _step(model, synthetic)
    expected = (v + drift).detach()[:, model.residual.object_rows]
    error = (fitted.detach()[:, model.residual.object_rows] - expected).abs().mean(0)
    assert error[0] < 0.2 * drift[:, 0].abs().mean()


def test_checkpoint_round_trip_and_the_frozen_step_refuses_it(transitions, tmp_path):
    meta = transitions.meta
    config = FitConfig(residual=8)
    model = build_model(config, meta)
    with torch.no_grad():
        for parameter in model.residual.parameters():
            parameter.add_(0.1 * torch.randn_like(parameter))
        model.residual.feature_std.fill_(2.0)
    path = save_checkpoint(tmp_path / "model.pt", model, config, meta)
    loaded, loaded_config, _ = load_checkpoint(path)
    assert loaded_config.residual == 8
    torch.testing.assert_close(
        _step(loaded.double(), transitions)[0], _step(model.double(), transitions)[0]
    )
    _, (Q, b, contacts) = _step(model, transitions)
    with pytest.raises(ValueError, match="object residual"):
        model.freeze(contacts[0], meta["h"], transitions.q[0])
    with pytest.raises(ValueError, match="q must be given"):
        model(Q, b, contacts, meta["h"])


def test_bad_arguments_are_named(transitions):
    meta = transitions.meta
    q_index, v_index = object_indices(meta["joints"])
    with pytest.raises(ValueError, match="object_q must have shape"):
        ObjectResidual(q_index[:, :3], v_index, meta["nq"], meta["nv"])
    with pytest.raises(ValueError, match="hidden must be a positive integer"):
        ObjectResidual(q_index, v_index, meta["nq"], meta["nv"], hidden=0)
    with pytest.raises(ValueError, match="residual must be a non-negative integer"):
        FitConfig(residual=-1)
    with pytest.raises(ValueError, match="features must have shape"):
        _residual(meta).standardize(torch.zeros(3, 2))


def test_a_model_pickled_before_residuals_loads_without_one():
    model = ComplementarityFree(1.0)
    del model.__dict__["residual"]  # as a model pickled by an older release holds it
    buffer = io.BytesIO()
    torch.save(model, buffer)
    buffer.seek(0)
    assert torch.load(buffer, weights_only=False).residual is None
