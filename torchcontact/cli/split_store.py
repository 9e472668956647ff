"""``learn-k``'s finished splits on disk, so that a rerun fits only the splits it lacks.

Each split's record (its figures, fitted model, fit config and history) is saved as it
finishes, atomically, under ``RESULTS/splits/``, in a file named by the split's seed and a
digest of everything that decides it: the options that change the data, the fit or the
evaluation, the versions of torchcontact, torch and MuJoCo, and the datasets' manifests. A
rerun with the same inputs loads those records; any change of them gives other file names, so
nothing stale is reused (a change of the library's code within one version is not seen).
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import torch

from torchcontact.learn.data import MANIFEST
from torchcontact.mpc.trials import library_versions
from torchcontact.results import atomic_write

NOT_DECIDING = (
    *("out", "results", "data", "json", "ship", "no_progress"),
    *("workers", "backend", "address", "no_compile", "splits"),
)
"""Options that change where results go, how the work is spread, how many splits there are
(each is decided by its seed) or how missing data would be collected (the manifests say how
they were), not what a split gives. Every other option, a new one included, is part of the
digest."""


def split_digest(args: argparse.Namespace, directories: list[Path]) -> str:
    """Hex SHA-256 of the deciding options, the library versions and the datasets' manifests,
    in order."""
    options = {k: v for k, v in sorted(vars(args).items()) if k not in NOT_DECIDING}
    options["versions"] = library_versions()
    digest = hashlib.sha256(json.dumps(options, sort_keys=True, default=str).encode())
    for directory in directories:
        digest.update((Path(directory) / MANIFEST).read_bytes())
    return digest.hexdigest()


def split_path(results: Path, seed: int, digest: str) -> Path:
    """Where split ``seed``'s record with inputs ``digest`` lives."""
    return Path(results) / "splits" / f"split{seed}_{digest[:16]}.pt"


def load_split(path: Path) -> dict | None:
    """The record saved at ``path``, or None when there is none."""
    if not path.is_file():
        return None
    return torch.load(path, weights_only=False)  # written by save_split: the model and config


def save_split(path: Path, record: dict) -> None:
    """Save a split's record (atomically: a crash leaves no partial file)."""
    atomic_write(path, lambda f: torch.save(record, f), binary=True)
