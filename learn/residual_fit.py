"""Fit an :class:`~torchcontact.residual.ObjectResidual` on what a fitted model leaves.

The second stage of a fit: with K(q), D(q) and the system's factors fitted and fixed, the
residual learns the objects' velocity that takes each recorded state to MuJoCo's next one,
less the model's (the body-frame velocity of :func:`~torchcontact.integrate.difference`), as a
mean squared error in the residual's output units (1 cm and 0.2 rad a step). Adam with a
little weight decay, early stopping on the validation windows, the best state kept.

The settings were measured on the Allegro's 17 built-in objects (five object splits; see
docs/experiments.md, "Learning K(q) and D(q)"), and are module constants rather than options.
"""

from __future__ import annotations

import dataclasses

import torch

from torchcontact.checkpoint import FitConfig
from torchcontact.integrate import JointLayout, difference, object_indices
from torchcontact.learn.fit import (
    FitResult,
    StepData,
    adam_with_early_stopping,
    carried,
    predict,
    step_terms,
)
from torchcontact.model import ComplementarityFree
from torchcontact.residual import ObjectResidual
from torchcontact.validation import validate_args

LR = 1e-3
WEIGHT_DECAY = 1e-4
BATCH_SIZE = 256


def residual_examples(
    model: ComplementarityFree, data: StepData, residual: ObjectResidual
) -> tuple[torch.Tensor, torch.Tensor]:
    """Raw features ``(N, F)`` and targets ``(N, 6·n_obj)`` [output units] of ``data``'s first
    steps under ``model`` (which must hold no residual)."""
    first = data.first_steps()
    n_obj = first.pose.shape[-2]
    layout = JointLayout(["free"] * n_obj)
    with torch.no_grad(), validate_args(False):
        predicted = predict(model, first)[0][:, 0]
        Q, b = step_terms(model, first)
        _, b = carried(model, Q[:, 0], b[:, 0], first.displacement, first.object_rows)
        start = first.pose.flatten(-2)
        moved = difference(start, predicted.flatten(-2), first.h, layout)
        wanted = difference(start, first.target[:, 0].flatten(-2), first.h, layout)
        v = b.new_zeros(len(first), b.shape[-1])
        v[:, first.object_rows] = moved
        features = residual.features(first.q, b, v, first.h)
        units = residual.units.to(wanted)
        return features, (wanted - moved) * first.h / units


def fit_residual(
    model: ComplementarityFree,
    train: StepData,
    val: StepData,
    joints: list[str],
    config: FitConfig,
    progress: bool = True,
) -> FitResult:
    """Fit a residual of ``config.residual`` hidden units to what ``model`` leaves on
    ``train``'s windows' first steps, stopping after ``config.epochs`` or ``config.patience``
    epochs without a better loss on ``val``; sets ``model.residual`` (the best validation
    state) and returns the :class:`~torchcontact.learn.fit.FitResult` of this stage.

    Args:
        model: a fitted model without a residual, in ``train``'s dtype and on its device.
        joints: the dataset's joint kinds (``meta["joints"]``), which place the objects in q.
    """
    if config.residual < 1:
        raise ValueError(f"config.residual must be a positive integer, got {config.residual}")
    if model.residual is not None:
        raise ValueError("model already holds a residual: fit it on the model without one")
    if len(train) == 0 or len(val) == 0:
        raise ValueError(f"train and val must be non-empty, got {len(train)} and {len(val)}")
    torch.manual_seed(config.seed)
    nq, nv = train.q.shape[-1], train.metric.shape[-1]
    residual = ObjectResidual(*object_indices(joints), nq, nv, hidden=config.residual)
    residual = residual.to(device=train.q.device, dtype=train.q.dtype)
    x_train, y_train = residual_examples(model, train, residual)
    x_val, y_val = residual_examples(model, val, residual)
    residual.standardize(x_train)
    optimizer = torch.optim.Adam(residual.net.parameters(), lr=LR, weight_decay=WEIGHT_DECAY)

    def batch_loss(rows: torch.Tensor) -> torch.Tensor:
        return (residual.correction(x_train[rows]) - y_train[rows]).square().mean()

    def val_loss() -> float:
        with torch.no_grad():
            return float((residual.correction(x_val) - y_val).square().mean())

    result = adam_with_early_stopping(
        residual,
        optimizer,
        len(x_train),
        batch_loss,
        val_loss,
        config,
        progress,
        BATCH_SIZE,
        "residual",
    )
    model.residual = residual
    return dataclasses.replace(result, model=model)
