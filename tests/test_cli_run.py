"""``torchcontact run fingertips``: options, one short trial end to end, its files, resuming."""

import json

import pytest

from torchcontact.cli import main
from torchcontact.cli.run import configs_of, parse_args
from torchcontact.environments import environment
from torchcontact.environments.fingertips import PAPER_STIFFNESS, STIFFNESS
from torchcontact.mpc.model_options import ModelOptions
from torchcontact.mpc.report import SUMMARY_KEYS
from torchcontact.mpc.trial_config import SCENES_VERSION, TrialConfig
from torchcontact.mpc.trials import build_trial
from torchcontact.relaxed_qp import PAPER_RELAXATION

ARGS = ["run", "fingertips", "--task", "rotation", "--object", "cube", "--trials", "1"]
FAST = ["--max-steps", "15", "--max-iter", "5", "--no-compile", "--no-progress"]
RECORD = "fingertips_rotation_cube_seed0.json"


def test_one_short_trial_writes_summary_table_and_plot(tmp_path, capsys):
    summary_path = tmp_path / "summary.json"
    assert main([*ARGS, *FAST, "--out", str(tmp_path / "out"), "--json", str(summary_path)]) == 0
    summary = json.loads(summary_path.read_text())
    assert set(SUMMARY_KEYS) <= set(summary)
    assert summary["trials"] == 1 and summary["success_rate"] == 0.0  # 15 steps are too few
    assert summary["solve_ms_median"] > 0 and summary["pos_err_mm_mean"] > 0
    assert summary["model"] == "paper" and summary["preset"] is None  # options overrode it
    assert summary["settings"]["max_iter"] == 5 and summary["settings"]["compile"] is False
    out = tmp_path / "out"
    assert json.loads((out / "summary.json").read_text()) == summary
    assert (out / "trials.csv").read_text().startswith("task,object,seed,success")
    assert (out / "results.png").stat().st_size > 0
    record = json.loads((out / "trials" / RECORD).read_text())
    assert record["steps"] == 15 and len(record["solve_ms"]) == 15
    assert record["aim_pose"] == record["target_pose"]  # a rotation target rests already
    assert record["fell"] is False and summary["falls"] == 0  # the ground holds it
    assert summary["tipped"] == 0  # the cube turns about the vertical
    printed = capsys.readouterr().out
    assert "rotation" in printed and "success 0.0% of 1" in printed
    assert "falls 0, tipped 0 |" in printed
    assert "through the paper model" in printed


def test_finished_trials_are_not_run_again(tmp_path):
    """A record is rewritten (atomically, as a new file) only when its trial is run again."""
    out = tmp_path / "out"
    main([*ARGS, *FAST, "--out", str(out)])
    path = out / "trials" / RECORD
    before = path.stat()
    assert main([*ARGS, *FAST, "--out", str(out)]) == 0
    after = path.stat()
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)


def test_a_record_of_other_settings_refuses_the_run_in_one_line(tmp_path, capsys):
    """Other settings into the same folder: refused before any trial, the record kept; another
    folder runs them."""
    out = tmp_path / "out"
    main([*ARGS, *FAST, "--out", str(out)])
    path = out / "trials" / RECORD
    before = path.read_text()
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        main([*ARGS, "--max-steps", "16", *FAST[2:], "--out", str(out)])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("torchcontact run: error: ")
    assert "--out" in err and "max_steps 15 → 16" in err
    assert path.read_text() == before
    other = tmp_path / "other"
    assert main([*ARGS, "--max-steps", "16", *FAST[2:], "--out", str(other)]) == 0
    record = json.loads((other / "trials" / RECORD).read_text())
    assert record["max_steps"] == 16 and record["steps"] == 16


def test_a_short_relaxed_qp_trial_is_recorded_under_its_own_name(tmp_path, capsys):
    out = tmp_path / "out"
    fast = ["--max-steps", "5", *FAST[2:]]
    assert main([*ARGS, *fast, "--model", "relaxed_qp", "--out", str(out)]) == 0
    name = "fingertips_relaxed_qp_rotation_cube_seed0.json"
    record = json.loads((out / "trials" / name).read_text())
    assert record["model"] == "relaxed_qp" and record["relaxation"] == PAPER_RELAXATION
    assert record["stiffness"] is None and record["steps"] == 5
    assert record["gaps"] == "frozen"  # the preset's propagated gaps are the paper model's
    summary = json.loads((out / "summary.json").read_text())
    assert summary["model"] == "relaxed_qp" and summary["trials"] == 1
    assert "through the relaxed_qp model" in capsys.readouterr().out


def test_the_options_become_one_trial_config_per_seed_and_pair():
    args = parse_args(["fingertips", "--task", "rotation", "--object", "all", "--trials", "2"])
    configs = configs_of(args)
    env = environment("fingertips")
    pairs = env.select("rotation", "all")
    assert len(pairs) > 1 and len(configs) == 2 * len(pairs)
    assert [(c.task, c.object, c.seed) for c in configs] == [
        (task, obj, seed) for task, obj in pairs for seed in (0, 1)
    ]
    balanced = env.preset("balanced")
    assert configs[0] == TrialConfig(
        env="fingertips",
        task="rotation",
        object=pairs[0][1],
        seed=0,
        max_steps=env.criterion.max_steps,
        settings=balanced,
        model_options=ModelOptions(stiffness=STIFFNESS),
    )
    assert configs[0].settings == balanced


def test_first_seed_moves_the_seeds_off_the_reported_ones():
    args = parse_args(["fingertips", "--task", "rotation", "--trials", "3", "--first-seed", "20"])
    assert sorted({c.seed for c in configs_of(args)}) == [20, 21, 22]


def test_a_residuals_plan_is_fixed_unless_told_and_reaches_the_mpc():
    assert configs_of(parse_args(["fingertips"]))[0].model_options.residual_plan == "fixed"
    config = configs_of(parse_args(["fingertips", "--residual-plan", "full"]))[0]
    assert config.model_options.residual_plan == "full"
    assert build_trial(config)[2].residual_plan == "full"


def test_each_model_has_its_own_variant_the_default_output_folder():
    """``main`` writes to results/VARIANT unless given ``--out``."""
    assert configs_of(parse_args(["fingertips"]))[0].variant == "fingertips"
    relaxed = configs_of(parse_args(["fingertips", "--model", "relaxed_qp"]))[0]
    assert relaxed.variant == "fingertips_relaxed_qp"
    assert parse_args(["fingertips"]).model_options.model == "paper"


def test_the_cli_plans_with_each_environments_default_k_and_learn_k_keeps_the_papers():
    from torchcontact.learn.scenes import make_scene

    def k(*argv):
        return parse_args(list(argv)).model_options.stiffness

    assert k("fingertips") == STIFFNESS == 4.64  # learn-k's best on the cube
    assert k("allegro") == 0.5
    assert k("trifinger") is None  # its shipped model (tests/test_shipped.py)
    assert k("trifinger", "--stiffness", "paper") == 0.5
    assert k("fingertips", "--stiffness", "1") == 1.0
    assert make_scene("fingertips", "cube").paper_stiffness == PAPER_STIFFNESS == 1.0
    assert environment("fingertips").stiffness == PAPER_STIFFNESS


def test_the_benchmark_collides_every_object_as_its_hull_as_the_paper_does():
    assert parse_args(["trifinger"]).collision == "hull"
    assert parse_args(["trifinger", "--collision", "auto"]).collision == "auto"
    trifinger = environment("trifinger")
    mug = trifinger.make_plant("mug")
    assert mug.object.collide_hull and len(mug.object.collision_parts) == 1
    assert not trifinger.make_plant("mug", "auto").object.collide_hull


def test_the_qp_plans_with_frozen_gaps_whatever_the_preset():
    assert parse_args(["fingertips", "--model", "relaxed_qp"]).settings.gaps == "frozen"
    assert parse_args(["fingertips", "--gaps", "propagated"]).settings.gaps == "propagated"
    assert parse_args(["fingertips", "--gaps", "frozen"]).settings.gaps == "frozen"


def test_a_record_without_scenes_is_run_again_and_stamped(tmp_path):
    """A record without ``scenes`` comes from version 1 of the plants: its outcome may differ."""
    out = tmp_path / "out"
    main([*ARGS, *FAST, "--out", str(out)])
    path = out / "trials" / RECORD
    record = json.loads(path.read_text())
    assert record["scenes"] == SCENES_VERSION
    path.write_text(json.dumps({k: v for k, v in record.items() if k != "scenes"}))
    assert main([*ARGS, *FAST, "--out", str(out)]) == 0
    assert json.loads(path.read_text())["scenes"] == SCENES_VERSION


@pytest.mark.parametrize(
    "bad, message",
    [
        (["--trials", "0"], "--trials"),
        (["--stiffness", "-1"], "--stiffness"),
        (["--task", "spin"], "--task"),
        (["--object", "teapot"], "--object"),
        (["--model", "cf"], "--model"),
        (["--model", "qp"], "--model"),  # the relaxed QP's old name
        (["--model", "relaxed_qp", "--stiffness", "1"], "--stiffness"),
        (["--relaxation", "1e-3"], "--relaxation"),
        (["--model", "relaxed_qp", "--relaxation", "0"], "--relaxation"),
        (["--preset", "fastest"], "--preset"),
        (["--horizon", "0"], "--horizon"),
        (["--memory", "0"], "--memory"),
        (["--max-iter", "0"], "--max-iter"),
        (["--planner", "adam"], "--planner"),
        (["--collision", "convex"], "--collision"),
        (["--gaps", "updated"], "--gaps"),
        (["--model", "relaxed_qp", "--gaps", "propagated"], "--gaps"),
        (["--tips", "a,b"], "--tips"),
    ],
)
def test_bad_options_are_refused(tmp_path, capsys, bad, message):
    with pytest.raises(SystemExit) as exit_info:
        main(["run", "fingertips", *bad, "--out", str(tmp_path)])
    assert exit_info.value.code not in (0, None)
    assert message in capsys.readouterr().err + str(exit_info.value.code)
