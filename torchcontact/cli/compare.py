"""Two sweeps compared trial by trial: which trials each one won, and whether that is chance.

Closed-loop trials are chaotic: on the TriFinger's generated objects two runs of one
configuration, differing only in float rounding, end about one trial in ten the other way
(docs/experiments.md, "TriFinger and Allegro MPC"). So two success rates say little on their
own; what does is the trials one run won and the other lost, on the same trials::

    torchcontact compare results/defaults results/variant [--json comparison.json]

pairs the records of the two ``--out`` folders by (environment, task, object, seed), counts the
trials B won and lost against A, and gives the exact two-sided McNemar p-value of that split
(the chance of a split at least as uneven if each such trial were a fair coin).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from torchcontact.cli import Parser
from torchcontact.mpc.records import SET_ASIDE_STEM, read_record
from torchcontact.mpc.report import tipped
from torchcontact.results import writable_file, write_json

TrialKey = tuple[str, str, str, int]
"""(environment, task, object, seed) of a trial."""


def load_run(folder: str | Path) -> dict[TrialKey, dict]:
    """The trial records of a run's ``folder`` (its ``trials/*.json``, or the folder itself
    when it holds them), keyed by (environment, task, object, seed). Records a run set aside
    (``NAME.corrupt-1.json``, ``NAME.stale-1.json``) are not its trials and are left out.

    Raises ``ValueError`` naming the folder when it holds no records, and naming the file when
    a record is unreadable or a trial appears twice (two variants in one folder)."""
    folder = Path(folder)
    trials = folder / "trials" if (folder / "trials").is_dir() else folder
    if not trials.is_dir():
        raise ValueError(f"run must be a folder of trial records, got {str(folder)!r}")
    records: dict[TrialKey, dict] = {}
    seen: dict[TrialKey, Path] = {}
    for path in sorted(trials.glob("*.json")):
        if SET_ASIDE_STEM.search(path.stem):
            continue
        record, problem = read_record(path)
        if record is None:
            raise ValueError(f"{path} is not a trial record: {problem}")
        key = (record["env"], record["task"], record["object"], int(record["seed"]))
        if key in records:
            raise ValueError(
                f"{path} and {seen[key]} are the same trial {key}: compare one variant per folder"
            )
        records[key], seen[key] = record, path
    if not records:
        raise ValueError(f"run {str(folder)!r} holds no trial records (trials/*.json)")
    return records


def mcnemar_p(won: int, lost: int) -> float:
    """Exact two-sided McNemar p-value of ``won`` against ``lost`` discordant trials: twice
    the binomial(won + lost, ½) tail at the smaller count, at most 1 (1 when both are 0)."""
    for name, value in (("won", won), ("lost", lost)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    n, k = won + lost, min(won, lost)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2**n
    return min(1.0, 2 * tail)


@dataclass(frozen=True)
class Comparison:
    """Run B against run A on the trials both finished.

    Attributes:
        common: the number of trials both runs hold.
        successes: ``(a, b)`` successes among them.
        won, lost: the trials ``(env, task, object, seed)`` B succeeded in and A failed, and
            the other way round.
        pos_err_mm, angle_err_deg: ``(a, b)`` mean final errors over the common trials.
        tipped: ``(a, b)`` common trials whose object ended tipped over
            (:func:`~torchcontact.mpc.report.tipped`).
        only_a, only_b: trials one run holds and the other does not (left out).
    """

    common: int
    successes: tuple[int, int]
    won: list[TrialKey]
    lost: list[TrialKey]
    pos_err_mm: tuple[float, float]
    angle_err_deg: tuple[float, float]
    tipped: tuple[int, int]
    only_a: int
    only_b: int

    @property
    def p_value(self) -> float:
        """The exact McNemar p-value of ``len(won)`` against ``len(lost)``."""
        return mcnemar_p(len(self.won), len(self.lost))

    def summary(self) -> str:
        """A few lines for a terminal."""
        a, b = self.successes
        lines = [
            f"{self.common} common trials (left out: {self.only_a} only in A, "
            f"{self.only_b} only in B)",
            f"A: {a} ({100 * a / self.common:.1f} %), {self.pos_err_mm[0]:.1f} mm, "
            f"{self.angle_err_deg[0]:.1f}°, tipped {self.tipped[0]}",
            f"B: {b} ({100 * b / self.common:.1f} %), {self.pos_err_mm[1]:.1f} mm, "
            f"{self.angle_err_deg[1]:.1f}°, tipped {self.tipped[1]}",
            f"B won {len(self.won)}, lost {len(self.lost)}: McNemar p = {self.p_value:.3g}",
        ]
        for label, keys in (("won", self.won), ("lost", self.lost)):
            if keys:
                shown = ", ".join(f"{obj} seed {seed}" for _, _, obj, seed in keys)
                lines.append(f"  {label}: {shown}")
        return "\n".join(lines)


def compare_runs(a: str | Path, b: str | Path) -> Comparison:
    """Run ``b``'s trial records against run ``a``'s (``--out`` folders, see :func:`load_run`)
    on the trials both hold; ``ValueError`` when they share none."""
    runs = load_run(a), load_run(b)
    common = sorted(set(runs[0]) & set(runs[1]))
    if not common:
        raise ValueError(f"runs {str(a)!r} and {str(b)!r} share no trial (env, task, object, seed)")
    won = [key for key in common if runs[1][key]["success"] and not runs[0][key]["success"]]
    lost = [key for key in common if runs[0][key]["success"] and not runs[1][key]["success"]]

    def pair(field: str, reduce) -> tuple:
        return tuple(reduce([run[key][field] for key in common]) for run in runs)

    return Comparison(
        common=len(common),
        successes=pair("success", lambda values: int(sum(values))),
        won=won,
        lost=lost,
        pos_err_mm=pair("pos_err_mm", lambda values: float(np.mean(values))),
        angle_err_deg=pair("angle_err_deg", lambda values: float(np.mean(values))),
        # load_run reads only records with their poses, so every one can tell
        tipped=tuple(sum(tipped(run[key]) for key in common) for run in runs),
        only_a=len(set(runs[0]) - set(runs[1])),
        only_b=len(set(runs[1]) - set(runs[0])),
    )


def main(argv: list[str] | None = None) -> int:
    """``torchcontact compare A B [--json PATH]``."""
    parser = Parser(
        prog="torchcontact compare",
        description="Compare two runs' trial records trial by trial (B against A).",
    )
    parser.add_argument("a", type=Path, help="the baseline run's --out folder")
    parser.add_argument("b", type=Path, help="the variant run's --out folder")
    parser.add_argument("--json", type=Path, help="also write the comparison here")
    args = parser.parse_args(argv)
    if args.json is not None:
        writable_file("--json", args.json)
    comparison = compare_runs(args.a, args.b)
    print(comparison.summary())
    if args.json is not None:
        write_json(args.json, {**asdict(comparison), "p_value": comparison.p_value})
        print(f"wrote {args.json}")
    return 0
