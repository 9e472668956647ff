"""The ``torchcontact`` command dispatches to its jobs and rejects unknown ones clearly."""

import pytest

from torchcontact.cli import JOBS, main


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
