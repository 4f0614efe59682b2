"""Copies a finished training run's learning figures into ``benchmarks/results/learning/<name>/``.

Usage::

    python benchmarks/learning/record_learning_run.py <run dir> <name> [--note "wall 6 min 21 s, load 0.4 -> 1.6"]
    python benchmarks/learning/record_learning_run.py <run dir> cassie_walk --out benchmarks/results/cassie_walk --checkpoint

Writes (small, text only, committed with the repo):

* ``curve.csv``: ``frames, return_total, reward_per_step, episodes, frames_per_second`` per iteration
  (return over the episodes that ended in that batch; blank when none ended);
* ``evaluation.json``: the run's ``python -m torchrl_ahrs.evaluate run=<dir>`` summary (when it has one);
* ``config.yaml``: the resolved training config;
* ``timing.txt``: the wall time and load line written by the launching script, plus ``--note``;
* with ``--checkpoint``: ``checkpoint.pt`` and ``scheduler_decisions.jsonl`` too, so that
  ``python -m torchrl_ahrs.evaluate run=<out>`` reproduces ``evaluation.json`` (a few MB).
"""

from __future__ import annotations

import argparse
import csv
import shutil
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "results" / "learning"
SCALARS = {
    "return_total": "return/total.csv",
    "reward_per_step": "reward/total.csv",
    "episodes": "episodes.csv",
    "frames_per_second": "frames_per_second.csv",
}


def read_scalar(path: Path) -> dict[int, float]:
    """``frames -> value`` from one of the CSV logger's ``step,value`` files (empty when absent)."""
    if not path.exists():
        return {}
    with path.open() as handle:
        return {int(float(row[0])): float(row[1]) for row in csv.reader(handle) if row and row[0][0].isdigit()}


def record(run_dir: Path, name: str, note: str = "", out: Path | None = None, checkpoint: bool = False) -> Path:
    """Writes the run's curve, evaluation, config and timing (and with ``checkpoint`` its checkpoint and scheduler
    decisions) under ``out`` (default ``RESULTS / name``); returns that folder."""
    scalars = run_dir / "metrics" / "scalars"
    series = {column: read_scalar(scalars / file) for column, file in SCALARS.items()}
    frames = sorted(set().union(*series.values()))
    out = out or RESULTS / name
    out.mkdir(parents=True, exist_ok=True)
    with (out / "curve.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["frames", *SCALARS])
        for frame in frames:
            writer.writerow([frame, *(series[c].get(frame, "") for c in SCALARS)])
    if (run_dir / "evaluation.json").exists():  # absent for runs stopped early (an ablation cut short)
        shutil.copy(run_dir / "evaluation.json", out / "evaluation.json")
    shutil.copy(run_dir / "config.yaml", out / "config.yaml")
    timing = (run_dir / "timing.txt").read_text() if (run_dir / "timing.txt").exists() else ""
    (out / "timing.txt").write_text(timing + (note + "\n" if note else ""))
    for file in ("checkpoint.pt", "scheduler_decisions.jsonl") if checkpoint else ():
        if (run_dir / file).exists():
            shutil.copy(run_dir / file, out / file)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("name")
    parser.add_argument("--note", default="")
    parser.add_argument("--out", type=Path, default=None, help="default: benchmarks/results/learning/<name>")
    parser.add_argument("--checkpoint", action="store_true", help="also copy checkpoint.pt and the decisions")
    args = parser.parse_args()
    print(record(args.run_dir, args.name, args.note, args.out, args.checkpoint))


if __name__ == "__main__":
    main()
