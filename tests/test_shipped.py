"""The learned models that ship with the package: they load, match their manifests, and are
what ``torchcontact run ENV`` plans with when no flag says otherwise."""

from pathlib import Path

import pytest
import torch

from torchcontact.checkpoint import FitConfig, build_model, load_checkpoint, save_checkpoint
from torchcontact.cli import main
from torchcontact.cli.run import parse_args
from torchcontact.digests import file_sha256
from torchcontact.environments import environment
from torchcontact.mpc.trial_config import trial_configs, trial_inputs
from torchcontact.mpc.trials import trial_model
from torchcontact.shipped import SHIPPED, shipped_environments, shipped_manifest, shipped_path
from torchcontact.stiffness import Constant

SHIPPED_ENVS = shipped_environments()


def test_trifinger_ships_a_model():
    assert "trifinger" in SHIPPED_ENVS


@pytest.mark.parametrize("env", SHIPPED_ENVS)
def test_shipped_model_loads_and_matches_its_manifest(env):
    path = shipped_path(env)
    model, config, meta = load_checkpoint(path)
    manifest = shipped_manifest(env)
    assert manifest["sha256"] == file_sha256(path)
    assert manifest["environment"] == env
    assert manifest["command"].startswith(f"torchcontact learn-k --scene {env}")
    assert manifest["fit"]["stiffness"] == config.stiffness
    assert manifest["dataset"]["transitions"] > 0
    assert set(manifest["versions"]) >= {"torch", "mujoco", "torchcontact"}
    assert "improvement_vs_best_constant" in manifest["validation"]
    assert path.stat().st_size < 1_000_000  # small enough to ship


@pytest.mark.parametrize("env", SHIPPED_ENVS)
def test_default_mpc_plans_with_the_shipped_model(env):
    """Fails if the defaults fall back to a constant K (the paper's or any other)."""
    args = parse_args([env]).model_options
    assert args.learned == SHIPPED and args.stiffness is None
    task, obj = environment(env).pairs[0]
    (config,) = trial_configs(env, [(task, obj)], [0])
    assert config.model_options.learned == SHIPPED and config.model_options.stiffness is None
    model = trial_model(config, h=0.1)
    shipped = load_checkpoint(shipped_path(env))[0]
    assert not isinstance(model.stiffness, Constant) or shipped.stiffness.__class__ is Constant
    for (name, value), expected in zip(
        model.state_dict().items(), shipped.state_dict().values(), strict=True
    ):
        assert torch.equal(value, expected), name
    assert trial_inputs(config)["learned_sha256"] == file_sha256(shipped_path(env))


@pytest.mark.parametrize("env", SHIPPED_ENVS)
def test_paper_stiffness_flag_takes_the_papers_constant(env):
    args = parse_args([env, "--stiffness", "paper"]).model_options
    assert args.learned is None and args.stiffness == environment(env).stiffness


def test_an_env_without_a_shipped_model_refuses_the_flag(capsys):
    unshipped = [name for name in ("fingertips", "allegro") if name not in SHIPPED_ENVS]
    if not unshipped:
        pytest.skip("every built-in environment ships a model")
    with pytest.raises(SystemExit):
        parse_args([unshipped[0], "--stiffness", "shipped"])
    assert "ships no model" in capsys.readouterr().err


GRIPPER = Path(__file__).parents[1] / "examples" / "two_finger_gripper.xml"
CUSTOM = ["custom", "--robot", str(GRIPPER), "--tips", "left_tip,right_tip", "--object", "cube"]


def test_a_users_robot_takes_its_own_checkpoint_and_refuses_the_shipped_one(tmp_path, capsys):
    """A checkpoint saved for a user's robot (meta scene None, its joints) is what
    ``run custom --learned`` takes; the TriFinger's is refused in one line naming both."""
    config = FitConfig(stiffness="constant", damping="relative")
    joints = ["free", "slide", "slide", "slide", "slide"]
    meta = {"scene": None, "gamma": 100.0, "facets": 4, "slots": 8, "nq": 11, "nv": 10, "nu": 4,
            "joints": joints, "paper_stiffness": 1.0}  # fmt: skip
    path = save_checkpoint(tmp_path / "gripper.pt", build_model(config, meta), config, meta)
    given = parse_args([*CUSTOM, "--learned", str(path)]).model_options
    assert given.learned == str(path.resolve())
    with pytest.raises(SystemExit) as info:
        main(["run", *CUSTOM, "--learned", str(shipped_path("trifinger")), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert info.value.code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert "learned in the 'trifinger' environment on states of joints free + 9 hinge" in err
    assert "not for this robot (joints free + 4 slide)" in err
