"""The contact floor of the hands' cost: how low the fingertip sites can go (read from the
robot's geometry), and the cost's contact and grasp terms drawing the tips no lower."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from torchcontact.environments import environment
from torchcontact.environments.costs import ManipulationCost, raised
from torchcontact.sim.hands import HandPlant

F64 = torch.float64


def test_tip_clearance_is_the_depth_of_the_sites_inside_their_tip_geoms():
    """TriFinger: each site is the centre of a 1 cm sphere. Allegro: the sites lie inside
    capsules of radius 12 mm, the thumb's 11 mm from its end-cap centre (the MJCF)."""
    assert HandPlant("trifinger", "cube").tip_clearance == pytest.approx(0.01)
    assert HandPlant("allegro", "cube").tip_clearance == pytest.approx(0.001)


def test_raised_lifts_only_what_lies_below_the_floor():
    p = torch.tensor([[0.1, -0.2, 0.005], [0.3, 0.4, 0.02]], dtype=F64)
    expected = torch.tensor([[0.1, -0.2, 0.01], [0.3, 0.4, 0.02]], dtype=F64)
    torch.testing.assert_close(raised(p, 0.01), expected)
    assert raised(p.expand(5, 2, 3), 0.01).shape == (5, 2, 3)


def _rollout(height: float, tip_height: float, T: int = 2):
    positions = torch.tensor([0.0, 0.0, height], dtype=F64).expand(T + 1, 3)
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=F64).expand(T + 1, 4)
    ring = torch.tensor([[0.03, 0.0], [-0.015, 0.026], [-0.015, -0.026]], dtype=F64)
    tips = torch.cat([ring, torch.full((3, 1), tip_height, dtype=F64)], -1)
    tips = tips.expand(T + 1, 3, 3).clone().requires_grad_(True)
    controls = torch.zeros(T, 9, dtype=F64)
    target = (torch.tensor([0.0, 0.0, height], dtype=F64), quats[0])
    return positions, quats, tips, controls, target


def test_the_floor_stops_the_cost_pulling_tips_below_it():
    """A 1.2 cm plate (centre 6 mm up) ringed by tips at the floor (1 cm): the paper's cost
    pulls them down into the support; with the floor it leaves their height alone."""
    cost = ManipulationCost(contact=0.5, grasp=0.05, control=10.0)
    floored = dataclasses.replace(cost, contact_floor=0.01)
    for c, pulled_down in ((cost, True), (floored, False)):
        positions, quats, tips, controls, target = _rollout(0.006, 0.01)
        (grad,) = torch.autograd.grad(c(positions, quats, tips, controls, *target), tips)
        vertical = grad[:-1, :, 2]
        assert bool((vertical > 1e-6).all()) == pulled_down  # descent moves them down
        if not pulled_down:
            torch.testing.assert_close(vertical, torch.zeros_like(vertical))


def test_the_floor_changes_nothing_for_an_object_centred_above_it():
    cost = ManipulationCost(contact=0.5, grasp=0.05, control=10.0)
    floored = dataclasses.replace(cost, contact_floor=0.01)
    positions, quats, tips, controls, target = _rollout(0.03, 0.02)
    torch.testing.assert_close(
        floored(positions, quats, tips, controls, *target),
        cost(positions, quats, tips, controls, *target),
    )


def test_the_trifinger_cost_floors_its_tips_at_the_height_of_a_resting_tip():
    env = environment("trifinger")
    plant = HandPlant("trifinger", "random-31")
    assert env.cost(plant).contact_floor == pytest.approx(plant.support_height + 0.01)
    assert ManipulationCost().contact_floor is None  # the paper's cost is unchanged
