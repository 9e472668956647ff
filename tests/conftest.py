"""Test settings: one thread (2-core machines run 5–20× slower oversubscribed), seeded RNG."""

import ctypes.util
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
# MuJoCo picks its GL backend at import and fails to import if the backend's library is
# missing, so offscreen rendering is asked for only where a backend exists.
if "MUJOCO_GL" not in os.environ:
    for backend, library in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(library):
            os.environ["MUJOCO_GL"] = backend
            break

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(1)

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)


def cuda_or_skip():
    """Parameter list ``["cuda"]`` marked to skip when no CUDA device is present."""
    return [
        pytest.param(
            "cuda",
            marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device"),
        )
    ]
