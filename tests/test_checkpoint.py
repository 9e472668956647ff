"""Checkpoints: a file that is not one is refused by name, without unsafe advice."""

import pytest
import torch

from torchcontact.checkpoint import CheckpointError, load_checkpoint


def test_a_file_that_is_no_checkpoint_is_named_without_unpickling_advice(tmp_path):
    path = tmp_path / "notes.pt"
    path.write_text("not a checkpoint\n")
    with pytest.raises(CheckpointError, match=r"notes\.pt: not a torchcontact checkpoint") as info:
        load_checkpoint(path)
    assert "weights_only" not in str(info.value)
    assert isinstance(info.value, ValueError)


def test_a_torch_file_of_other_content_is_refused(tmp_path):
    path = tmp_path / "weights.pt"
    torch.save({"layer.weight": torch.zeros(2)}, path)
    with pytest.raises(CheckpointError, match="expected version 1, found None"):
        load_checkpoint(path)
    torch.save({"version": 1, "config": {"no_such_field": 1}}, path)
    with pytest.raises(CheckpointError, match="damaged checkpoint"):
        load_checkpoint(path)
