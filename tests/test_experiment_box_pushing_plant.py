"""The box-pushing plant: a kinematically driven bar and MuJoCo cubes."""

import numpy as np
import pytest

from torchcontact.experiments.box_pushing import BoxPushingConfig
from torchcontact.experiments.box_pushing_plant import BoxPushingPlant


def test_the_bar_moves_as_commanded_and_pushes_the_first_cube():
    plant = BoxPushingPlant(BoxPushingConfig(cubes=2))
    plant.reset(plant.initial_state)
    start = plant.state()
    for _ in range(30):
        q = plant.step([-0.001])
    assert q[-1] == pytest.approx(start[-1] - 0.03, abs=1e-12)
    # the bar starts 1 cm behind the first cube: the cube has moved by about 2 cm, not more
    assert -0.025 < q[0] - start[0] < -0.012
    assert abs(q[2] - start[2]) < 1e-3  # still on the ground
    assert int(plant.contacts().active.sum()) >= 4


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda p: p.step([np.nan]), "u must be"),
        (lambda p: p.step([0.1, 0.2]), "u must be"),
        (lambda p: p.reset(np.zeros(3)), "initial must be"),
        (lambda p: BoxPushingPlant(substeps=0), "substeps"),
    ],
)
def test_bad_input_is_refused_by_name(call, message):
    plant = BoxPushingPlant(BoxPushingConfig(cubes=1))
    with pytest.raises(ValueError, match=message):
        call(plant)
