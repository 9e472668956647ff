"""Pick MuJoCo's offscreen GL backend before ``mujoco`` is imported (it reads it at import)."""

from __future__ import annotations

import ctypes.util
import os

BACKENDS = (("egl", "EGL"), ("osmesa", "OSMesa"))


def select_gl_backend() -> str | None:
    """Set ``MUJOCO_GL`` to the first backend whose library exists, unless already set.

    MuJoCo fails to *import* when ``MUJOCO_GL`` names a backend whose library is missing, so
    nothing is set when none is found (rendering then raises, simulation still works).
    Returns the backend in force.
    """
    if "MUJOCO_GL" not in os.environ:
        for backend, library in BACKENDS:
            if ctypes.util.find_library(library):
                os.environ["MUJOCO_GL"] = backend
                break
    return os.environ.get("MUJOCO_GL")
