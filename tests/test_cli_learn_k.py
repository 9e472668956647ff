"""``torchcontact learn-k``: a tiny end-to-end run writes its results and headline JSON."""

import math

import pytest
import torch

from torchcontact.checkpoint import load_checkpoint
from torchcontact.cli import main
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
        "--horizon 3 --stride 2 --sweep 0.1 10 3 --epochs 2 --hidden 8 --seed 1 --no-progress"
    )
    argv = ["learn-k", *options.split(), "--out", str(tmp_path)]
    argv += ["--json", str(tmp_path / "headline.json")]
    assert main(argv) == 0
    headline = read_json(tmp_path / "headline.json")
    assert set(HEADLINE) <= set(headline)
    assert headline["transitions"] == 24
    assert all(math.isfinite(headline[key]) for key in HEADLINE)
    record = read_json(tmp_path / "trifinger_cube" / "results.json")
    assert [row["stiffness"] for row in record["sweep"]] == pytest.approx([0.1, 1.0, 10.0])
    assert record["best_constant_k"] in [row["stiffness"] for row in record["sweep"]]
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
        main(["learn-k", "--trajectories", "2"])
    assert "--trajectories must be >= 3" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["learn-k", "--steps", "5", "--horizon", "10"])
    assert "--steps must exceed --horizon" in capsys.readouterr().err


def test_tiny_learn_k_run_on_box_pushing(tmp_path):
    options = (
        "--scene box_pushing --trajectories 3 --steps 8 --horizon 3 --stride 2 "
        "--sweep 0.1 10 2 --epochs 2 --hidden 8 --no-progress"
    )
    argv = ["learn-k", *options.split(), "--out", str(tmp_path)]
    assert main([*argv, "--json", str(tmp_path / "headline.json")]) == 0
    headline = read_json(tmp_path / "headline.json")
    assert headline["transitions"] == 24
    assert all(math.isfinite(headline[key]) for key in HEADLINE)
    _, _, meta = load_checkpoint(tmp_path / "box_pushing_cube" / "model.pt")
    assert meta["actions"] == "random" and meta["joints"].count("free") == 10


def test_learn_k_refuses_mpc_actions_for_box_pushing(capsys):
    with pytest.raises(SystemExit):
        main(["learn-k", "--scene", "box_pushing", "--actions", "mpc"])
    assert "--actions must be random for box_pushing" in capsys.readouterr().err
