"""``torchcontact learn-k``: a tiny end-to-end run writes its results and headline JSON."""

import math

import pytest
import torch

from torchcontact.calibration import PARTS
from torchcontact.checkpoint import load_checkpoint
from torchcontact.cli import learn_k, main
from torchcontact.cli.learn_config import RESULTS_LABEL_LIMIT, build_parser, parse_config
from torchcontact.cli.split_store import split_digest
from torchcontact.mpc.trials import TrialRecord, trial_model
from torchcontact.results import read_json

HEADLINE = (
    "rollout10_err_paper_k",
    "rollout10_err_best_constant_k",
    "rollout10_err_learned",
    "improvement_vs_best_constant",
    "fit_seconds",
    "transitions",
)


def test_tiny_learn_k_run(tmp_path, capsys):
    options = (
        "--scene trifinger --object cube --trajectories 3 --steps 8 --actions random "
        "--horizon 3 --stride 2 --sweep 0.1 10 3 --epochs 2 --hidden 8 --seed 1 --no-progress "
        "--splits 2"
    )
    argv = ["learn-k", *options.split(), "--out", str(tmp_path)]
    argv += ["--json", str(tmp_path / "headline.json")]
    assert main(argv) == 0
    headline = read_json(tmp_path / "headline.json")
    assert set(HEADLINE) <= set(headline)
    assert headline["transitions"] == 24
    assert all(math.isfinite(headline[key]) for key in HEADLINE)
    record = read_json(tmp_path / "trifinger_cube" / "results.json")
    assert record["split"] == "trajectories" and len(record["splits"]) == 2
    first = record["splits"][0]
    assert [row["stiffness"] for row in first["sweep"]] == pytest.approx([0.1, 1.0, 10.0])
    assert first["best_constant_k"] in [row["stiffness"] for row in first["sweep"]]
    model, config, meta = load_checkpoint(tmp_path / "trifinger_cube" / "model.pt")
    assert config.stiffness == "contact_network" and meta["scene"] == "trifinger"
    out = capsys.readouterr().out
    assert "best constant K" in out and "learned" in out
    # A rerun reuses the collected data.
    assert main(argv) == 0
    assert "24 transitions" in capsys.readouterr().out
    # The checkpoint drives the closed loop: the MPC plans with the learned K(q), D(q).
    checkpoint = tmp_path / "trifinger_cube" / "model.pt"
    run = ["run", "trifinger", "--object", "cube", "--trials", "1", "--max-steps", "3"]
    run += ["--learned", str(checkpoint), "--no-compile", "--no-progress"]
    assert main([*run, "--out", str(tmp_path / "loop"), "--json", str(tmp_path / "loop.json")]) == 0
    assert "learned K(q), D(q)" in capsys.readouterr().out
    summary = read_json(tmp_path / "loop.json")
    assert summary["learned"] == str(checkpoint.resolve()) and summary["trials"] == 1
    trial = read_json(tmp_path / "loop" / "trials" / "trifinger_learned_in-hand_cube_seed0.json")
    assert trial["learned"] == str(checkpoint.resolve()) and trial["stiffness"] is None
    assert trial["steps"] == 3
    planned = trial_model(TrialRecord.from_dict(trial).config, h=0.1)
    assert not any(p.requires_grad for p in planned.parameters())
    for a, b in zip(planned.state_dict().values(), model.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b.to(a.dtype))


def test_run_rejects_bad_learned_options(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["run", "trifinger", "--learned", str(tmp_path / "missing.pt")])
    assert "--learned must be an existing checkpoint" in capsys.readouterr().err
    (tmp_path / "model.pt").write_bytes(b"")
    with pytest.raises(SystemExit):
        main(["run", "trifinger", "--learned", str(tmp_path / "model.pt"), "--model", "relaxed_qp"])
    assert "--learned replaces the paper model's constant K" in capsys.readouterr().err


def test_bad_options_are_rejected(capsys):
    with pytest.raises(SystemExit):
        main(["learn-k", "--object", "cube", "--trajectories", "2"])
    assert "--trajectories must give 3 or more trajectories" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["learn-k", "--steps", "5", "--horizon", "10"])
    assert "--steps must exceed --horizon" in capsys.readouterr().err


def test_tiny_learn_k_run_on_box_pushing(tmp_path):
    options = (
        "--scene box_pushing --trajectories 3 --steps 8 --horizon 3 --stride 2 "
        "--sweep 0.1 10 2 --epochs 2 --hidden 8 --no-progress --splits 1 --gamma 300"
    )
    argv = ["learn-k", *options.split(), "--out", str(tmp_path)]
    assert main([*argv, "--json", str(tmp_path / "headline.json")]) == 0
    headline = read_json(tmp_path / "headline.json")
    assert headline["transitions"] == 24
    assert all(math.isfinite(headline[key]) for key in HEADLINE)
    model, _, meta = load_checkpoint(tmp_path / "box_pushing_cube" / "model.pt")
    assert meta["actions"] == "random" and meta["joints"].count("free") == 10
    # --gamma: the fitted model, and the checkpoint that rebuilds it, use that γ
    assert meta["gamma"] == 300.0 and model.gamma == 300.0
    data = tmp_path / "data" / "box_pushing_cube_random_steps8_seed0" / "manifest.json"
    assert read_json(data)["gamma"] != 300.0  # the collected data are not rewritten


def test_learn_k_refuses_mpc_actions_for_box_pushing(capsys):
    with pytest.raises(SystemExit):
        main(["learn-k", "--scene", "box_pushing", "--actions", "mpc"])
    assert "--actions must be random for box_pushing" in capsys.readouterr().err


def test_multi_object_run_holds_out_whole_objects(tmp_path, capsys):
    """Three objects, two splits: each split's test object is in no other set of it, the
    headline gives the mean and standard deviation over the splits, and the model's system
    factors are fitted."""
    options = (
        "--scene trifinger --object cube,random-3,random-4 --trajectories 3 --steps 8 "
        "--actions random --horizon 3 --stride 2 --sweep 0.1 10 2 --epochs 2 --hidden 8 "
        "--splits 2 --loss-horizon 2 --ablate --no-progress"
    )
    argv = ["learn-k", *options.split(), "--out", str(tmp_path)]
    assert main([*argv, "--json", str(tmp_path / "headline.json")]) == 0
    headline = read_json(tmp_path / "headline.json")
    assert headline["split"] == "objects" and headline["transitions"] == 72
    assert math.isfinite(headline["improvement_vs_best_constant_sd"])
    gains = [split["improvement_vs_best_constant"] for split in headline["splits"]]
    assert headline["improvement_vs_best_constant"] == pytest.approx(sum(gains) / 2)
    for split in headline["splits"]:
        sets = [set(split[f"{name}_objects"]) for name in ("train", "val", "test")]
        assert sum(map(len, sets)) == 3 and len(set.union(*sets)) == 3
    # early stopping may keep a split's initial factors; the fit moves them somewhere
    assert any(split["calibration"]["command_gain"] != [1.0] * 9 for split in headline["splits"])
    model, config, meta = load_checkpoint(
        tmp_path / "trifinger_cube_random-3_random-4" / "model.pt"
    )
    assert config.calibrate == (*PARTS, "object_momentum")  # the TriFinger's default
    assert config.loss_horizon == 2 and meta["objects"] == ["cube", "random-3", "random-4"]
    record = read_json(tmp_path / "trifinger_cube_random-3_random-4" / "results.json")
    assert math.isfinite(record["rollout10_err_calibrated_constant_k"])
    assert math.isfinite(record["rollout10_err_uncalibrated_learned"])
    out = capsys.readouterr().out
    assert "splits by objects" in out and "calibrated constant k" in out


def test_splits_fitted_in_parallel_match_a_serial_run(tmp_path):
    options = (
        "--scene trifinger --object cube,random-3,random-4 --trajectories 3 --steps 8 "
        "--actions random --horizon 3 --stride 2 --sweep 0.1 10 2 --epochs 2 --hidden 8 "
        "--splits 3 --no-progress"
    )
    records = []
    for workers in ("1", "2"):
        out = tmp_path / f"workers{workers}"
        argv = ["learn-k", *options.split(), "--workers", workers, "--data", str(tmp_path / "data")]
        assert main([*argv, "--out", str(out)]) == 0
        records.append(read_json(out / "trifinger_cube_random-3_random-4" / "results.json"))
    for record in records:
        for split in record["splits"]:
            del split["fit_seconds"]  # the only figure that may differ
    serial, parallel = (record["splits"] for record in records)
    assert [split["seed"] for split in parallel] == [0, 1, 2]  # in split order
    assert parallel == serial


def test_a_rerun_fits_only_the_splits_it_lacks(tmp_path, monkeypatch):
    fitted = []
    run_split = learn_k.run_split
    monkeypatch.setattr(
        learn_k, "run_split", lambda *a: fitted.append(a[2]) or run_split(*a), raising=True
    )
    options = (
        "--scene trifinger --object cube --trajectories 3 --steps 8 --actions random "
        "--horizon 3 --stride 2 --sweep 0.1 10 2 --epochs 2 --hidden 8 --no-progress"
    )
    argv = ["learn-k", *options.split(), "--out", str(tmp_path)]
    results = tmp_path / "trifinger_cube" / "results.json"
    assert main([*argv, "--splits", "2"]) == 0
    first = read_json(results)["splits"]
    assert main([*argv, "--splits", "3"]) == 0  # e.g. after a crash in the third split
    assert fitted == [0, 1, 2]
    assert read_json(results)["splits"][:2] == first  # fit_seconds included: not refitted
    assert len(list((tmp_path / "trifinger_cube" / "splits").glob("*.pt"))) == 3
    assert main([*argv, "--splits", "3", "--lr", "0.01"]) == 0  # another fit: all refitted
    assert fitted == [0, 1, 2, 0, 1, 2]


def test_objects_are_listed_once_in_order():
    config = parse_config(["--scene", "fingertips", "--object", "cube,stick,cube,bunny"])
    assert config.objects == ("cube", "stick", "bunny") and config.split == "objects"
    config = parse_config(["--scene", "allegro", "--object", "all,random:3-4"])
    assert len(config.objects) == 19 and config.objects[-2:] == ("random-3", "random-4")


def test_a_long_object_list_gets_a_short_unique_results_folder(tmp_path):
    names = [f"random-{seed}" for seed in range(60)]
    config = parse_config(
        ["--scene", "trifinger", "--object", ",".join(names), "--out", str(tmp_path)]
    )
    other = parse_config(["--scene", "trifinger", "--object", ",".join(names[1:] + names[:1])])
    assert len(config.results.name) <= len("trifinger_") + RESULTS_LABEL_LIMIT
    assert config.results.name != other.results.name  # the digest tells the lists apart
    config.results.mkdir()  # a name the file system takes
    short = parse_config(["--scene", "trifinger", "--object", "all,random:0-51"])
    assert short.results.name == "trifinger_all_random_0-51"


def test_each_scene_fits_its_measured_factors_by_default():
    """The TriFinger adds the object's momentum; the Allegro leaves μ alone (a fitted μ doubled
    its falls in closed loop); an explicit list is kept as given."""
    assert parse_config(["--scene", "trifinger"]).fit.calibrate == (*PARTS, "object_momentum")
    allegro = parse_config(["--scene", "allegro"]).fit.calibrate
    assert "friction" not in allegro and set(allegro) == set(PARTS) - {"friction"}
    assert parse_config(["--scene", "fingertips"]).fit.calibrate == PARTS
    chosen = parse_config(["--scene", "allegro", "--calibrate", "friction,command_gain"])
    assert chosen.fit.calibrate == ("friction", "command_gain")


def test_an_object_split_needs_three_objects(capsys):
    with pytest.raises(SystemExit):
        main(["learn-k", "--object", "cube,stick", "--split", "objects"])
    assert "--split objects needs 3 or more objects" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["learn-k", "--calibrate", "inertia"])
    assert "--calibrate must name distinct factors" in capsys.readouterr().err


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA is available here")
def test_cuda_device_is_refused_without_cuda(capsys):
    with pytest.raises(SystemExit):
        main(["learn-k", "--device", "cuda"])
    assert "this machine has no CUDA device" in capsys.readouterr().err


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_learn_k_fits_on_cuda(tmp_path):
    options = (
        "--scene trifinger --object cube --trajectories 3 --steps 8 --actions random "
        "--horizon 3 --stride 2 --sweep 0.1 10 2 --epochs 2 --hidden 8 --splits 1 "
        "--device cuda --no-progress"
    )
    assert main(["learn-k", *options.split(), "--out", str(tmp_path)]) == 0
    model, _, _ = load_checkpoint(tmp_path / "trifinger_cube" / "model.pt")
    assert all(p.device.type == "cpu" for p in model.parameters())


def test_residual_is_fitted_second_and_drives_the_mpc(tmp_path, capsys):
    """``--residual H``: the model holds an object residual, evaluated beside the model
    without it; ``run --learned`` plans with it."""
    options = (
        "--scene trifinger --object cube --trajectories 3 --steps 8 --actions random "
        "--horizon 3 --stride 2 --sweep 0.1 10 2 --epochs 2 --hidden 8 --no-progress "
        "--splits 1 --residual 8"
    )
    assert main(["learn-k", *options.split(), "--out", str(tmp_path)]) == 0
    record = read_json(tmp_path / "trifinger_cube" / "results.json")
    assert math.isfinite(record["rollout10_err_learned_without_residual"])
    assert "learned without residual" in capsys.readouterr().out
    checkpoint = tmp_path / "trifinger_cube" / "model.pt"
    model, config, _ = load_checkpoint(checkpoint)
    assert config.residual == 8 and model.residual is not None
    run = ["run", "trifinger", "--object", "cube", "--trials", "1", "--max-steps", "3"]
    run += ["--learned", str(checkpoint), "--no-compile", "--no-progress"]
    assert main([*run, "--out", str(tmp_path / "loop")]) == 0
    trial = read_json(tmp_path / "loop" / "trials" / "trifinger_learned_in-hand_cube_seed0.json")
    assert trial["steps"] == 3
    planned = trial_model(TrialRecord.from_dict(trial).config, h=0.1)
    assert planned.residual is not None


def test_loss_contacts_option_is_checked_and_frozen_keeps_the_old_digest(capsys):
    config = parse_config(["--object", "cube"])
    assert config.fit.loss_contacts == "frozen"
    with pytest.raises(SystemExit):
        parse_config(["--object", "cube", "--loss-contacts", "geometry"])
    err = capsys.readouterr().err
    assert "--loss-contacts geometry needs --loss-horizon 2 or more" in err
    with pytest.raises(SystemExit):
        parse_config(["--object", "cube", "--loss-contacts", "detector", "--loss-horizon", "2"])
    assert "--loss-contacts: invalid choice: 'detector'" in capsys.readouterr().err
    geometry = parse_config(
        ["--object", "cube", "--loss-contacts", "geometry", "--loss-horizon", "2"]
    )
    # the digest reads every option by its name and what they resolve to, as the saved
    # records' digests did; frozen, as before the option existed, so old records are reused
    options = set(vars(build_parser().parse_args([]))) | {"objects", "grid", "results"}
    assert set(vars(learn_k.deciding_options(geometry))) == options
    assert set(vars(learn_k.deciding_options(config))) == options - {"loss_contacts"}
    frozen = parse_config(["--object", "cube", "--loss-horizon", "2"])
    assert split_digest(learn_k.deciding_options(geometry), []) != split_digest(
        learn_k.deciding_options(frozen), []
    )


def test_tiny_run_with_the_geometry_in_the_loss(tmp_path):
    """``--loss-contacts geometry``: the fit's record and checkpoint say so, and it is another
    fit than the frozen one on the same data (its own split record)."""
    options = (
        "--scene trifinger --object cube --trajectories 3 --steps 8 --actions random "
        "--horizon 3 --stride 2 --sweep 0.1 10 2 --epochs 2 --hidden 8 --no-progress "
        "--splits 1 --loss-horizon 3"
    )
    argv = ["learn-k", *options.split(), "--out", str(tmp_path)]
    results = tmp_path / "trifinger_cube"
    assert main([*argv, "--loss-contacts", "geometry"]) == 0
    geometry = read_json(results / "results.json")
    assert geometry["splits"][0]["fit"]["loss_contacts"] == "geometry"
    assert all(math.isfinite(geometry[key]) for key in HEADLINE[:-1])
    _, config, _ = load_checkpoint(results / "model.pt")
    assert config.loss_contacts == "geometry" and config.loss_horizon == 3
    assert main(argv) == 0
    frozen = read_json(results / "results.json")
    assert frozen["splits"][0]["fit"]["loss_contacts"] == "frozen"
    assert load_checkpoint(results / "model.pt")[1].loss_contacts == "frozen"
    assert len(list((results / "splits").glob("*.pt"))) == 2
    assert frozen["rollout10_err_learned"] != geometry["rollout10_err_learned"]
    assert frozen["rollout10_err_paper_k"] == geometry["rollout10_err_paper_k"]  # same data
