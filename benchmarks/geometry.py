"""The torch contact geometry: its agreement with MuJoCo and its speed, in one run.

Agreement: random poses of a hull (a mesh's convex hull) against a plane, a sphere, a capsule
and a box, in penetration and apart up to 2 cm: the signed distance against
``mujoco.mj_geomDistance`` (worst and 99th percentile [mm]) and, apart by more than 1 mm, the
normal against the direction of MuJoCo's witness points [deg]. Speed, on the TriFinger with
the cube, one thread: ``Contacts`` at one state and at B states beside the MuJoCo detector
(with ``--compile`` also ``torch.compile``d, ``fullgraph=True``: no graph break), and the
rollout (``torchcontact.geometry.rollout``, h = 0.1 s) in states per second beside
``mujoco.rollout`` of the plant for the same simulated time (50 substeps of 2 ms a state).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/geometry.py --compile

writes JSON (default results/geometry/geometry.json).
"""

# ruff: noqa: B023  (each timed lambda runs at once, inside its own loop turn)
from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import mujoco  # noqa: E402
import mujoco.rollout  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from torchcontact.environments import environment  # noqa: E402
from torchcontact.geometry import rollout  # noqa: E402
from torchcontact.model import paper_model  # noqa: E402
from torchcontact.results import write_json  # noqa: E402
from torchcontact.sim.detect import ContactDetector  # noqa: E402
from torchcontact.sim.geometry import scene_geometry  # noqa: E402
from torchcontact.sim.hands import HandPlant  # noqa: E402

OTHERS = {"plane": "ground", "sphere": "sphere", "capsule": "capsule", "box": "box"}


def _scene(seed: int) -> mujoco.MjModel:
    points = np.random.default_rng(seed).normal(size=(40, 3)) * [0.03, 0.02, 0.025]
    vertices = " ".join(map(str, points.ravel()))
    return mujoco.MjModel.from_xml_string(f"""<mujoco><asset><mesh name="m" vertex="{vertices}"/>
    </asset><worldbody><geom name="ground" type="plane" size="1 1 .1"/>
    <body name="object"><freejoint/><geom name="hull" type="mesh" mesh="m"/></body>
    <body><freejoint/><geom name="sphere" type="sphere" size="0.01"/></body>
    <body><freejoint/><geom name="capsule" type="capsule" size="0.012 0.02"/></body>
    <body><freejoint/><geom name="box" type="box" size="0.02 0.015 0.01"/></body>
    </worldbody></mujoco>""")


def agreement(poses: int, seed: int = 0) -> list[dict]:
    model = _scene(seed)
    geometry = scene_geometry(
        ContactDetector(model, ["object"], 8, margin=0.02), dtype=torch.float64
    )
    data = mujoco.MjData(model)
    kinds = [geometry.shapes[p.b].kind for p in geometry.pairs]
    index = {"plane": "plane", "sphere": "point", "capsule": "segment", "box": "polytope"}
    rng = np.random.default_rng(seed + 1)
    errors = {name: ([], []) for name in OTHERS}
    for _ in range(poses):
        q = np.zeros(model.nq)
        for body in range(4):
            q[7 * body : 7 * body + 3] = rng.uniform(-0.04, 0.04, 3) + [0, 0, 0.05]
            quat = rng.normal(size=4)
            q[7 * body + 3 : 7 * body + 7] = quat / np.linalg.norm(quat)
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        phi, normal = geometry.distances(torch.tensor(q))
        for name, geom in OTHERS.items():
            fromto = np.zeros(6)
            reference = mujoco.mj_geomDistance(
                model, data, model.geom("hull").id, model.geom(geom).id, 0.02, fromto
            )
            if reference >= 0.02:
                continue
            pair = kinds.index(index[name])
            errors[name][0].append(abs(phi[pair].item() - reference) * 1e3)
            if reference > 1e-3:
                expected = fromto[3:] - fromto[:3]
                cosine = normal[pair].numpy() @ expected / np.linalg.norm(expected)
                errors[name][1].append(np.degrees(np.arccos(np.clip(cosine, -1, 1))))
    rows = []
    for name, (distance, angle) in errors.items():
        rows.append(
            {
                "pair": f"hull-{name}",
                "poses": len(distance),
                "distance_worst_mm": float(np.max(distance)),
                "distance_p99_mm": float(np.quantile(distance, 0.99)),
                "normal_worst_deg": float(np.max(angle)) if angle else None,
                "normal_p99_deg": float(np.quantile(angle, 0.99)) if angle else None,
            }
        )
    return rows


def _timed(call, repeat: int) -> float:
    call()
    start = time.perf_counter()
    for _ in range(repeat):
        call()
    return (time.perf_counter() - start) / repeat


def speed(batches: list[int], steps: int, compile_: bool) -> tuple[list[dict], list[dict]]:
    env = HandPlant("trifinger", "cube")
    description = environment("trifinger")
    geometry = scene_geometry(env.detector, dtype=torch.float64)
    system = description.system(env).double()
    model = paper_model(0.5).double()
    rng = np.random.default_rng(0)
    contacts_rows, rollout_rows = [], []
    for batch in (1, max(batches)):
        q = np.tile(env.data.qpos, (batch, 1))
        q[:, 7:] += rng.normal(0, 0.05, (batch, 9))
        q_torch = torch.tensor(q)
        with torch.no_grad():
            ours = _timed(lambda: geometry(q_torch), 3)
        theirs = _timed(lambda: env.detector(q), 3)
        contacts_rows.append({"batch": batch, "torch_ms": ours * 1e3, "detector_ms": theirs * 1e3})
    if compile_:
        compiled = torch.compile(geometry, fullgraph=True, dynamic=False)
        for row in contacts_rows:
            q_torch = torch.tensor(np.tile(env.data.qpos, (row["batch"], 1)))
            start = time.perf_counter()
            with torch.no_grad():
                compiled(q_torch)
            row["compile_s"] = time.perf_counter() - start
            with torch.no_grad():
                row["torch_compiled_ms"] = _timed(lambda: compiled(q_torch), 3) * 1e3
    data = [mujoco.MjData(env.model)]
    state_size = mujoco.mj_stateSize(env.model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    substeps = round(0.1 / env.model.opt.timestep)
    for batch in batches:
        q0 = torch.tensor(env.data.qpos).expand(batch, -1).contiguous()
        controls = torch.full((batch, steps, 9), 0.01, dtype=torch.float64)
        with torch.no_grad():
            ours = _timed(
                lambda: rollout(model, system, geometry, description.layout, q0, controls, 0.1), 1
            )
        initial = np.zeros((batch, state_size))
        mujoco.mj_getState(env.model, env.data, initial[0], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        initial[:] = initial[0]
        ctrl = np.zeros((batch, steps * substeps, env.model.nu))
        theirs = _timed(lambda: mujoco.rollout.rollout(env.model, data, initial, ctrl), 1)
        rollout_rows.append(
            {
                "batch": batch,
                "steps": steps,
                "torch_states_per_s": batch * steps / ours,
                "mujoco_states_per_s": batch * steps / theirs,
            }
        )
    return contacts_rows, rollout_rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--poses", type=int, default=400, help="random poses per shape pair")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024])
    parser.add_argument("--steps", type=int, default=4, help="rollout steps of 0.1 s")
    parser.add_argument("--compile", action="store_true", help="also time torch.compile'd Contacts")
    parser.add_argument("--out", type=Path, default=Path("results/geometry"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    rows = agreement(args.poses)
    for r in rows:
        print(r)
    contacts, rollouts = speed(args.batches, args.steps, args.compile)
    for r in contacts + rollouts:
        print(r)
    settings = vars(args) | {"out": str(args.out), "device": "cpu", "threads": 1}
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(
        args.out / "geometry.json",
        {"agreement": rows, "contacts": contacts, "rollout": rollouts, "settings": settings},
    )
    print(f"wrote {args.out / 'geometry.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
