"""``torchcontact learn-k``: a tiny end-to-end run writes its results and headline JSON."""

import math

import pytest

from torchcontact.cli import main
from torchcontact.learn.fit import load_checkpoint
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


def test_bad_options_are_rejected(capsys):
    with pytest.raises(SystemExit):
        main(["learn-k", "--trajectories", "2"])
    assert "--trajectories must be >= 3" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["learn-k", "--steps", "5", "--horizon", "10"])
    assert "--steps must exceed --horizon" in capsys.readouterr().err
