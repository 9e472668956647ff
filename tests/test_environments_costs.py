"""The MPC's tilt cost: blind to turns about the target's z axis, 1 − cos of the lean."""

import dataclasses
import math

import torch

from torchcontact.environments.costs import (
    ManipulationCost,
    tilt_cost,
    up_axis,
)
from torchcontact.environments.hands import TRIFINGER_ENV
from torchcontact.environments.tasks import quat_from_yaw_pitch_roll

DT = torch.float64


def _quat(yaw=0.0, pitch=0.0, roll=0.0):
    return torch.as_tensor(quat_from_yaw_pitch_roll(yaw, pitch, roll), dtype=DT)


def test_up_axis_is_the_third_column_of_the_rotation():
    from pytorch_kinematics.transforms import quaternion_to_matrix

    quats = torch.nn.functional.normalize(torch.randn(5, 4, dtype=DT), dim=-1)
    torch.testing.assert_close(up_axis(quats), quaternion_to_matrix(quats)[..., :, 2])


def test_tilt_cost_ignores_yaw_and_grows_as_one_minus_cos_of_the_lean():
    upright = _quat()
    assert abs(float(tilt_cost(_quat(yaw=2.5), upright))) < 1e-12
    for lean in (0.1, 0.7, math.pi / 2):
        leaning = _quat(yaw=1.0, pitch=lean)
        torch.testing.assert_close(
            tilt_cost(leaning, upright), torch.tensor(1 - math.cos(lean), dtype=DT)
        )
    # relative to a target that itself leans: its own pose costs nothing
    target = _quat(pitch=0.4, roll=-0.3)
    assert abs(float(tilt_cost(target, target))) < 1e-12


def test_manipulation_cost_charges_the_tilt_of_planned_states_only():
    without = TRIFINGER_ENV.model.cost
    cost = dataclasses.replace(without, tilt=100.0)
    T = 4
    quats = _quat().expand(T + 1, 4).clone()
    quats[0] = _quat(pitch=1.0)  # the current state: the plan cannot change it
    quats[2] = _quat(yaw=0.3, pitch=0.2)
    positions = torch.zeros(T + 1, 3, dtype=DT)
    tips = torch.full((T + 1, 3, 3), 0.05, dtype=DT)
    args = (positions, quats, tips, torch.zeros(T, 9, dtype=DT), positions[0], _quat())
    extra = cost(*args) - without(*args)
    torch.testing.assert_close(extra, torch.tensor(cost.tilt * (1 - math.cos(0.2)), dtype=DT))


def test_tilt_is_off_by_default():
    assert ManipulationCost().tilt == 0.0
