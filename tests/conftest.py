"""Test settings: one thread (2-core machines run 5–20× slower oversubscribed), seeded RNG."""

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
import pytest  # noqa: E402
import torch  # noqa: E402

import torchcontact.sim  # noqa: E402, F401  (sets MUJOCO_GL before any test imports mujoco)

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


def render_or_skip(env, width: int, height: int):
    """``env.render(width, height)``, the test skipped where the machine has no OpenGL backend
    for offscreen rendering (MuJoCo then fails to make a context: an AttributeError under
    ``MUJOCO_GL=disable``, other errors for a missing EGL or OSMesa). A ValueError, the
    environment's own argument check, is not a missing backend and fails the test."""
    try:
        return env.render(width, height)
    except ValueError:
        raise
    except Exception as error:
        pytest.skip(f"no OpenGL backend for offscreen rendering: {error}")
