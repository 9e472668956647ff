"""The ``torchcontact`` command dispatches to its jobs and rejects unknown ones clearly; a
user's mistake ends in one line naming the option and exit code 2 before anything runs, and
``--debug`` shows its traceback."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import trimesh

import torchcontact.cli
import torchcontact.results
from torchcontact.cli import JOBS, main

ROOT = Path(__file__).resolve().parents[1]


def test_unknown_job_is_rejected(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["no-such-job"])
    assert exit_info.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


@pytest.mark.parametrize("job", sorted(JOBS))
def test_job_help_lists_its_options(job, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([job, "--help"])
    assert exit_info.value.code == 0
    assert "--json" in capsys.readouterr().out


@pytest.fixture
def files(tmp_path):
    """Inputs that are not what the options expect, in ``tmp_path``."""
    (tmp_path / "notes.pt").write_text("not a checkpoint\n")
    (tmp_path / "text.stl").write_text("hello, not a mesh\n")
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]])
    flat.export(tmp_path / "flat.stl")
    (tmp_path / "a_file").write_text("")
    (tmp_path / "a_dir").mkdir()
    return tmp_path


def _refused(argv, capsys, job, option):
    """Run ``argv``; check exit code 2 and a last stderr line naming ``option``."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"torchcontact {job}: error: {option}"), err
    return last


RUN_ERRORS = [
    (["--first-seed", "-1"], "--first-seed"),
    (["--stiffness", "inf"], "--stiffness"),
    (["--stiffness", "nan"], "--stiffness"),
    (["--learned", "{d}/notes.pt"], "--learned"),
    (["--object", "{d}/text.stl", "--workers", "2"], "--object"),
    (["--object", "{d}/flat.stl", "--workers", "2"], "--object"),
    (["--out", "{d}/a_file"], "--out"),
    (["--out", "{d}/a_file/sub"], "--out"),
    (["--json", "{d}/a_dir"], "--json"),
    (["--json", "{d}/a_file/summary.json"], "--json"),
]


@pytest.mark.parametrize("bad, option", RUN_ERRORS)
def test_run_refuses_user_errors_in_one_line_before_any_trial(files, capsys, bad, option):
    bad = [arg.format(d=files) for arg in bad]
    out = ["--out", str(files / "out")] if "--out" not in bad else []
    argv = ["run", "trifinger", "--trials", "1", "--max-steps", "1", "--no-progress", *out, *bad]
    last = _refused(argv, capsys, "run", option)
    assert "weights_only" not in last and "QH" not in last
    assert not (files / "out" / "trials").exists()  # no trial ran


def test_run_refuses_an_unwritable_out_before_any_trial(files, capsys, monkeypatch):
    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(torchcontact.results.tempfile, "TemporaryFile", denied)
    argv = ["run", "fingertips", "--trials", "1", "--out", str(files / "out")]
    assert "Permission denied" in _refused(argv, capsys, "run", "--out")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes anywhere")
def test_run_refuses_a_read_only_out(files, capsys):
    locked = files / "locked"
    locked.mkdir(mode=0o555)
    _refused(["run", "fingertips", "--out", str(locked)], capsys, "run", "--out")
    _refused(["run", "fingertips", "--json", str(locked / "s.json")], capsys, "run", "--json")


LEARN_K_ERRORS = [
    (["--lr", "-1"], "--lr"),
    (["--lr", "inf"], "--lr"),
    (["--noise", "-1"], "--noise"),
    (["--noise", "nan"], "--noise"),
    (["--distance-scale", "inf"], "--distance-scale"),
    (["--gamma", "0"], "--gamma"),
    (["--gamma", "nan"], "--gamma"),
    (["--sweep", "0.1", "inf", "4"], "--sweep"),
    (["--object", "teapot", "--scene", "fingertips"], "--object"),
    (["--task", "spin"], "--task"),
    (["--out", "{d}/a_file"], "--out"),
    (["--data", "{d}/a_file"], "--data"),
    (["--data", "{d}/a_file/data"], "--data"),
    (["--json", "{d}/a_dir"], "--json"),
]


@pytest.mark.parametrize("bad, option", LEARN_K_ERRORS)
def test_learn_k_refuses_user_errors_before_writing_anything(files, capsys, bad, option):
    bad = [arg.format(d=files) for arg in bad]
    out = files / "out"
    argv = ["learn-k", "--trajectories", "3", "--steps", "12", "--no-progress", *bad]
    argv += ["--out", str(out)] if "--out" not in bad else []
    _refused(argv, capsys, "learn-k", option)
    assert not (out / "data").exists() and not (out / "trifinger_cube").exists()


def test_learn_k_refuses_an_unwritable_data_folder(files, capsys):
    data = Path("/proc/no/such/data")  # no one can write there, not even root
    argv = ["learn-k", "--out", str(files / "out"), "--data", str(data), "--no-progress"]
    _refused(argv, capsys, "learn-k", "--data")
    assert not data.exists()


def test_a_corrected_learn_k_rerun_is_not_refused_after_a_bad_noise(files, capsys):
    """The bad run writes nothing, so the dataset folder of the corrected one is fresh."""
    data = files / "data"
    argv = ["learn-k", "--out", str(files / "out"), "--data", str(data), "--no-progress"]
    _refused([*argv, "--noise", "-1"], capsys, "learn-k", "--noise")
    assert not data.exists() and not (files / "out").exists()


def test_debug_shows_the_traceback_of_a_user_error(files, capsys):
    learned = str(files / "notes.pt")
    for argv in (
        ["--debug", "run", "fingertips", "--learned", learned],
        ["run", "fingertips", "--learned", learned, "--debug"],
    ):
        with pytest.raises(ValueError, match="--learned: .*not a torchcontact checkpoint"):
            main(argv)


def test_debug_in_a_subprocess_prints_the_traceback_and_without_it_one_line(files):
    command = [sys.executable, "-c", "import sys, torchcontact.cli as c; sys.exit(c.main())"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    learned = ["--learned", str(files / "notes.pt")]
    plain = subprocess.run(
        [*command, "run", "fingertips", *learned],
        capture_output=True, text=True, timeout=300, env=env,
    )  # fmt: skip
    assert plain.returncode == 2 and "Traceback" not in plain.stderr
    assert plain.stderr.strip().splitlines() == [
        f"torchcontact run: error: --learned: {files / 'notes.pt'}: not a torchcontact "
        "checkpoint (expected the model.pt of learn-k)"
    ]
    debug = subprocess.run(
        [*command, "--debug", "run", "fingertips", *learned],
        capture_output=True, text=True, timeout=300, env=env,
    )  # fmt: skip
    assert debug.returncode == 1 and "Traceback" in debug.stderr


def test_tradeoff_benchmark_help_prints_its_usage():
    result = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "tradeoff.py"), "--help"],
        capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage: python benchmarks/tradeoff.py")


def test_warm_takes_runs_options_and_refuses_a_run_that_does_not_compile(capsys):
    """``torchcontact warm`` is ``run``'s options under its own name; with ``--no-compile``
    there is nothing to compile, said in one line before anything is built."""
    with pytest.raises(SystemExit) as exit_info:
        main(["warm", "fingertips", "--object", "cube", "--no-compile"])
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert (
        error.startswith("torchcontact warm: error: --no-compile") and len(error.splitlines()) == 1
    )
    with pytest.raises(SystemExit):
        main(["warm", "fingertips", "--object", "no-such-object"])
    assert "torchcontact warm: error: " in capsys.readouterr().err
