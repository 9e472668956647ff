"""The MPC's tilt cost: blind to turns about the target's z axis, 1 − cos of the lean."""

import dataclasses
import math

import torch

from torchcontact.environments.costs import (
    ManipulationCost,
    axis_contact_cost,
    contact_cost,
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


def test_axis_contact_cost_draws_each_tip_to_its_nearest_point_of_the_axis():
    p = torch.tensor([0.1, 0.0, 0.05], dtype=DT)
    turned = _quat(yaw=math.pi / 2)  # the body's x axis along the world's y
    half = torch.tensor([0.04, 0.0, 0.0], dtype=DT)
    tips = p + torch.tensor(
        [[0.01, 0.02, 0.0], [0.0, 0.07, 0.0], [0.0, -0.01, 0.03]], dtype=DT
    )  # beside the axis, past its end, above it
    expected = 0.01**2 + 0.03**2 + 0.03**2
    torch.testing.assert_close(
        axis_contact_cost(p, turned, tips, half), torch.tensor(expected, dtype=DT)
    )
    # a zero axis is the paper's pull to the centre
    torch.testing.assert_close(
        axis_contact_cost(p, turned, tips, torch.zeros(3, dtype=DT)), contact_cost(p, tips)
    )


def test_axis_contact_cost_batches_and_has_exact_gradients():
    torch.manual_seed(0)
    p = torch.randn(2, 5, 3, dtype=DT, requires_grad=True)
    quat = torch.nn.functional.normalize(torch.randn(2, 5, 4, dtype=DT), dim=-1).requires_grad_()
    tips = torch.randn(2, 5, 3, 3, dtype=DT, requires_grad=True)
    half = torch.tensor([0.0, 0.3, 0.0], dtype=DT)
    assert axis_contact_cost(p, quat, tips, half).shape == (2, 5)
    assert torch.autograd.gradcheck(lambda *a: axis_contact_cost(*a, half), (p, quat, tips))


def test_the_contact_axis_replaces_only_the_contact_term():
    paper = TRIFINGER_ENV.model.cost
    cost = dataclasses.replace(paper, contact_axis=(0.05, 0.0, 0.0))
    T = 3
    positions = torch.zeros(T + 1, 3, dtype=DT)
    quats = _quat().expand(T + 1, 4).clone()
    tips = torch.tensor([[0.06, 0.0, 0.0], [0.0, 0.02, 0.0], [-0.03, 0.0, 0.01]], dtype=DT)
    tips = tips.expand(T + 1, 3, 3)
    args = (positions, quats, tips, torch.zeros(T, 9, dtype=DT), positions[0], _quat())
    # per planned step the first tip's pull falls from 0.06² to 0.01², the third's from
    # 0.03² + 0.01² to 0.01²: the grasp and the other terms are the paper's
    saved = (0.06**2 - 0.01**2) + 0.03**2
    torch.testing.assert_close(
        paper(*args) - cost(*args), torch.tensor(paper.contact * T * saved, dtype=DT)
    )
