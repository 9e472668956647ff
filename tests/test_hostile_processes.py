"""Hostile inputs of the second audit (issue 75) that take other processes or real work: a
folder another process holds, two runs started together into one ``--out``, Ctrl-C in a run, a
Ray address where nothing listens and a dataset collected before its mesh changed. The cases that
need none of these are in ``test_hostile_inputs.py``."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest
import trimesh
from hostile_helpers import CLI, ENV, FAST, RUN, fake_record, refused

from torchcontact.digests import content_sha256
from torchcontact.learn.data import DataFormatError, collect, read_manifest
from torchcontact.mpc.trials import run_trials
from torchcontact.results import FolderInUse

# --- 1. two runs into one --out ------------------------------------------------------------


@pytest.fixture
def held(tmp_path):
    """``tmp_path / "out"`` held by another process (until the test ends)."""
    out = tmp_path / "out"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys; from torchcontact.results import locked_folder\n"
         f"with locked_folder({str(out)!r}):\n print('held', flush=True); sys.stdin.read()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=ENV,
    )  # fmt: skip
    assert holder.stdout.readline().strip() == "held"
    yield out, holder
    holder.kill()
    holder.wait()


def test_a_run_into_a_folder_another_run_holds_is_refused_in_one_line(held, capsys):
    out, holder = held
    pid = holder.pid
    last = refused([*RUN, "--out", str(out)], capsys, "run", "--out")
    assert f"is in use by another run (process {pid})" in last
    assert not (out / "trials").exists() and not (out / "summary.json").exists()


def test_run_trials_refuses_a_folder_another_process_holds_before_any_trial(held):
    out, holder = held
    expected = rf"^out '{out}' is in use by another run \(process {holder.pid}\)"
    with pytest.raises(FolderInUse, match=expected):
        run_trials(FAST, out=out, progress=False)
    assert not list((out / "trials").glob("*.json"))


def test_the_lock_goes_with_the_process_that_held_it(held):
    out, holder = held
    fake_record(out, FAST[0])
    with pytest.raises(FolderInUse):
        run_trials(FAST, out=out, progress=False)
    holder.kill()  # dies holding it
    holder.wait()
    (record,) = run_trials(FAST, out=out, progress=False)  # reused, not run
    assert record.steps == 1 and record.pos_err_mm == 1.0


def test_two_runs_started_together_into_one_out_never_overwrite_each_other(tmp_path):
    """The issue's reproduction: the second run is refused (the folder is held, or its
    records were made with other settings), and the first run's records stand."""
    out = tmp_path / "out"
    first = subprocess.Popen(
        [*CLI, *RUN[:8], "--max-steps", "6", *RUN[10:], "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV,
    )  # fmt: skip
    for _ in range(600):
        if (out / ".lock").is_file() and (out / ".lock").read_text().strip():
            break
        time.sleep(0.05)
    second = subprocess.run(
        [*CLI, *RUN[:8], "--max-steps", "7", *RUN[10:], "--out", str(out)],
        capture_output=True, text=True, env=ENV, timeout=300,
    )  # fmt: skip
    assert first.wait(timeout=300) == 0, first.stderr.read()
    assert second.returncode == 2 and "Traceback" not in second.stderr, second.stderr
    assert len(second.stderr.strip().splitlines()) == 1
    (record,) = (out / "trials").glob("*.json")
    assert json.loads(record.read_text())["max_steps"] == 6


# --- 3. learn-k datasets know their objects by content --------------------------------------


def test_a_dataset_of_a_mesh_since_changed_is_refused_in_one_line(tmp_path):
    mesh = tmp_path / "block.stl"
    trimesh.creation.box([0.05, 0.05, 0.05]).export(mesh)
    data = tmp_path / "data"
    collect(data, "trifinger", str(mesh), trajectories=1, steps=2, progress=False)
    assert read_manifest(data)["object_sha256"] == content_sha256(mesh)
    box = trimesh.creation.box([0.05, 0.05, 0.05])
    box.vertices[0] *= 0.5  # same bounding box and mass, another shape
    box.export(mesh)
    with pytest.raises(DataFormatError, match="other settings .*'object_sha256'") as error:
        collect(data, "trifinger", str(mesh), trajectories=2, steps=2, progress=False)
    assert "\n" not in str(error.value)


# --- 8. bounded and honest at the edges -----------------------------------------------------


def test_a_ray_address_where_nothing_listens_is_refused_at_once(tmp_path, capsys):
    start = time.perf_counter()
    argv = [*RUN, "--out", str(tmp_path), "--backend", "ray", "--address", "127.0.0.1:1"]
    last = refused(argv, capsys, "run", "--backend/--address/--workers")
    assert "address '127.0.0.1:1': no Ray cluster answers there" in last
    with pytest.raises(ValueError, match="address '127.0.0.1:1': no Ray cluster answers"):
        run_trials(FAST, out=tmp_path, progress=False, backend="ray", address="127.0.0.1:1")
    assert time.perf_counter() - start < 60 and not (tmp_path / "trials").exists()


# --- 9. one line means one line: Ctrl-C -----------------------------------------------------


def test_ctrl_c_ends_a_run_with_one_line(tmp_path):
    out = tmp_path / "out"
    # more one-step trials than can finish between the first record and the signal
    argv = [*CLI, *RUN[:7], "500", *RUN[8:], "--out", str(out)]
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV)
    for _ in range(1200):
        if list((out / "trials").glob("*.json")) or process.poll() is not None:
            break
        time.sleep(0.05)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    err = err.decode()
    kept = len(list((out / "trials").glob("*.json")))
    assert process.returncode == 130, err
    assert err.strip().splitlines()[-1] == (
        f"torchcontact run: interrupted; {kept} trials kept, rerun to resume"
    ), err
    assert "Traceback" not in err and 1 <= kept < 500
