"""The support term of the hands' cost: the palm's footprint read from the model, the cost of
a planned centre leaving it, and the options that switch it."""

from __future__ import annotations

import pytest
import torch

from torchcontact.cli import main
from torchcontact.environments import environment
from torchcontact.environments.costs import ManipulationCost, support_cost
from torchcontact.sim.hands import HandEnv

F64 = torch.float64
REGION = (-0.09, -0.05, 0.0, 0.05)


def test_support_cost_is_zero_inside_and_the_squared_distance_outside():
    p = torch.tensor(
        [[-0.05, 0.0, 0.1], [0.02, 0.0, 0.1], [-0.1, 0.08, 0.0], [0.0, -0.05, 0.3]], dtype=F64
    )
    expected = torch.tensor([0.0, 0.02**2, 0.01**2 + 0.03**2, 0.0], dtype=F64)
    torch.testing.assert_close(support_cost(p, REGION), expected)
    batched = support_cost(p.expand(2, 3, 4, 3), REGION)
    assert batched.shape == (2, 3, 4)


def test_the_allegro_palm_footprint_is_its_collision_box_in_the_world():
    """The palm box spans x ∈ [−0.095, 0] (fingers towards +x) and y ∈ ±0.0565 (the MJCF)."""
    plant = HandEnv("allegro", "cube")
    torch.testing.assert_close(
        torch.tensor(plant.support_footprint), torch.tensor((-0.095, -0.0565, 0.0, 0.0565))
    )
    assert HandEnv("trifinger", "cube").support_footprint is None  # resting on the ground


def test_the_support_term_charges_a_plan_that_leaves_the_palm():
    env = environment("allegro")
    plant = HandEnv("allegro", "cube")
    with_term, without = env.cost(plant, support=True), env.cost(plant, support=False)
    assert without.support is None
    margin = env.model.support_margin or 0.0
    x_min, y_min, x_max, y_max = plant.support_footprint
    assert with_term.support == pytest.approx(
        (x_min + margin, y_min + margin, x_max - margin, y_max - margin)
    )
    T, tips = 3, torch.zeros(4, 4, 3, dtype=F64)
    target = (torch.tensor([-0.03, 0.0, 0.05], dtype=F64), torch.tensor([1.0, 0, 0, 0], dtype=F64))
    quats = torch.tensor([1.0, 0, 0, 0], dtype=F64).expand(T + 1, 4)
    controls = torch.zeros(T, 16, dtype=F64)
    on_palm = torch.tensor([-0.03, 0.0, 0.05], dtype=F64).expand(T + 1, 3)
    off_palm = on_palm + torch.tensor([-0.1, 0.0, 0.0], dtype=F64) * torch.arange(T + 1)[:, None]
    for positions, charged in ((on_palm, False), (off_palm, True)):
        extra = with_term(positions, quats, tips, controls, *target) - without(
            positions, quats, tips, controls, *target
        )
        assert (float(extra) > 1.0) == charged and float(extra) >= 0.0


def test_support_is_refused_where_the_object_rests_on_the_ground():
    for options in ({"support": True}, {"margin": 0.01}):
        with pytest.raises(ValueError, match="support: trifinger's object rests on the ground"):
            environment("trifinger").cost(HandEnv("trifinger", "cube"), **options)
    with pytest.raises(ValueError, match="support: the fingertips' objects rest"):
        fingertips = environment("fingertips")
        fingertips.cost(fingertips.make_plant("cube"), support=True)


def test_a_manipulation_cost_without_support_is_unchanged_by_the_field():
    cost = ManipulationCost()
    assert cost.support is None


def test_the_cli_refuses_support_with_another_cost(capsys):
    with pytest.raises(SystemExit):
        main(["run", "allegro", "--support", "on", "--cost", "pushing", "--trials", "1"])
    assert "--support is a term of the environment's cost" in capsys.readouterr().err


@pytest.mark.parametrize(
    "env, argv, message",
    [
        ("allegro", ["--support-margin", "-0.01"], "--support-margin must be a distance >= 0"),
        ("allegro", ["--support", "off", "--support-margin", "0.01"], "drop --support off"),
        ("allegro", ["--support-margin", "0.05"], "margin must be in [0, half the support's"),
        ("trifinger", ["--support", "on"], "support: trifinger's object rests on the ground"),
    ],
)
def test_the_cli_refuses_a_meaningless_support_option(env, argv, message, capsys):
    with pytest.raises(SystemExit):
        main(["run", env, "--trials", "1", *argv])
    assert message in capsys.readouterr().err


def test_a_margin_wider_than_the_palm_is_refused_by_name():
    env, plant = environment("allegro"), HandEnv("allegro", "cube")
    with pytest.raises(ValueError, match="margin must be in"):
        env.cost(plant, margin=0.05)  # the palm is 9.5 cm long: 5 cm off each end overlap
    assert env.cost(plant, margin=0.05 - 0.03).support is not None
