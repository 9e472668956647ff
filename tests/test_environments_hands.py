"""The hand environments' MPC: the paper's settings, a plan inside the box, the tilt cost, and
`run trifinger|allegro` smoke runs."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch
import trimesh

from torchcontact.cli import main
from torchcontact.environments import ENVIRONMENTS, environment
from torchcontact.environments.hands import (
    ALLEGRO_ENV,
    TRIFINGER_ENV,
    tips_before_sliding,
)
from torchcontact.environments.presets import MPCSettings
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.report import SUMMARY_KEYS
from torchcontact.results import read_json
from torchcontact.shapes import make_object, object_names
from torchcontact.sim.hands import HANDS, Hand

FAST = ["--trials", "2", "--max-steps", "4", "--max-iter", "3", "--no-compile", "--no-progress"]
EAGER = MPCSettings(compile=False)


def test_the_hands_are_registered_environments():
    assert all(ENVIRONMENTS[name].hand is hand for name, hand in HANDS.items())
    assert environment("trifinger") is TRIFINGER_ENV and environment("allegro") is ALLEGRO_ENV


@pytest.mark.parametrize("hand", sorted(HANDS))
def test_a_plan_stays_in_its_box_and_lowers_the_cost(hand):
    env = environment(hand)
    plant = env.make_plant("cube")
    mpc = ContactImplicitMPC.from_env(env, plant, settings=MPCSettings(max_iter=10, compile=False))
    q = torch.as_tensor(plant.state())
    target = plant.resting_pose(plant.support_centre, [0.0, 0.0, 0.0, 1.0])
    tp, tq = torch.as_tensor(target[:3]), torch.as_tensor(target[3:])
    contacts = plant.contacts(mpc.dtype)
    plan = mpc.plan(q, contacts, tp, tq)
    bound = env.control_bound(plant)
    assert bound == env.model.control_bound
    assert plan.controls.shape == (4, HANDS[hand].n_joints)
    assert float(plan.controls.abs().max()) <= bound + 1e-12
    with torch.no_grad():
        args = (q, mpc.freeze(q, contacts), tp, tq)
        idle = mpc.objective(torch.zeros_like(plan.controls), *args)
        planned = mpc.objective(plan.controls, *args)
    assert float(planned) < float(idle)


def leaned(T: int) -> torch.Tensor:
    """``(T + 1, 4)`` quaternions leaned 0.3 rad about x."""
    half = torch.tensor(0.15, dtype=torch.float64)
    return torch.stack([half.cos(), half.sin(), half * 0, half * 0]).expand(T + 1, 4)


def test_only_objects_that_tip_before_they_slide_get_the_tilt_cost():
    tipping = {name for name in object_names() if tips_before_sliding(make_object(name))}
    # the stick, a rod like the paper's, rolls over its narrow flat when pushed sideways
    assert tipping == {"binoculars", "camera", "rubber_duck", "stick", "water_bottle"}
    assert TRIFINGER_ENV.model.cost.tilt == 0  # the paper's cost
    weight = TRIFINGER_ENV.model.tilt
    # every object carries the term (one compiled graph), switched on where it tips
    cube = TRIFINGER_ENV.cost(TRIFINGER_ENV.make_plant("cube"))
    assert cube.tilt == weight and float(cube.tilt_applies) == 0
    camera = TRIFINGER_ENV.cost(TRIFINGER_ENV.make_plant("camera"))
    assert weight > 0 and camera.tilt == weight and float(camera.tilt_applies) == 1
    T = 2
    f64 = {"dtype": torch.float64}
    upright = torch.tensor([1.0, 0.0, 0.0, 0.0], **f64)
    args = (torch.zeros(T + 1, 3, **f64), leaned(T), torch.zeros(T + 1, 3, 3, **f64),
            torch.zeros(T, 9, **f64), torch.zeros(3, **f64), upright)  # fmt: skip
    cube, camera = (dataclasses.replace(cost, hold=None) for cost in (cube, camera))  # aim: target
    untilted = dataclasses.replace(cube, tilt=0.0)
    assert torch.equal(cube(*args), untilted(*args))  # switched off: the cost without it
    assert bool(camera(*args) > dataclasses.replace(camera, tilt=0.0)(*args))
    # the MPC takes the cost of its plant's object; the Allegro has no tilt weight
    duck = TRIFINGER_ENV.make_plant("rubber_duck")
    planned = ContactImplicitMPC.from_env(TRIFINGER_ENV, duck, settings=EAGER).cost
    assert planned.tilt == weight and float(planned.tilt_applies) == 1
    duck = ALLEGRO_ENV.make_plant("rubber_duck")
    assert ALLEGRO_ENV.model.tilt == 0
    assert ContactImplicitMPC.from_env(ALLEGRO_ENV, duck, settings=EAGER).cost.tilt == 0


def test_an_mpc_takes_its_object_from_the_plant_instead_of_building_it_again(tmp_path, monkeypatch):
    path = tmp_path / "tall.stl"
    trimesh.creation.cylinder(radius=0.01, height=0.06).export(path)  # tips before it slides
    plant = TRIFINGER_ENV.make_plant(str(path))
    builds = []
    build = Hand.object_mesh
    monkeypatch.setattr(Hand, "object_mesh", lambda *a, **k: builds.append(a) or build(*a, **k))
    mpc = ContactImplicitMPC.from_env(TRIFINGER_ENV, plant, settings=EAGER)
    assert builds == []  # a user mesh is not loaded (and decomposed) a second time
    assert tips_before_sliding(plant.object) and mpc.cost.tilt == TRIFINGER_ENV.model.tilt
    TRIFINGER_ENV.make_plant(str(path))  # a new plant: built anew
    assert len(builds) == 1


def test_the_mpc_fingertips_are_the_plants_sites():
    plant = ALLEGRO_ENV.make_plant("cube")
    mpc = ContactImplicitMPC.from_env(ALLEGRO_ENV, plant, settings=EAGER)
    tips = mpc.fingertips(torch.as_tensor(plant.state()))
    np.testing.assert_allclose(tips.numpy(), plant.fingertips(), atol=1e-6)


@pytest.mark.parametrize("hand", sorted(HANDS))
def test_two_objects_two_short_trials(hand, tmp_path):
    for obj in ("cube", "torus"):
        summary = tmp_path / f"{obj}.json"
        out = tmp_path / obj
        assert (
            main(["run", hand, "--object", obj, *FAST, "--out", str(out), "--json", str(summary)])
            == 0
        )
        result = json.loads(summary.read_text())
        assert set(SUMMARY_KEYS) <= set(result) and result["trials"] == 2
        records = sorted((out / "trials").glob("*.json"))
        assert len(records) == 2
        record = json.loads(records[0].read_text())
        assert record["steps"] == 4 and record["contact_slots"] >= 1
        assert 0 <= record["contacts_found_max"]


def test_a_user_mesh_runs_on_a_hand(tmp_path):
    path = tmp_path / "wedge.stl"
    trimesh.creation.box([0.06, 0.04, 0.03]).export(path)
    out = tmp_path / "out"
    args = ["run", "trifinger", "--object", str(path), *FAST, "--trials", "1", "--out", str(out)]
    assert main(args) == 0
    (record,) = (out / "trials").glob("trifinger_in-hand_wedge-mesh-*_seed0.json")
    assert read_json(record)["object"] == str(path.resolve())


@pytest.mark.parametrize(
    "bad", [["--object", "spoon"], ["--object", "missing.stl"], ["--workers", "0"]]
)
def test_bad_options_are_refused(bad, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["run", "allegro", *bad, "--out", str(tmp_path)])
    assert exit_info.value.code not in (0, None)
    assert bad[0] in capsys.readouterr().err
