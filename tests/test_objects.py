"""The user's object: ObjectOptions, mesh files at their own size in metres (millimetres
refused by name), resolve() of every kind of object, the options in the MuJoCo plants, the MPC
model and the trial records, and the run command's --object-* options."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
import trimesh

import torchcontact.cli
from torchcontact import generated
from torchcontact.cli.run import configs_of, parse_args
from torchcontact.environments.fingertips import FINGERTIPS
from torchcontact.environments.hands import ALLEGRO_ENV, PAPER_OBJECT_MASS, TRIFINGER_ENV
from torchcontact.environments.presets import MPCSettings
from torchcontact.mpc.model_options import ModelOptions
from torchcontact.mpc.trial_config import TrialConfig, config_from_flat, flat_config
from torchcontact.mpc.trials import object_facts
from torchcontact.object_sources import is_mesh_file
from torchcontact.objects import ObjectOptions, resolve
from torchcontact.shapes import MAX_MESH_EXTENT, OBJECT_SIZES, load_object, make_object
from torchcontact.sim.fingertips import FingertipsPlant
from torchcontact.sim.hands import HandPlant
from torchcontact.systems import GRAVITY

BOX = (0.04, 0.03, 0.02)
"""[m] The box mesh's extents."""


@pytest.fixture
def box_mesh(tmp_path) -> Path:
    """A 4 × 3 × 2 cm box, in metres."""
    path = tmp_path / "box.stl"
    trimesh.creation.box(extents=BOX).export(path)
    return path


@pytest.fixture
def mm_mesh(tmp_path) -> Path:
    """The same box written in millimetres: 40 × 30 × 20 units."""
    path = tmp_path / "part_mm.stl"
    trimesh.creation.box(extents=[1000 * side for side in BOX]).export(path)
    return path


# --- ObjectOptions -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"size": 0.0}, "^size must be"),
        ({"size": -0.05}, "^size must be"),
        ({"size": math.inf}, "^size must be"),
        ({"scale": 0.0}, "^scale must be"),
        ({"scale": math.nan}, "^scale must be"),
        ({"mass": -0.01}, "^mass must be"),
        ({"mass": True}, "^mass must be"),
        ({"mass": "0.1"}, "^mass must be"),
        ({"friction": -0.1}, "^friction must be"),
        ({"friction": math.nan}, "^friction must be"),
        ({"size": 0.05, "scale": 2.0}, "size and scale"),
    ],
)
def test_bad_options_are_refused_by_name(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ObjectOptions(**kwargs)


def test_good_options_are_kept():
    assert ObjectOptions().is_default
    options = ObjectOptions(size=0.08, mass=0.05, friction=0.0)  # frictionless is allowed
    assert (options.size, options.scale, options.mass, options.friction) == (0.08, None, 0.05, 0)
    assert not options.is_default and not ObjectOptions(friction=0.0).is_default


def test_what_counts_as_a_mesh_file(box_mesh):
    assert is_mesh_file(box_mesh) and is_mesh_file(str(box_mesh)) and is_mesh_file("scan.obj")
    for name in ("cube", "random-1000", "random:3", 3, None):
        assert not is_mesh_file(name)


# --- mesh files at their own size -----------------------------------------------------------


def test_a_mesh_file_is_used_at_its_own_size_in_metres(box_mesh):
    obj = load_object(box_mesh, decomposition="hull")
    np.testing.assert_allclose(obj.size, BOX, atol=1e-6)
    assert obj.name == "box"
    np.testing.assert_allclose(
        load_object(box_mesh, 0.08, decomposition="hull").size, [0.08, 0.06, 0.04], atol=1e-6
    )
    np.testing.assert_allclose(
        load_object(box_mesh, scale=2, decomposition="hull").size, [0.08, 0.06, 0.04], atol=1e-6
    )
    boxed = load_object(box_mesh, (0.05, 0.05, 0.01), decomposition="hull")
    np.testing.assert_allclose(boxed.size, [0.05, 0.05, 0.01], atol=1e-6)
    with pytest.raises(ValueError, match="size and scale"):
        load_object(box_mesh, 0.08, scale=2)
    with pytest.raises(ValueError, match="scale"):
        load_object(box_mesh, scale=-1)


def test_a_mesh_in_millimetres_is_refused_naming_the_options_to_fix_it(mm_mesh):
    with pytest.raises(ValueError, match="millimetres") as refused:
        load_object(mm_mesh, decomposition="hull")
    message = str(refused.value)
    for option in ("--object-size", "--object-scale", "size=", "scale="):
        assert option in message
    assert "part_mm.stl" in message
    # scaled past the limit is refused as well; its own size times 0.001, or a size, is fine
    with pytest.raises(ValueError, match="--object-scale"):
        load_object(mm_mesh, scale=0.1, decomposition="hull")
    np.testing.assert_allclose(
        load_object(mm_mesh, scale=0.001, decomposition="hull").size, BOX, atol=1e-6
    )
    assert load_object(mm_mesh, 0.05, decomposition="hull").size.max() == pytest.approx(0.05)
    # the limit itself is allowed: a 1 m object is large, not millimetres
    assert load_object(mm_mesh, MAX_MESH_EXTENT, decomposition="hull").size.max() == 1.0


# --- resolve ---------------------------------------------------------------------------------


def test_resolve_sizes_and_weighs_built_in_objects():
    plain = resolve("stick")
    np.testing.assert_allclose(plain.size, OBJECT_SIZES["stick"])
    assert plain.mass == 0.01
    sized = resolve("stick", ObjectOptions(size=0.26, mass=0.03), mass=0.1)
    np.testing.assert_allclose(sized.size, 2 * np.asarray(OBJECT_SIZES["stick"]), rtol=1e-9)
    assert sized.mass == 0.03  # the user's mass over the scene's
    assert resolve("stick", mass=0.1).mass == 0.1
    halved = resolve("cube", ObjectOptions(scale=0.5))
    np.testing.assert_allclose(halved.size, [0.03] * 3, rtol=1e-9)
    # a scene's listed size is what options scale
    scene = resolve("cube", ObjectOptions(scale=2.0), listed_size=(0.05, 0.05, 0.05))
    np.testing.assert_allclose(scene.size, [0.1] * 3, rtol=1e-9)


def test_resolve_keeps_a_scenes_listed_size_without_options():
    """The Allegro's cube is the paper's 5 cm one; options left empty must not lose it."""
    obj = resolve("cube", None, mass=0.1, listed_size=(0.05, 0.05, 0.05))
    np.testing.assert_allclose(obj.size, [0.05] * 3, rtol=1e-9)


def test_resolve_generated_objects_and_mesh_files(box_mesh):
    drawn = generated.generate(1001)
    obj = resolve("random-1001", ObjectOptions(size=0.07, mass=0.02), collision="hull")
    assert obj.name == "random-1001" and obj.mass == 0.02
    np.testing.assert_allclose(obj.vertices, drawn.vertices * (0.07 / drawn.size.max()))
    scaled = resolve("random-1001", ObjectOptions(scale=0.5))
    np.testing.assert_allclose(scaled.size, drawn.size / 2, rtol=1e-9)
    assert len(resolve("random-1000", collision="parts").collision_parts) == 4
    mesh = resolve(box_mesh, ObjectOptions(scale=2.0, mass=0.04), collision="hull")
    assert mesh.name == "mesh_box"  # apart from the built-in names
    np.testing.assert_allclose(mesh.size, [0.08, 0.06, 0.04], atol=1e-6)
    assert mesh.mass == 0.04


def test_resolve_refuses_what_it_cannot_place():
    cube = make_object("cube")
    assert resolve(cube) is cube
    with pytest.raises(ValueError, match="options must be empty"):
        resolve(cube, ObjectOptions(mass=0.02))
    with pytest.raises(ValueError, match="obj must be"):
        resolve("spoon")
    with pytest.raises(ValueError, match="collision"):
        resolve("cube", collision="mesh")


# --- the options in the plants ---------------------------------------------------------------


def _object_geoms(env) -> np.ndarray:
    body = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_BODY, "object")
    geoms = np.flatnonzero(env.model.geom_bodyid == body)
    return geoms[env.model.geom_contype[geoms] != 0]  # the colliding ones


def test_a_hand_plant_takes_the_users_mass_and_friction(box_mesh):
    env = HandPlant("trifinger", box_mesh, options=ObjectOptions(mass=0.05, friction=0.3))
    assert env.options == ObjectOptions(mass=0.05, friction=0.3)
    assert env.object.mass == 0.05 and env.object_friction == 0.3
    np.testing.assert_allclose(env.object.size, BOX, atol=1e-6)
    # read back from the compiled MuJoCo model
    body = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_BODY, "object")
    assert env.model.body_mass[body] == pytest.approx(0.05)
    np.testing.assert_allclose(env.model.geom_friction[_object_geoms(env), 0], 0.3)
    # the user's friction wins over a per-object override (the Allegro's binoculars: 0.9)
    binoculars = HandPlant("allegro", "binoculars", options=ObjectOptions(friction=0.2))
    assert binoculars.object_friction == 0.2
    assert HandPlant("allegro", "binoculars").object_friction == 0.9
    # and the user's mass over the Allegro cube's 100 g
    assert HandPlant("allegro", "cube", options=ObjectOptions(mass=0.05)).object.mass == 0.05


def test_the_fingertips_plant_takes_the_users_friction():
    env = FingertipsPlant("cube", options=ObjectOptions(friction=0.3, mass=0.02))
    assert env.object_friction == 0.3 and env.object.mass == 0.02
    np.testing.assert_allclose(env.model.geom_friction[_object_geoms(env), 0], 0.3)


def test_the_fingertips_environment_refuses_options():
    with pytest.raises(ValueError, match="options must be empty for fingertips"):
        FINGERTIPS.make_plant("cube", options=ObjectOptions(mass=0.02))
    assert FINGERTIPS.make_plant("cube", options=ObjectOptions()).object.mass == 0.01


def _weight(env, plant) -> float:
    """The z entry of the MPC model's object force [N]."""
    return float(env.system(plant).object_force[2])


def test_the_hands_model_weighs_the_users_mass_else_the_papers(box_mesh):
    heavy = TRIFINGER_ENV.make_plant(box_mesh, options=ObjectOptions(mass=0.05))
    assert _weight(TRIFINGER_ENV, heavy) == pytest.approx(-0.05 * GRAVITY)
    assert GRAVITY == pytest.approx(9.8)
    cube = TRIFINGER_ENV.make_plant("cube")
    assert _weight(TRIFINGER_ENV, cube) == pytest.approx(-0.01 * 9.8)
    # the metric scales with the modelled mass too
    ratio = TRIFINGER_ENV.system(heavy).object_metric / TRIFINGER_ENV.system(cube).object_metric
    torch.testing.assert_close(ratio, torch.full((6,), 5.0, dtype=ratio.dtype))
    # the Allegro's 100 g cube is modelled at the paper's 10 g unless the user sets a mass
    allegro_cube = ALLEGRO_ENV.make_plant("cube")
    assert allegro_cube.object.mass == pytest.approx(0.1)
    assert _weight(ALLEGRO_ENV, allegro_cube) == pytest.approx(-PAPER_OBJECT_MASS * GRAVITY)
    light = ALLEGRO_ENV.make_plant("cube", options=ObjectOptions(mass=0.02))
    assert _weight(ALLEGRO_ENV, light) == pytest.approx(-0.02 * GRAVITY)


def test_object_facts_describe_the_plants_object(box_mesh):
    plant = TRIFINGER_ENV.make_plant(box_mesh, options=ObjectOptions(mass=0.05, friction=0.3))
    facts = object_facts(plant)
    assert set(facts) == {"object_extent", "object_mass_kg", "object_friction_mu",
                          "object_collision"}  # fmt: skip
    np.testing.assert_allclose(facts["object_extent"], BOX, atol=1e-6)
    assert all(isinstance(x, float) for x in facts["object_extent"])
    assert facts["object_mass_kg"] == 0.05 and facts["object_friction_mu"] == 0.3
    assert facts["object_collision"] == "hull"
    parts = object_facts(TRIFINGER_ENV.make_plant("random-1000", collision="parts"))
    assert parts["object_collision"] == "4 parts"
    assert object_facts(TRIFINGER_ENV.make_plant("random-1000"))["object_collision"] == "hull"
    cube = object_facts(TRIFINGER_ENV.make_plant("cube"))
    assert cube["object_extent"] == pytest.approx([0.06] * 3)
    assert cube["object_mass_kg"] == 0.01 and cube["object_friction_mu"] == 0.5


def test_a_trial_config_carries_the_object_options():
    base = {"env": "trifinger", "task": "in-hand", "object": "cube", "seed": 0, "max_steps": 1,
            "settings": MPCSettings(max_iter=1, compile=False),
            "model_options": ModelOptions(stiffness=0.5)}  # fmt: skip
    assert TrialConfig(**base).object_options.is_default
    options = ObjectOptions(scale=2.0, mass=0.02, friction=0.4)
    record = flat_config(TrialConfig(**base, object_options=options))
    assert (record["object_scale"], record["object_mass"], record["object_friction"]) == (
        2.0, 0.02, 0.4)  # fmt: skip
    assert config_from_flat(record).object_options == options
    with pytest.raises(ValueError, match="size and scale both"):
        ObjectOptions(size=0.1, scale=2.0)


# --- the run command ---------------------------------------------------------------------------


def test_run_refuses_a_mesh_in_millimetres_naming_the_options(mm_mesh, capsys):
    # parse_args raises ValueError for an unusable input file; the command turns it into one
    # line on stderr and exit code 2
    with pytest.raises(ValueError, match="--object-scale"):
        parse_args(["allegro", "--object", str(mm_mesh)])
    with pytest.raises(SystemExit) as exit_info:
        torchcontact.cli.main(["run", "allegro", "--object", str(mm_mesh)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "--object-scale" in err and "--object-size" in err and "Traceback" not in err
    # with a scale it parses, at the mesh's absolute path
    args = parse_args(["allegro", "--object", str(mm_mesh), "--object-scale", "0.001"])
    assert args.pairs == [("on-palm", str(mm_mesh.resolve()))]
    assert args.object_options == ObjectOptions(scale=0.001)


def test_run_takes_generated_sets_and_object_options():
    args = parse_args(["trifinger", "--object", "random:2", "--object-mass", "0.02"])
    assert args.pairs == [("in-hand", "random-1000"), ("in-hand", "random-1001")]
    assert args.object_options == ObjectOptions(mass=0.02)
    configs = configs_of(args)
    assert {c.object for c in configs} == {"random-1000", "random-1001"}
    assert len(configs) == 2 * args.trials
    for config in configs:
        assert config.object_options == ObjectOptions(mass=0.02)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["fingertips", "--object-mass", "0.02"], "not for fingertips"),
        (["trifinger", "--object-mass", "-1"], "--object-mass must be a positive"),
        (["trifinger", "--object-size", "0.05", "--object-scale", "2"], "size and scale"),
        (["trifinger", "--object", "random:0"], "--object"),
    ],
)
def test_run_refuses_bad_object_options(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        parse_args(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err
