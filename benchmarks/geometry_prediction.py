"""The torch contact geometry on the environments' recorded data: agreement and prediction.

For each environment and object, a dataset of random-action MuJoCo trajectories (collected
once into ``--out``, resumable; the learning datasets' format). On every recorded state:
each modelled pair's signed distance against ``mujoco.mj_geomDistance`` (worst and 99th
percentile [mm] over pairs within 2 cm), how often the set of pairs within the detection
margin is the detector's, and the deepest contact's φ and normal row against the recorded
(detector) contacts. Then the paper's model rolled out 1 and 10 steps from recorded states
under the recorded controls (``torchcontact.learn.evaluate.rollout_error``), with its
contacts from three sources: frozen (detected at the window's first state and held), the
MuJoCo detector at every predicted state, and the torch geometry at every predicted state;
once with the model's robot and once ``_object_only``, the robot reset to MuJoCo's after
every step (the error of the contact model and its geometry alone).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/geometry_prediction.py

writes JSON (default results/geometry/prediction.json).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from torchcontact.learn.data import collect, load  # noqa: E402
from torchcontact.learn.evaluate import rollout_error  # noqa: E402
from torchcontact.learn.scenes import make_scene  # noqa: E402
from torchcontact.results import write_json  # noqa: E402
from torchcontact.sim.geometry import geom_id, scene_geometry  # noqa: E402

CASES = (("fingertips", "cube"), ("trifinger", "cube"), ("trifinger", "bunny"), ("allegro", "cube"))
REACH = 0.02
"""[m] Pairs farther apart than this are left out of the distance errors."""


class FrozenAtStart:
    """Contacts detected at each window's first state and held over its ``horizon`` steps."""

    def __init__(self, detect, horizon: int):
        self.detect, self.horizon, self.calls, self.held = detect, horizon, 0, None

    def __call__(self, q):
        if self.calls % self.horizon == 0:
            self.held = self.detect(q)
        self.calls += 1
        return self.held


def agreement(detector, geometry, transitions) -> dict:
    model, data = detector.model, mujoco.MjData(detector.model)
    pairs = [tuple(geom_id(model, half) for half in p.label.split("|")) for p in geometry.pairs]
    q = transitions.q
    with torch.no_grad():
        phi, _ = geometry.distances(q)
        ours = geometry(q)
    errors, same_set = [], 0
    for state in range(len(q)):
        data.qpos[:] = q[state].numpy()
        mujoco.mj_forward(model, data)
        reference = np.array(
            [mujoco.mj_geomDistance(model, data, a, b, REACH, None) for a, b in pairs]
        )
        near = reference < REACH
        errors.extend(np.abs(phi[state].numpy()[near] - reference[near]) * 1e3)
        same_set += bool(
            np.array_equal(reference < geometry.margin, phi[state].numpy() < geometry.margin)
        )
    recorded = transitions.contacts
    both = recorded.active.any(-1) & ours.active.any(-1)
    deepest_ours = ours.phi.argmin(-1)
    deepest_recorded = torch.where(recorded.active, recorded.phi, torch.inf).argmin(-1)
    rows = torch.arange(len(q))
    phi_error = (ours.phi[rows, deepest_ours] - recorded.phi[rows, deepest_recorded].double())[both]
    cosine = torch.nn.functional.cosine_similarity(
        ours.jac_normal[rows, deepest_ours],
        recorded.jac_normal[rows, deepest_recorded].double(),
        -1,
    )[both]
    return {
        "states": len(q),
        "pair_distance_worst_mm": float(np.max(errors)),
        "pair_distance_p99_mm": float(np.quantile(errors, 0.99)),
        "same_pairs_within_margin": same_set / len(q),
        "states_in_contact": int(both.sum()),
        "deepest_phi_worst_mm": float(phi_error.abs().max() * 1e3) if both.any() else None,
        "deepest_row_cosine_min": float(cosine.min()) if both.any() else None,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trajectories", type=int, default=8)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--out", type=Path, default=Path("results/geometry"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    for name, obj in CASES:
        directory = collect(
            args.out / f"data_{name}_{obj}",
            name,
            obj,
            args.trajectories,
            args.steps,
            progress=False,
        ).parent
        transitions = load(directory)
        scene = make_scene(name, obj)
        detector = scene.plant.detector
        geometry = scene_geometry(detector, dtype=torch.float64)
        row = {"environment": name, "object": obj} | agreement(detector, geometry, transitions)
        for horizon in (1, 10):
            sources = {
                "frozen": FrozenAtStart(detector, horizon),
                "detector": detector,
                "geometry": geometry,
            }
            for label, source in sources.items():
                for robot in ("model", "recorded"):
                    if isinstance(source, FrozenAtStart):
                        source.calls = 0
                    error = rollout_error(
                        scene.model, transitions, source, horizon=horizon, robot=robot
                    )
                    key = f"{label}_{horizon}" + ("_object_only" if robot == "recorded" else "")
                    row[f"{key}_pos_mm"] = error["pos_mm"]
                    row[f"{key}_angle_deg"] = error["angle_deg"]
        print(row, flush=True)
        rows.append(row)
    settings = vars(args) | {"out": str(args.out)}
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "prediction.json", {"rows": rows, "settings": settings})
    print(f"wrote {args.out / 'prediction.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
