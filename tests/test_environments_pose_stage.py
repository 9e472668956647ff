"""The pose stage of the hands' cost: the pose terms charged on every planned state, not the
last alone, and the options that set it."""

from __future__ import annotations

import math

import pytest
import torch

from mpc.trials import LEGACY_DEFAULTS, build_trial, stored_config, trial_configs
from torchcontact.cli import main
from torchcontact.environments import environment
from torchcontact.environments.costs import ManipulationCost, PushingCost
from torchcontact.sim.hands import HandEnv

F64 = torch.float64
T, TIPS, NU = 3, 3, 9


def rollout(batch=(), generator=None):
    """A random rollout ``(positions, quats, tips, controls)`` of T steps, leading ``batch``."""
    g = torch.Generator().manual_seed(0) if generator is None else generator
    positions = 0.05 * torch.randn(*batch, T + 1, 3, generator=g, dtype=F64)
    quats = torch.nn.functional.normalize(
        torch.randn(*batch, T + 1, 4, generator=g, dtype=F64), dim=-1
    )
    tips = 0.05 * torch.randn(*batch, T + 1, TIPS, 3, generator=g, dtype=F64)
    controls = 0.01 * torch.randn(*batch, T, NU, generator=g, dtype=F64)
    return positions, quats, tips, controls


TARGET = (
    torch.tensor([0.01, -0.02, 0.03], dtype=F64),
    torch.tensor([0.0, 0.0, 0.6, 0.8], dtype=F64),
)


def pose_terms(cost: ManipulationCost, positions, quats, target_p, target_q):
    """The pose terms of V at each state ``(..., T+1)``, by hand."""
    position = (positions - target_p).square().sum(-1)
    orientation = 1 - (quats * target_q).sum(-1).square()
    return cost.position * position + cost.orientation * orientation


def test_the_stage_charges_the_pose_on_every_planned_state_before_the_last():
    base = ManipulationCost(contact=0.5, grasp=0.05, control=10.0)
    staged = ManipulationCost(contact=0.5, grasp=0.05, control=10.0, stage=0.7)
    for batch in ((), (2,), (2, 3)):
        positions, quats, tips, controls = rollout(batch)
        plain = base(positions, quats, tips, controls, *TARGET)
        extra = pose_terms(base, positions, quats, *TARGET)[..., 1:-1].sum(-1)
        got = staged(positions, quats, tips, controls, *TARGET)
        assert got.shape == batch
        torch.testing.assert_close(got, plain + 0.7 * base.final * extra)
    # q₀ is where the plan starts, which no control changes: it is never charged
    positions, quats, tips, controls = rollout()
    moved = positions.clone()
    moved[0] += 1.0
    torch.testing.assert_close(
        staged(moved, quats, tips, controls, *TARGET) - base(moved, quats, tips, controls, *TARGET),
        staged(positions, quats, tips, controls, *TARGET)
        - base(positions, quats, tips, controls, *TARGET),
    )


def test_the_radius_stages_only_plans_that_start_near_the_target():
    base = ManipulationCost(contact=0.5, grasp=0.05, control=10.0)
    gated = ManipulationCost(contact=0.5, grasp=0.05, control=10.0, stage=1.0, stage_radius=0.04)
    positions, quats, tips, controls = rollout((2,))
    positions[0, 0] = TARGET[0] + torch.tensor([0.03, 0.0, 0.0], dtype=F64)  # 3 cm: staged
    positions[1, 0] = TARGET[0] + torch.tensor([0.0, 0.05, 0.0], dtype=F64)  # 5 cm: not
    plain = base(positions, quats, tips, controls, *TARGET)
    got = gated(positions, quats, tips, controls, *TARGET)
    extra = pose_terms(base, positions, quats, *TARGET)[..., 1:-1].sum(-1)
    torch.testing.assert_close(got[0], plain[0] + base.final * extra[0])
    torch.testing.assert_close(got[1], plain[1])


def test_the_staged_cost_has_exact_gradients_and_stays_finite_in_float32():
    staged = ManipulationCost(contact=0.5, grasp=0.05, control=10.0, stage=1.0)
    positions, quats, tips, controls = rollout((2,))
    positions.requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda p: staged(p, quats, tips, controls, *TARGET), (positions,)
    )
    p32 = positions.detach().float().requires_grad_(True)
    value = staged(p32, quats.float(), tips.float(), controls.float(), *(t.float() for t in TARGET))
    value.sum().backward()
    assert value.dtype == torch.float32 and torch.isfinite(p32.grad).all()


def test_the_hands_set_the_stage_and_refuse_a_meaningless_one():
    env, cube = environment("trifinger"), HandEnv("trifinger", "cube")
    assert env.cost(cube).stage == env.pose_stage
    assert env.cost(cube, pose_stage=0.5).stage == 0.5
    assert env.cost(cube, pose_stage=0.0).stage == 0.0
    assert env.cost(cube).stage_radius == env.pose_stage_radius
    assert env.cost(cube, pose_stage=1.0, pose_stage_radius=math.inf).stage_radius == math.inf
    for value in (0.0, -0.01, math.nan):
        with pytest.raises(ValueError, match="pose_stage_radius must be a distance > 0"):
            env.cost(cube, pose_stage_radius=value)
    with pytest.raises(ValueError, match="pose_stage_radius: it confines the pose stage"):
        env.cost(cube, pose_stage=0.0, pose_stage_radius=0.04)
    # a value of the cost: one compiled graph per setting, not per object
    bottle = HandEnv("trifinger", "water_bottle")
    assert "stage=0.5" in repr(env.cost(bottle, pose_stage=0.5))
    for value in (-1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="pose_stage must be a non-negative number"):
            env.cost(cube, pose_stage=value)
    fingertips = environment("fingertips")
    for asked in ({"pose_stage": 1.0}, {"pose_stage_radius": 0.04}):
        with pytest.raises(ValueError, match="pose_stage: the fingertips keep the paper's"):
            fingertips.cost(fingertips.make_plant("cube"), **asked)
    assert fingertips.cost(fingertips.make_plant("cube"), pose_stage=0.0).stage == 0.0
    assert not isinstance(PushingCost(), ManipulationCost)  # no pose terms to stage


def test_a_trial_plans_with_its_stage():
    default = trial_configs("trifinger", [("in-hand", "cube")], [0])[0]
    assert default.pose_stage == environment("trifinger").pose_stage
    assert default.pose_stage_radius == environment("trifinger").pose_stage_radius
    old = {k: v for k, v in vars(default).items() if not k.startswith("pose_stage")}
    assert stored_config(old)["pose_stage"] == LEGACY_DEFAULTS["pose_stage"] == 0.0
    assert stored_config(old)["pose_stage_radius"] == math.inf
    # a record writes an infinite radius as null, and still matches its configuration
    unbounded = trial_configs(
        "trifinger", [("in-hand", "cube")], [0], pose_stage=1.0, pose_stage_radius=math.inf
    )[0]
    written = {**vars(unbounded), "pose_stage_radius": None}
    assert unbounded.matches(written)
    assert build_trial(unbounded)[2].cost.stage_radius == math.inf
    staged = trial_configs("trifinger", [("in-hand", "cube")], [0], pose_stage=0.5)[0]
    assert build_trial(staged)[2].cost.stage == 0.5
    pushing = trial_configs("trifinger", [("in-hand", "cube")], [0], cost="pushing")[0]
    assert pushing.pose_stage == 0.0
    assert trial_configs("fingertips", [("rotation", "cube")], [0])[0].pose_stage == 0.0


def test_the_cli_refuses_a_meaningless_stage(capsys):
    for argv, message in (
        (["trifinger", "--pose-stage", "-1"], "--pose-stage must be a weight >= 0"),
        (["trifinger", "--pose-stage", "1", "--cost", "pushing"], "--pose-stage is a term of"),
        (["trifinger", "--pose-stage-radius", "0"], "--pose-stage-radius must be a distance"),
        (["trifinger", "--pose-stage", "0", "--pose-stage-radius", "0.04"], "set pose_stage"),
        (["fingertips", "--pose-stage", "1"], "pose_stage: the fingertips keep the paper's"),
    ):
        with pytest.raises(SystemExit):
            main(["run", *argv, "--trials", "1"])
        assert message in capsys.readouterr().err
