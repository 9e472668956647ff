"""What the hostile-input tests share (issue 75): the fastest trial there is, its command line,
paths no one can write, a one-line refusal check and a made-up record a run reuses."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from torchcontact.cli import main
from torchcontact.environments.presets import MPCSettings
from torchcontact.mpc.trial_config import TrialRecord, trial_configs, trial_inputs
from torchcontact.results import write_json
from torchcontact.shipped import shipped_path

ENV = {**os.environ, "OMP_NUM_THREADS": "1"}
CLI = [sys.executable, "-c", "import sys, torchcontact.cli as c; sys.exit(c.main())"]
FAST = trial_configs(
    "fingertips", [("rotation", "cube")], range(1), MPCSettings(max_iter=2, compile=False),
    max_steps=1,
)  # fmt: skip
RUN = ["run", "fingertips", "--task", "rotation", "--object", "cube", "--trials", "1"]
RUN += ["--max-steps", "1", "--max-iter", "2", "--no-compile", "--no-progress"]
UNWRITABLE = "/proc/no/such/place.json"
"""A file path no one can write, not even root (for whom ``os.access`` says yes to anything)."""
TOO_LONG = "x" * 250 + ".json"
"""A file name the file system takes, but not with the temporary name it is written under."""
SHIPPED_TRIFINGER = Path(shipped_path("trifinger"))


def refused(argv, capsys, job: str, option: str) -> str:
    """Run ``argv``; check exit code 2 and one stderr line naming ``option``; return it."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"torchcontact {job}: error: {option}"), err
    return lines[0]


def fake_record(folder: Path, config) -> Path:
    """A record of ``config`` as a run would leave it (its outcome made up), where a run of
    ``config`` into ``folder`` finds and reuses it."""
    pose = [0.0, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0]
    record = TrialRecord(
        config=config, success=False, steps=1, pos_err_mm=1.0, quat_err=0.1,
        angle_err_deg=2.0, initial_pose=pose, target_pose=pose, aim_pose=pose, final_pose=pose,
        fell=False, iterations=[2], contact_slots=4, contacts_found_mean=1.0,
        contacts_found_max=1, steps_with_dropped_contacts=0, detect_ms=[1.0], solve_ms=[2.0],
        sim_ms=[1.0], inputs=trial_inputs(config),
    )  # fmt: skip
    return write_json(folder / "trials" / f"{config.name}.json", record.to_dict())
