"""Projected L-BFGS (torchcontact.mpc.optim): its own overhead per round, and its evaluations
against SciPy's L-BFGS-B on bounded quadratics, one thread.

    python benchmarks/lbfgs_overhead.py                  # eager and torch.compile'd bookkeeping
    python benchmarks/lbfgs_overhead.py --no-compile --repeats 50

Overhead: the wall time of ``lbfgs_box`` minus the time spent inside ``fun``, per round, with a
trivially cheap objective (a 36-variable quadratic, B = 1, box ±0.005), tolerances at zero so
that every solve runs exactly ``--rounds`` rounds; setup and the start's evaluation are spread
over those rounds. Convergence: rounds, calls of ``fun`` and points evaluated to converge on
random bounded quadratics (n = 36, eigenvalues 1…10³, box ±0.005 with most bounds active),
beside SciPy's iterations and evaluations at the same tolerances (pgtol 1e-6, ftol 1e-9).
Prints tables and writes JSON (default results/lbfgs_overhead/lbfgs_overhead.json).
"""

import os

os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported: one thread for every op

import argparse  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402
import torch  # noqa: E402
from scipy.optimize import minimize  # noqa: E402

from torchcontact.mpc.optim import lbfgs_box  # noqa: E402
from torchcontact.results import write_json  # noqa: E402

torch.set_num_threads(1)

N_VARS = 36
BOX = 0.005
TOL_GRAD, TOL_CHANGE = 1e-6, 1e-9


def bounded_quadratic(seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A (n, n) with eigenvalues 1…10³ and b (n,) whose unconstrained minimiser lies about 1.5
    box half-widths out, so that most bounds are active at the optimum."""
    generator = torch.Generator().manual_seed(seed)
    q, _ = torch.linalg.qr(torch.randn(N_VARS, N_VARS, generator=generator, dtype=torch.float64))
    matrix = q @ torch.diag(torch.logspace(0, 3, N_VARS, dtype=torch.float64)) @ q.T
    minimiser = 1.5 * BOX * torch.randn(N_VARS, generator=generator, dtype=torch.float64)
    return matrix, -(matrix @ minimiser)


class TimedQuadratic:
    """``fun`` of 0.5 xᵀAx + bᵀx on rows of x, adding the time spent inside to ``seconds``."""

    def __init__(self, matrix: torch.Tensor, linear: torch.Tensor):
        self.matrix, self.linear, self.seconds = matrix, linear, 0.0

    def __call__(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        start = time.perf_counter()
        grad = x @ self.matrix + self.linear
        f = (x * (0.5 * (grad - self.linear) + self.linear)).sum(-1)
        self.seconds += time.perf_counter() - start
        return f, grad


def overhead(memory: int, compile_steps: bool, rounds: int, repeats: int) -> dict:
    """Optimizer time per round outside ``fun`` [µs]: median and minimum over ``repeats``."""
    fun = TimedQuadratic(*bounded_quadratic(0))
    x0 = torch.zeros(1, N_VARS, dtype=torch.float64)
    per_round, fun_per_call = [], []
    for repeat in range(repeats + 3):  # three warm-up solves (compilation happens in the first)
        fun.seconds = 0.0
        start = time.perf_counter()
        result = lbfgs_box(
            fun, x0, -BOX, BOX, memory=memory, max_iter=rounds, tol_grad=0.0, tol_change=0.0,
            compile_steps=compile_steps,
        )  # fmt: skip
        elapsed = time.perf_counter() - start
        assert int(result.n_iter[0]) == rounds, "the solve stopped early; lower --rounds"
        if repeat >= 3:
            per_round.append((elapsed - fun.seconds) / rounds * 1e6)
            fun_per_call.append(fun.seconds / (rounds + 1) * 1e6)
    return {
        "memory": memory,
        "compile_steps": compile_steps,
        "rounds": rounds,
        "overhead_us_median": statistics.median(per_round),
        "overhead_us_min": min(per_round),
        "fun_us_per_call_median": statistics.median(fun_per_call),
    }


def median_seconds(solve, repeats: int) -> float:
    """Median wall time of ``solve()`` over ``repeats`` runs, after one warm-up."""
    solve()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        solve()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def convergence(seed: int, trial_steps: tuple[float, ...], repeats: int) -> dict:
    """Ours and SciPy's L-BFGS-B (memory 10 both) on one bounded quadratic from x = 0."""
    matrix, linear = bounded_quadratic(seed)
    fun = TimedQuadratic(matrix, linear)
    x0 = torch.zeros(1, N_VARS, dtype=torch.float64)

    def ours():
        return lbfgs_box(
            fun, x0, -BOX, BOX, tol_grad=TOL_GRAD, tol_change=TOL_CHANGE, trial_steps=trial_steps
        )

    a, b = matrix.numpy(), linear.numpy()

    def theirs():
        return minimize(
            lambda x: (0.5 * x @ a @ x + b @ x, a @ x + b),
            np.zeros(N_VARS),
            jac=True,
            method="L-BFGS-B",
            bounds=[(-BOX, BOX)] * N_VARS,
            options={"maxcor": 10, "gtol": TOL_GRAD, "ftol": TOL_CHANGE},
        )

    result, reference = ours(), theirs()
    return {
        "seed": seed,
        "trial_steps": list(trial_steps),
        "rounds": int(result.n_iter[0]),
        "calls": int(result.n_iter[0]) + 1,
        "points": int(result.n_evals[0]),
        "converged": bool(result.converged[0]),
        "ms": 1e3 * median_seconds(ours, repeats),
        "scipy_iterations": int(reference.nit),
        "scipy_evaluations": int(reference.nfev),
        "scipy_ms": 1e3 * median_seconds(theirs, repeats),
        "f_minus_scipy": float(result.f[0]) - float(reference.fun),
        "x_gap_to_scipy": float(np.abs(result.x[0].numpy() - reference.x).max()),
        "active_bounds": int(np.isclose(np.abs(reference.x), BOX).sum()),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=20, help="rounds per overhead solve")
    parser.add_argument("--repeats", type=int, default=200, help="timed solves per setting")
    parser.add_argument("--seeds", type=int, default=10, help="random quadratics to converge on")
    parser.add_argument("--no-compile", action="store_true", help="skip compile_steps=True")
    parser.add_argument(
        "--out", type=Path, default=Path("results/lbfgs_overhead/lbfgs_overhead.json")
    )
    argv = sys.argv[1:] if argv is None else argv
    args = parser.parse_args(argv)

    modes = [False] if args.no_compile else [False, True]
    overheads = [
        overhead(memory, compiled, args.rounds, args.repeats)
        for compiled in modes
        for memory in (5, 10)
    ]
    print(f"Optimizer overhead per round, n = {N_VARS}, B = 1, one thread [µs]")
    print(f"{'bookkeeping':>12} {'memory':>6} {'median':>8} {'min':>8} {'fun/call':>9}")
    for row in overheads:
        mode = "compiled" if row["compile_steps"] else "eager"
        print(
            f"{mode:>12} {row['memory']:>6} {row['overhead_us_median']:>8.0f} "
            f"{row['overhead_us_min']:>8.0f} {row['fun_us_per_call_median']:>9.1f}"
        )

    step_sets = [(1.0, 0.5, 0.25, 0.1), (2.0, 1.0, 0.5, 0.25)]
    runs = [
        convergence(seed, steps, max(3, args.repeats // 10))
        for steps in step_sets
        for seed in range(args.seeds)
    ]
    print(f"\nConvergence on bounded quadratics (n = {N_VARS}, box ±{BOX}), eager; ms per solve")
    header = ("seed", "active", "rounds", "calls", "points", "ms", "scipy it", "scipy fev")
    print(f"{'trial_steps':>14}", " ".join(f"{h:>9}" for h in header), "  scipy ms    |Δx|∞")
    for run in runs:
        steps = "/".join(f"{s:g}" for s in run["trial_steps"])
        print(
            f"{steps:>14} {run['seed']:>9} {run['active_bounds']:>9} {run['rounds']:>9} "
            f"{run['calls']:>9} {run['points']:>9} {run['ms']:>9.2f} {run['scipy_iterations']:>9} "
            f"{run['scipy_evaluations']:>9} {run['scipy_ms']:>9.2f} {run['x_gap_to_scipy']:>8.1e}"
        )
    summary = {}
    for steps in step_sets:
        chosen = [run for run in runs if tuple(run["trial_steps"]) == steps]
        summary["/".join(f"{s:g}" for s in steps)] = {
            key: statistics.mean(run[key] for run in chosen)
            for key in ("rounds", "calls", "points", "ms", "scipy_iterations",
                        "scipy_evaluations", "scipy_ms")
        }  # fmt: skip
    print("\nMeans over seeds:")
    for steps, means in summary.items():
        print(f"  trial_steps {steps}: " + ", ".join(f"{k} {v:.2f}" for k, v in means.items()))

    write_json(
        args.out,
        {
            "command": " ".join(["python benchmarks/lbfgs_overhead.py", *argv]),
            "torch": torch.__version__,
            "scipy": scipy.__version__,
            "machine": platform.processor() or platform.machine(),
            "threads": torch.get_num_threads(),
            "n_vars": N_VARS,
            "box": BOX,
            "overhead": overheads,
            "convergence": runs,
            "convergence_means": summary,
        },
    )
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
