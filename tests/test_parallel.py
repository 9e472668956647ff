"""Parallel backends: local processes and Ray give the serial run's results; a Ray task whose
worker dies is run once more; a missing Ray names the extra to install."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from torchcontact.environments.presets import MPCSettings
from torchcontact.learn.data import collect, load
from torchcontact.mpc.trial_config import trial_configs
from torchcontact.mpc.trials import run_trials
from torchcontact.parallel import RAY_EXTRA, parallel_map

ray = pytest.importorskip("ray")

TIMINGS = ("detect_ms", "solve_ms", "sim_ms")
CONFIGS = trial_configs(
    "fingertips",
    [("rotation", "cube")],
    seeds=range(2),
    settings=MPCSettings(max_iter=5, compile=False),
    max_steps=4,
)


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance of two CPUs for the module's tests."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def _outcome(record) -> dict:
    return {k: v for k, v in record.to_dict().items() if k not in TIMINGS}


def test_local_processes_give_the_serial_results():
    items = list(range(7))
    serial = dict(parallel_map(abs, [-i for i in items]))
    pooled = dict(parallel_map(abs, [-i for i in items], workers=2))
    assert serial == pooled == {i: i for i in items}


def test_bad_backend_options_name_themselves():
    with pytest.raises(ValueError, match="backend must be one of"):
        list(parallel_map(abs, [1], backend="dask"))
    with pytest.raises(ValueError, match="workers must be a positive integer"):
        list(parallel_map(abs, [1], workers=0))
    with pytest.raises(ValueError, match="address is for backend='ray'"):
        list(parallel_map(abs, [1], address="auto"))


def test_a_ray_sweep_writes_the_serial_runs_records(local_ray, tmp_path):
    serial = run_trials(CONFIGS, out=tmp_path / "serial", progress=False)
    on_ray = run_trials(CONFIGS, out=tmp_path / "ray", progress=False, backend="ray")
    assert [_outcome(r) for r in on_ray] == [_outcome(r) for r in serial]
    for config in CONFIGS:
        assert (tmp_path / "ray" / "trials" / f"{config.name}.json").is_file()
    seen = []
    run_trials(CONFIGS, out=tmp_path / "ray", backend="ray", progress=False,
               on_record=lambda record, reused: seen.append(reused))  # fmt: skip
    assert seen == [True, True]  # resumed: nothing runs again


def test_a_ray_task_whose_worker_dies_runs_once_more(local_ray, tmp_path):
    marker = tmp_path / "died"

    def die_once(value: int) -> int:
        if value == 2 and not marker.exists():
            marker.touch()
            os._exit(1)  # the worker process dies mid-task, as a killed one does
        return 10 * value

    retried = []
    results = dict(
        parallel_map(die_once, [0, 1, 2, 3], backend="ray", on_retry=lambda i, e: retried.append(i))
    )
    assert results == {0: 0, 1: 10, 2: 20, 3: 30}
    assert retried == [2] and marker.exists()


def test_a_missing_ray_names_the_extra(tmp_path):
    code = (
        "import sys; sys.modules['ray'] = None\n"
        "from torchcontact.cli import main\n"
        "main(['run', 'fingertips', '--backend', 'ray', '--trials', '1'])\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=300
    )
    assert result.returncode == 2
    assert "--backend ray" not in result.stdout and RAY_EXTRA in result.stderr
    assert not Path(tmp_path / "results").exists()  # refused before any trial ran


def test_collecting_on_ray_stores_the_serial_runs_transitions(local_ray, tmp_path):
    options = {"scene": "trifinger", "obj": "cube", "trajectories": 3, "steps": 3}
    collect(tmp_path / "serial", progress=False, **options)
    collect(tmp_path / "ray", progress=False, backend="ray", **options)
    serial, on_ray = load(tmp_path / "serial"), load(tmp_path / "ray")
    for field in ("q", "u", "q_next"):
        assert torch.equal(getattr(serial, field), getattr(on_ray, field))
    assert torch.equal(serial.contacts.phi, on_ray.contacts.phi)
