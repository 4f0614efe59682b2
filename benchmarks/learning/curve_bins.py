"""A run's training curve in frame bins, read from its CSV scalars: where a Cassie probe leaves standing still.

    python benchmarks/learning/curve_bins.py benchmarks/results/issue26_probes/cassie_kl002_128x12_s*

prints, per run and per bin of ``--bin`` frames (default 0.5M), the mean per-step reward of ``--term``
(default ``tracking_lin_vel``, in 10^-3; Cassie collects ~3.9 standing still and 20 following every command)
and the episodes ended per batch (fewer = longer episodes). The RESULTS.md Cassie tables quote these numbers.
``--scalar <name>`` bins any other logged scalar instead, as logged (e.g. ``--scalar train/entropy``: the policy's
entropy per batch, which round 19 of issue 26 compares between runs that walk and runs that do not).

``--reaches 10,20`` prints instead, per run, where the training return first reaches each value: the frames and the
minutes of training (the sum of each batch's frames over its logged ``frames_per_second``) at the first batch where
the mean of ``return/total`` over the episodes that ended in the trailing ``--window`` frames (default 100k) is at
least that value. RESULTS.md's session-35 table quotes these.

A batch belongs to the bin where its frames start: rows are logged at the frames collected *after* the batch,
so the last batch of a 2.5M-frame run (logged at 2 500 608) counts in "2-2.5M", not in a bin of its own.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path


def read_scalar(run_dir: Path, name: str) -> list[tuple[int, float]]:
    """``(frames, value)`` rows of ``metrics/scalars/<name>.csv`` (TorchRL's CSVLogger layout); [] if absent."""
    path = run_dir / "metrics" / "scalars" / f"{name}.csv"
    if not path.exists():
        return []
    with path.open() as file:
        return [(int(row["step"]), float(row["value"])) for row in csv.DictReader(file)]


def batch_starts(rows: list[tuple[int, float]]) -> list[tuple[int, float]]:
    """``(first frame, value)`` per batch from rows logged at the frames collected after it: a batch starts
    where the one before it ended (the first at 0)."""
    ends = [frames for frames, _ in rows]
    return [(start, value) for start, (_, value) in zip([0, *ends[:-1]], rows, strict=True)]


def bin_means(rows: list[tuple[int, float]], width: int) -> dict[int, float]:
    """Mean value per bin ``[b * width, (b + 1) * width)`` of ``(first frame, value)`` rows, keyed by the
    bin's first frame."""
    sums: dict[int, list[float]] = {}
    for frames, value in rows:
        sums.setdefault(frames // width * width, []).append(value)
    return {start: sum(values) / len(values) for start, values in sorted(sums.items())}


def first_reaches(run_dir: Path, values: list[float], window: int) -> dict[float, tuple[int, float] | None]:
    """Per value, ``(frames, minutes)`` where the trailing ``window``-frame, episode-weighted mean of
    ``return/total`` first reaches it (``None``: never), minutes summed from ``frames_per_second``."""
    returns = dict(read_scalar(run_dir, "return/total"))  # frames after a batch -> mean return of its episodes
    ended = dict(read_scalar(run_dir, "episodes"))  # frames after a batch -> episodes that ended in it
    seconds, before, elapsed = 0.0, 0, {}
    for frames, rate in read_scalar(run_dir, "frames_per_second"):
        seconds += (frames - before) / rate  # t_b = sum over batches of frames_b / (frames/s)_b
        before, elapsed[frames] = frames, seconds
    reached: dict[float, tuple[int, float] | None] = dict.fromkeys(values)
    for frames in elapsed:
        inside = [end for end in returns if frames - window < end <= frames]
        count = sum(ended.get(end, 0) for end in inside)
        if not count:
            continue
        mean = sum(returns[end] * ended.get(end, 0) for end in inside) / count  # episode-weighted mean return
        for value in values:
            if reached[value] is None and mean >= value:
                reached[value] = (frames, elapsed[frames] / 60)
    return reached


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--term", default="tracking_lin_vel")
    parser.add_argument("--scalar", default=None, help="bin metrics/scalars/<scalar>.csv as logged, not a reward term")
    parser.add_argument("--bin", type=int, default=500_000)
    parser.add_argument("--reaches", default=None, help="comma-separated training returns: where each is first reached")
    parser.add_argument("--window", type=int, default=100_000, help="with --reaches: the trailing frames averaged")
    args = parser.parse_args()
    if args.reaches:
        values = [float(value) for value in args.reaches.split(",")]
        for run_dir in args.runs:
            reached = first_reaches(run_dir, values, args.window)
            cells = [
                f"{value:g}: " + (f"{hit[0] / 1e6:.2f}M, {hit[1]:.1f} min" if hit else "not reached")
                for value, hit in reached.items()
            ]
            print(f"{run_dir.name}: " + " | ".join(cells))
        return
    name, scale = (args.scalar, 1.0) if args.scalar else (f"reward/{args.term}", 1e3)  # rewards print in 10^-3
    for run_dir in args.runs:
        logged = read_scalar(run_dir, name)  # one row per batch, at the frames after it
        if not logged:  # e.g. method=ppo logs no reward terms; entropy_coeff=0 logs no entropy
            print(f"{run_dir.name}: no metrics/scalars/{name}.csv")
            continue
        term_rows = batch_starts(logged)
        first_frame = {end: start for (end, _), (start, _) in zip(logged, term_rows, strict=True)}
        # a row only for batches where an episode ended, placed at its batch's first frame
        ended_rows = [(first_frame[end], count) for end, count in read_scalar(run_dir, "episodes")]
        cells = []
        for start, value in bin_means(term_rows, args.bin).items():
            batches = sum(1 for frames, _ in term_rows if start <= frames < start + args.bin)
            ended = sum(count for frames, count in ended_rows if start <= frames < start + args.bin)
            span = f"{start / 1e6:g}-{(start + args.bin) / 1e6:g}M"  # the bin [start, start + width)
            cells.append(f"{span}: {value * scale:5.2f} eps/batch {ended / batches:4.1f}")
        print(f"{run_dir.name}: " + " | ".join(cells))


if __name__ == "__main__":
    main()
