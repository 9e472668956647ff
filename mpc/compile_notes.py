"""What the first compiled MPC step tells its user: one line saying what happens, and none of
Inductor's warnings known to be harmless here."""

from __future__ import annotations

import functools
import logging
import warnings

HARMLESS_INDUCTOR_LOGS = ("is missing a c-shim implementation, using proxy executor as fallback",)
"""Inductor log messages that say it generated a slower path for an op (here the triangular
solve of the L-BFGS memory): the result is the same, and the MPC's speed is measured with it."""

HARMLESS_WARNINGS = (r"`torch\._prims_common\.check` is deprecated",)
"""Deprecation warnings raised inside torch's own lowering code, not by ours."""


class _DropHarmless(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        return not any(text in message for text in HARMLESS_INDUCTOR_LOGS)


@functools.cache
def quiet_known_inductor_warnings() -> None:
    """Filter exactly the messages of :data:`HARMLESS_INDUCTOR_LOGS` and
    :data:`HARMLESS_WARNINGS` (once per process); every other warning still shows."""
    logging.getLogger("torch._inductor.ir").addFilter(_DropHarmless())
    for pattern in HARMLESS_WARNINGS:
        warnings.filterwarnings("ignore", message=pattern, category=FutureWarning)


def compile_notice(scene: str, pid: int) -> str:
    """The line a run prints when its MPC starts compiling a graph in a background process."""
    from torch._inductor.runtime.cache_dir_utils import cache_dir

    return (
        f"compiling the MPC for {scene} in a background process (pid {pid}; minutes, once per "
        f"graph, cached in {cache_dir()}); meanwhile the MPC plans eagerly, slower"
    )


class CompilingWarning(UserWarning):
    """Raised (as a warning) by a compiled MPC's ``plan()`` that is about to compile a graph
    this machine has not compiled before: that call blocks for minutes."""


def foreground_notice(description: str) -> str:
    """The warning of a ``plan()`` that compiles ``description``'s graph in the foreground."""
    from torch._inductor.runtime.cache_dir_utils import cache_dir

    return (
        f"this plan() compiles the MPC's graph for {description}: minutes on this machine's "
        f"first run (cached in {cache_dir()}, seconds to load after). To plan meanwhile, build "
        "the MPC with background_compile=True (eager plans, slower, until the graph is ready); "
        "to skip compiling, settings with compile=False; to warm the cache, run one plan() or "
        "`torchcontact run ENV --trials 1` once"
    )
