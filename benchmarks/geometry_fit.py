"""Does fitting K along a multi-step loss with the geometry re-evaluated beat frozen rows?

The question behind a ``learn-k`` option: on the TriFinger, fit the paper model's K (with
its D = 0.1 K) on training objects by the 4-step rollout loss (the combined pose error
``w_p‖p − p*‖² + w_q(1 − ⟨q, q*⟩²)`` after 4 steps, mean over windows and objects) with its
contacts either frozen at each window's first state (as ``learn-k``'s loss holds them) or
re-evaluated by the torch geometry at every predicted state; then compare the two fitted K on
held-out objects by the learning metric (10-step rollouts, contacts re-detected by MuJoCo)
and by the geometry's own 10-step rollouts. K is fitted by a log grid, the same for both.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/geometry_fit.py

writes JSON (default results/geometry/fit.json).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from torchcontact.learn.data import collect, load  # noqa: E402
from torchcontact.learn.evaluate import log_grid, rollout_error  # noqa: E402
from torchcontact.learn.scenes import make_scene  # noqa: E402
from torchcontact.model import paper_model  # noqa: E402
from torchcontact.results import write_json  # noqa: E402
from torchcontact.sim.geometry import scene_geometry  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from geometry_prediction import FrozenAtStart  # noqa: E402

TRAINING = ("cube", "random-1", "random-2", "random-3")
HELD_OUT = ("bunny", "random-1001", "random-1002")
"""Generated seeds below 1000 tune, above it report; the bunny is a held-out mesh."""


def _objects(names, out: Path, trajectories: int, steps: int) -> list[dict]:
    objects = []
    for name in names:
        directory = collect(
            out / f"data_trifinger_{name}", "trifinger", name, trajectories, steps, progress=False
        ).parent
        detector = make_scene("trifinger", name).plant.detector
        geometry = scene_geometry(detector, dtype=torch.float64)
        objects.append(
            {"name": name, "data": load(directory), "detector": detector, "geometry": geometry}
        )
    return objects


def _error(stiffness: float, objects, source: str, horizon: int) -> dict:
    model = paper_model(stiffness).double()
    errors = []
    for obj in objects:
        contacts = {
            "frozen": FrozenAtStart(obj["detector"], horizon),
            "detector": obj["detector"],
            "geometry": obj["geometry"],
        }[source]
        errors.append(rollout_error(model, obj["data"], contacts, horizon=horizon))
    return {
        key: float(np.mean([e[key] for e in errors])) for key in ("combined", "pos_mm", "angle_deg")
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trajectories", type=int, default=6)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--grid", type=int, default=13, help="K values from 0.05 to 5")
    parser.add_argument("--out", type=Path, default=Path("results/geometry"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    training = _objects(TRAINING, args.out, args.trajectories, args.steps)
    held_out = _objects(HELD_OUT, args.out, args.trajectories, args.steps)
    grid = log_grid(0.05, 5.0, args.grid)
    rows = {}
    for source in ("frozen", "geometry"):
        losses = [_error(k, training, source, 4)["combined"] for k in grid]
        best = grid[int(np.argmin(losses))]
        rows[source] = {
            "fitted_stiffness": best,
            "training_losses": dict(zip(map(str, grid), losses, strict=True)),
            "held_out_detector_10": _error(best, held_out, "detector", 10),
            "held_out_geometry_10": _error(best, held_out, "geometry", 10),
        }
        print(source, {k: v for k, v in rows[source].items() if k != "training_losses"}, flush=True)
    settings = vars(args) | {"out": str(args.out), "training": TRAINING, "held_out": HELD_OUT}
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "fit.json", {"rows": rows, "settings": settings})
    print(f"wrote {args.out / 'fit.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
