"""Box pushing (Jin 2024): a bar on a slide joint pushes a row of N cubes; CF against the QP.

The paper's quasi-dynamic step, ``h = 0.02 s``, ``ε = 40``, ``Kᵣ = 500 N/m``, contact stiffness
``K = 1`` on every dual-cone row and a bar command of ``u = −0.001 m`` per step, is rolled out
for 1000 steps twice: once driven by the complementarity-free model (CF), once by the Anitescu
QP solved by OSQP. At every state of both rollouts both models predict ``v⁺`` from the same
``Q``, ``b`` and :class:`~torchcontact.Contacts`, each call timed. One step of :func:`rollout`::

    contacts = scene.detector(q)            # MuJoCo collision → φ, Jⁿ, Jᵈ, μ
    v = model(Q, b, contacts, h)            # ComplementarityFree or AnitescuQP   ← timed
    q = integrate(q, v, h, scene.layout)    # q ⊕ h v⁺

The scene, its constants and why the cubes weigh 1 g: :mod:`torchcontact.sim.box_pushing`.
Run ``python benchmarks/box_pushing.py --help``.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from studies import report
from torchcontact.contacts import Contacts
from torchcontact.integrate import integrate
from torchcontact.model import AnitescuQP, ComplementarityFree, ContactModel
from torchcontact.rotations import quaternion_angle
from torchcontact.sim.box_pushing import DTYPE, BoxPushingConfig, BoxPushingScene, build_scene
from torchcontact.stiffness import Constant
from torchcontact.validation import validate_args

SWEEP = (1, 5, 10, 15, 20)
"""Cube counts of the paper's timing comparison."""


TIMED_REGION = (
    "the call model(Q, b, contacts, h) -> v+ (dual-cone rows, K, lambda or the OSQP solve, v+), "
    "under torch.inference_mode() with value checks off; not detection, not integration"
)


def contact_model(name: str, config: BoxPushingConfig) -> ContactModel:
    """``"cf"``: the CF model with the fixed K (no damping); ``"qp"``: the OSQP baseline."""
    if name == "cf":
        stiffness = Constant(config.contact_stiffness, learnable=False)
        return ComplementarityFree(stiffness, gamma=config.gamma, facets=config.facets).to(DTYPE)
    if name == "qp":
        return AnitescuQP(facets=config.facets, settings=config.qp_settings)
    raise ValueError(f"name must be 'cf' or 'qp', got {name!r}")


@dataclass
class Rollout:
    """One trajectory and what was measured along it (per-step lists have ``steps`` entries).

    Attributes:
        q: ``(steps + 1, nq)`` configurations.
        detect_s, driver_s, other_s: seconds of detection and of each model's prediction.
        linear_diff, angular_diff: ``max |v_driver − v_other|`` over the linear velocities
            (cubes and bar) [m/s] and the cubes' angular velocities [rad/s].
        active: number of active contacts.
        phi_ground, phi_side: the smallest φ [m] of the active contacts with a vertical normal
            (cube–ground) and with a horizontal one (cube–cube, cube–bar); +inf when none.
    """

    q: torch.Tensor | None = None
    detect_s: list[float] = field(default_factory=list)
    driver_s: list[float] = field(default_factory=list)
    other_s: list[float] = field(default_factory=list)
    linear_diff: list[float] = field(default_factory=list)
    angular_diff: list[float] = field(default_factory=list)
    active: list[int] = field(default_factory=list)
    phi_ground: list[float] = field(default_factory=list)
    phi_side: list[float] = field(default_factory=list)


def _timed(model: ContactModel, scene: BoxPushingScene, contacts: Contacts):
    """``(v⁺, seconds)`` of one prediction: exactly the call ``model(Q, b, contacts, h)``."""
    start = time.perf_counter()
    v = model(scene.Q, scene.b, contacts, scene.config.h)
    return v, time.perf_counter() - start


def _smallest_phi(contacts: Contacts) -> tuple[float, float]:
    vertical = contacts.frame[:, 0, 2].abs() > 0.7  # normal ≈ ±z: a cube–ground contact

    def smallest(mask: torch.Tensor) -> float:
        selected = contacts.phi[mask & contacts.active]
        return float(selected.min()) if selected.numel() else math.inf

    return smallest(vertical), smallest(~vertical)


def rollout(
    scene: BoxPushingScene,
    driver: ContactModel,
    steps: int,
    other: ContactModel | None = None,
    progress: Callable[[], object] | None = None,
) -> Rollout:
    """Roll out ``steps`` steps driven by ``driver``: detect → v⁺ → q ⊕ h v⁺.

    When ``other`` is given it predicts from the same ``(Q, b, contacts)`` at every state,
    timed like ``driver``; it never changes the trajectory. Runs under
    ``torch.inference_mode()`` with value checks off (:func:`validate_args`), as a simulator
    calls a model in its loop. ``progress`` is called once per step.
    """
    h, layout = scene.config.h, scene.layout
    q = scene.q0
    trajectory = [q]
    out = Rollout()
    with torch.inference_mode(), validate_args(False):
        for _ in range(steps):
            start = time.perf_counter()
            contacts = scene.detector(q)
            out.detect_s.append(time.perf_counter() - start)
            v, seconds = _timed(driver, scene, contacts)
            out.driver_s.append(seconds)
            if other is not None:
                v_other, seconds = _timed(other, scene, contacts)
                out.other_s.append(seconds)
                difference = (v - v_other).abs()
                out.linear_diff.append(float(difference[scene.linear_v].max()))
                out.angular_diff.append(float(difference[scene.angular_v].max()))
            out.active.append(int(contacts.active.sum()))
            ground, side = _smallest_phi(contacts)
            out.phi_ground.append(ground)
            out.phi_side.append(side)
            q = integrate(q, v, h, layout)
            trajectory.append(q)
            if progress is not None:
                progress()
    out.q = torch.stack(trajectory)
    return out


def _median_ms(*runs: Sequence[float], warmup: int) -> float:
    """Median [ms] of the timings of several rollouts, each without its first ``warmup``."""
    timed = [t for run_ in runs for t in (run_[warmup:] or run_)]
    return 1e3 * statistics.median(timed)


def run(config: BoxPushingConfig, progress: bool = True) -> dict:
    """Both rollouts for one cube count; the measured figures as a JSON-ready dict.

    Timing (``cf_ms_median``, ``qp_ms_median``): the median over both rollouts' states, each
    after ``config.warmup`` steps, of one call ``model(Q, b, contacts, h)`` (see
    :data:`TIMED_REGION`); CF and QP predict from the same inputs at every state.
    ``trajectories`` holds the cube x positions [m], ``(steps + 1, N)`` lists, of both rollouts.
    """
    scene = build_scene(config)
    cf, qp = contact_model("cf", config), contact_model("qp", config)
    with tqdm(
        total=2 * config.steps, desc=f"N={config.cubes}", disable=not progress, leave=False
    ) as bar:
        by_cf = rollout(scene, cf, config.steps, other=qp, progress=bar.update)
        by_qp = rollout(scene, qp, config.steps, other=cf, progress=bar.update)
    warmup = config.warmup
    cf_ms = _median_ms(by_cf.driver_s, by_qp.other_s, warmup=warmup)
    qp_ms = _median_ms(by_cf.other_s, by_qp.driver_s, warmup=warmup)
    final_cf, final_qp = by_cf.q[-1, scene.cube_q], by_qp.q[-1, scene.cube_q]  # (N, 7)
    x0 = scene.q0[scene.cube_q[:, 0]]
    angle_deg = torch.rad2deg(quaternion_angle(final_cf[:, 3:], final_qp[:, 3:]))  # (N,)

    def height_error(r: Rollout) -> float:  # max |z − edge/2| of any cube [m]
        return float((r.q[:, scene.cube_q[:, 2]] - config.edge / 2).abs().max())

    return {
        "cubes": config.cubes,
        "cf_ms_median": cf_ms,
        "qp_ms_median": qp_ms,
        "speedup": qp_ms / cf_ms,
        "detect_ms_median": _median_ms(by_cf.detect_s, by_qp.detect_s, warmup=warmup),
        "steps": config.steps,
        "timed_predictions": 2 * max(config.steps - warmup, 0) or 2 * config.steps,
        "slots": config.slots,
        "active_contacts_max": max(by_cf.active + by_qp.active),
        "linear_v_diff_max_cf_states": max(by_cf.linear_diff),
        "linear_v_diff_median_cf_states": statistics.median(by_cf.linear_diff),
        "angular_v_diff_max_cf_states": max(by_cf.angular_diff),
        "linear_v_diff_max_qp_states": max(by_qp.linear_diff),
        "linear_v_diff_median_qp_states": statistics.median(by_qp.linear_diff),
        "angular_v_diff_max_qp_states": max(by_qp.angular_diff),
        "final_position_diff_max": float((final_cf[:, :3] - final_qp[:, :3]).norm(dim=-1).max()),
        "final_angle_diff_max_deg": float(angle_deg.max()),
        "cube_dx_mean_cf": float((final_cf[:, 0] - x0).mean()),
        "cube_dx_mean_qp": float((final_qp[:, 0] - x0).mean()),
        "bar_dx_cf": float(by_cf.q[-1, scene.bar_q] - scene.q0[scene.bar_q]),
        "bar_dx_qp": float(by_qp.q[-1, scene.bar_q] - scene.q0[scene.bar_q]),
        "ground_phi_min_cf": min(by_cf.phi_ground),
        "ground_phi_min_qp": min(by_qp.phi_ground),
        "side_phi_min_cf": min(by_cf.phi_side),
        "side_phi_min_qp": min(by_qp.phi_side),
        "height_error_max_cf": height_error(by_cf),
        "height_error_max_qp": height_error(by_qp),
        "trajectories": {
            "x_cf": by_cf.q[:, scene.cube_q[:, 0]].tolist(),
            "x_qp": by_qp.q[:, scene.cube_q[:, 0]].tolist(),
        },
    }


# --- reporting ------------------------------------------------------------------------------

HEADER = (
    "N",
    "contacts",
    "detect ms",
    "CF ms",
    "QP ms",
    "speedup",
    "max|dv| CF/QP states [m/s]",
    "final dp [mm]",
    "cube dx CF/QP [m]",
    "min phi ground/side [mm]",
)


def _cells(result: dict) -> list[str]:
    r = result
    return [
        f"{r['cubes']:d}",
        f"{r['active_contacts_max']:d}",
        f"{r['detect_ms_median']:.3f}",
        f"{r['cf_ms_median']:.3f}",
        f"{r['qp_ms_median']:.2f}",
        f"{r['speedup']:.1f}",
        f"{r['linear_v_diff_max_cf_states']:.3f} / {r['linear_v_diff_max_qp_states']:.3f}",
        f"{1e3 * r['final_position_diff_max']:.1f}",
        f"{r['cube_dx_mean_cf']:.3f} / {r['cube_dx_mean_qp']:.3f}",
        f"{1e3 * r['ground_phi_min_cf']:.2f} / {1e3 * r['side_phi_min_cf']:.1f}",
    ]


def format_table(results: Sequence[dict]) -> str:
    """A plain-text table of the main figures, one row per cube count."""
    return report.format_table(HEADER, [_cells(r) for r in results])


def _summary(result: dict) -> dict:
    """The scalar figures (no trajectories); a φ of +inf (no such contact) becomes None."""
    return report.json_ready({k: v for k, v in result.items() if k != "trajectories"})


def write_outputs(
    paths: dict[str, Path], results: Sequence[dict], config: BoxPushingConfig
) -> None:
    """Write the JSON, CSV and PNG (each atomically) to ``paths["json" | "csv" | "plot"]``.

    JSON: one cube count has its figures at the top level, a sweep ``{"runs": [...]}``; both
    add ``config`` (with ``cubes`` the list of cube counts), ``timed_region`` and
    ``torch_threads``. CSV: one row per cube count.
    """
    summaries = [_summary(r) for r in results]
    meta = {
        "config": {**asdict(config), "cubes": [r["cubes"] for r in results]},
        "timed_region": TIMED_REGION,
        "torch_threads": torch.get_num_threads(),
    }
    payload = {**summaries[0], **meta} if len(summaries) == 1 else {"runs": summaries, **meta}
    report.write_json(paths["json"], payload)
    report.write_csv(paths["csv"], summaries)
    plot(paths["plot"], results)


def plot(path: Path, results: Sequence[dict]) -> None:
    """Time per step against N (CF, QP, detection), and the cube x-trajectories of the
    largest N, CF (solid) against QP (dashed)."""
    from matplotlib import colormaps

    fig, (timing, paths) = report.figure(1, 2, size=(11, 4.2))
    cubes = [r["cubes"] for r in results]
    for key, label, style in (
        ("cf_ms_median", "CF (closed form)", "o-"),
        ("qp_ms_median", "QP (OSQP)", "s-"),
        ("detect_ms_median", "contact detection", "^:"),
    ):
        timing.plot(cubes, [r[key] for r in results], style, label=label)
    timing.set(xlabel="cubes N", ylabel="median time per step [ms]", yscale="log", xticks=cubes)
    timing.set_title("one-step prediction, single thread")
    timing.grid(True, which="both", alpha=0.3)
    timing.legend()
    largest = max(results, key=lambda r: r["cubes"])
    x_cf = np.asarray(largest["trajectories"]["x_cf"])
    x_qp = np.asarray(largest["trajectories"]["x_qp"])
    colors = colormaps["viridis"](np.linspace(0, 0.9, x_cf.shape[1]))
    for i, color in enumerate(colors):
        paths.plot(x_cf[:, i], color=color, lw=1.2)
        paths.plot(x_qp[:, i], color=color, lw=1.2, ls="--")
    paths.plot([], [], "k-", label="CF")
    paths.plot([], [], "k--", label="QP")
    paths.set(xlabel="step", ylabel="cube x [m]", title=f"cube x, N = {largest['cubes']}")
    paths.grid(True, alpha=0.3)
    paths.legend()
    fig.tight_layout()
    report.save_figure(fig, path)


# --- command line ---------------------------------------------------------------------------


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The options: ``--cubes`` (default the sweep), ``--steps``, ``--mass``, ``--qp-eps``,
    the output paths and ``--threads``."""
    defaults = BoxPushingConfig()
    parser = report.parser(
        "box_pushing",
        "Box pushing: CF vs QP (OSQP) predictions and time per step.",
        "results/box_pushing",
    )
    positive_int, positive_float = report.positive_int, report.positive_float
    parser.add_argument("--cubes", type=positive_int, help=f"cube count N (default {SWEEP})")
    parser.add_argument(
        "--steps", type=positive_int, default=defaults.steps, help="steps per rollout (1000)"
    )
    parser.add_argument(
        "--mass", type=positive_float, default=defaults.mass, help="cube mass [kg] (0.001)"
    )
    parser.add_argument(
        "--qp-eps",
        type=positive_float,
        default=defaults.qp_settings["eps_abs"],
        help="OSQP eps_abs = eps_rel of the QP baseline (1e-6)",
    )
    parser.add_argument("--json", type=Path, help="default OUT/box_pushing.json")
    parser.add_argument("--csv", type=Path, help="default OUT/box_pushing.csv")
    parser.add_argument("--plot", type=Path, help="default OUT/box_pushing.png")
    parser.add_argument("--threads", type=positive_int, default=1, help="torch threads")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Run one cube count (``--cubes``) or the sweep, print the table, write JSON/CSV/PNG;
    returns the exit status 0."""
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    counts = [args.cubes] if args.cubes is not None else list(SWEEP)
    qp_settings = {"eps_abs": args.qp_eps, "eps_rel": args.qp_eps}
    configs = [
        BoxPushingConfig(cubes=n, steps=args.steps, mass=args.mass, qp_settings=qp_settings)
        for n in counts
    ]
    results = []
    for config in tqdm(configs, desc="box pushing", disable=args.no_progress or len(configs) < 2):
        results.append(run(config, progress=not args.no_progress))
    print(format_table(results))
    print(f"timed: {TIMED_REGION}; medians over {results[0]['timed_predictions']} predictions")
    outputs = {
        "json": args.json or args.out / "box_pushing.json",
        "csv": args.csv or args.out / "box_pushing.csv",
        "plot": args.plot or args.out / "box_pushing.png",
    }
    write_outputs(outputs, results, configs[0])
    report.written(outputs.values())
    return 0


if __name__ == "__main__":
    report.run_main(main)
