"""Arms of evaluated runs side by side: per seed, per arm with intervals, and each pair's probability of improvement.

    python benchmarks/learning/compare_evaluations.py --lower-is-better --bar 0.25 --full-length 1000 \\
        --arm "ppo=benchmarks/results/issue26_probes/cassie_r1[236]_ppo_klactor_s*" \\
        --arm "mcppo=benchmarks/results/issue26_probes/cassie_r1[036]_mcppo_klactor_s*"

Each ``--arm name=pattern[,pattern...]`` names globs of run directories that hold ``evaluation.json`` (or the file
``--evaluation`` names, e.g. ``evaluation_seed4242.json`` for another evaluation seed; written by
``python -m torchrl_ahrs.evaluate run=<dir>``) and ``config.yaml`` (the training seed); quote it, so that the
script, not the shell, expands it and an arm that matches nothing is an error. Printed:

- per run: the training seed, ``--metric`` (a key of the evaluation's ``metrics``, or ``return`` for the total
  evaluated return), the episodes that lasted ``--full-length`` steps, and each ``--terms`` component's
  evaluated return (what the policy collects of it per episode);
- per arm: the metric's mean with its 95 % stratified-bootstrap interval, the runs with a short episode ("fall"),
  with ``--bar``, the runs whose metric is on the right side of the bar with every episode at full length, and with
  ``--stuck term=value``, the runs whose evaluated return of ``term`` is below ``value`` (Cassie's runs that turn on
  the spot instead of walking collect 1-5 of ``tracking_lin_vel``'s 20 per episode, those that walk 12-18);
- per pair of arms: P(a run of the first is better than one of the second) with its 95 % interval (rliable's
  probability of improvement, :func:`torchrl_ahrs.reporting.intervals.improvement_probability`; with
  ``--lower-is-better`` it is computed on the negated metric);
- the same for the training total in the run's last ``--bin`` frames (the native ``reward/total`` per 1 000 steps,
  binned as ``curve_bins.py`` bins it: what the run was collecting by the end, not an evaluation), higher better.

The RESULTS.md Cassie rounds quote these numbers.
"""

from __future__ import annotations

import argparse
import glob
import itertools
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from curve_bins import batch_starts, bin_means, read_scalar

from torchrl_ahrs.reporting.intervals import improvement_probability, mean_interval


@dataclass
class Evaluated:
    """One evaluated run: where it is, its training seed, the metric, episode lengths, component returns and the
    training total of its last frames."""

    run_dir: Path
    seed: int
    metric: float
    lengths: list[float]
    returns: dict[str, float]  # component -> mean evaluated return per episode
    final_total: float  # mean reward/total per 1 000 steps over the batches that start in the last bin


def read_run(run_dir: Path, metric: str, width: int, evaluation_file: str = "evaluation.json") -> Evaluated:
    """Reads ``evaluation_file``, ``config.yaml`` and the ``reward/total`` scalars of one run (``width``: the
    training total's bin); a missing file or metric is a one-line error."""
    evaluation_path, config_path = run_dir / evaluation_file, run_dir / "config.yaml"
    for path in (evaluation_path, config_path):
        if not path.exists():
            raise SystemExit(
                f"error: {path} does not exist (evaluate the run first: python -m torchrl_ahrs.evaluate run={run_dir})"
            )
    evaluation = json.loads(evaluation_path.read_text())
    seed = int(yaml.safe_load(config_path.read_text())["seed"])
    returns = {name: float(stats["mean"]) for name, stats in evaluation["return"].items()}
    if metric == "return":
        value = returns["total"]
    elif metric in evaluation.get("metrics", {}):
        value = float(evaluation["metrics"][metric]["mean"])
    else:
        known = ["return", *sorted(evaluation.get("metrics", {}))]
        raise SystemExit(f"error: {run_dir} has no metric {metric!r}; it has {', '.join(known)}")
    bins = bin_means(batch_starts(read_scalar(run_dir, "reward/total")), width)  # {first frame: mean per step}
    final_total = 1e3 * bins[max(bins)] if bins else float("nan")  # per 1 000 steps, as curve_bins prints it
    lengths = [float(n) for n in evaluation["per_episode"]["length"]]
    return Evaluated(run_dir, seed, value, lengths, returns, final_total)


def parse_arm(text: str) -> tuple[str, list[Path]]:
    """``name=pattern[,pattern...]`` -> the name and the run directories the globs match, sorted by name; a glob
    that matches nothing is an error (a mistyped round would otherwise drop out silently)."""
    name, separator, patterns = text.partition("=")
    if not separator or not name or not patterns:
        raise SystemExit(f"error: --arm takes name=glob[,glob...], got {text!r}")
    runs: set[Path] = set()
    for pattern in patterns.split(","):
        matched = {Path(match) for match in glob.glob(pattern) if Path(match).is_dir()}
        if not matched:
            raise SystemExit(f"error: arm {name!r}: {pattern!r} matches no directory")
        runs |= matched
    return name, sorted(runs)


def parse_stuck(text: str) -> tuple[str, float]:
    """``term=value`` -> the evaluated component and the return below which a run counts as stuck."""
    term, _, value = text.partition("=")
    try:
        below = float(value)
    except ValueError:
        below = math.nan
    if not term or math.isnan(below):
        raise SystemExit(f"error: --stuck takes term=value, e.g. tracking_lin_vel=8, got {text!r}")
    return term, below


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arm", action="append", required=True, help="name=glob[,glob...] of run dirs (repeat)")
    parser.add_argument("--metric", default="lin_vel_error", help="an evaluation metric, or 'return'")
    parser.add_argument("--lower-is-better", action="store_true", help="the metric is an error")
    parser.add_argument("--full-length", type=int, default=1000, help="steps of an episode that did not end early")
    parser.add_argument("--bar", type=float, default=None, help="the metric's target (with every episode full)")
    parser.add_argument("--terms", default="tracking_lin_vel,tracking_ang_vel", help="components to show, comma")
    parser.add_argument("--bin", type=int, default=500_000, help="frames of the last bin of the training total")
    parser.add_argument(
        "--evaluation",
        default="evaluation.json",
        help="the file in each run dir (evaluation_seed4242.json: another seed)",
    )
    parser.add_argument("--stuck", default=None, help="term=value: count the runs whose term's return is below value")
    args = parser.parse_args(argv)
    stuck_term, stuck_below = parse_stuck(args.stuck) if args.stuck is not None else (None, math.nan)
    arms = dict(parse_arm(text) for text in args.arm)
    evaluated = {
        name: [read_run(run, args.metric, args.bin, args.evaluation) for run in runs] for name, runs in arms.items()
    }
    if stuck_term is not None:  # checked before anything is printed
        for run in itertools.chain.from_iterable(evaluated.values()):
            if stuck_term not in run.returns:
                raise SystemExit(f"error: {run.run_dir} has no evaluated return {stuck_term!r} (--stuck)")
    terms = [term for term in args.terms.split(",") if term]
    sign = -1.0 if args.lower_is_better else 1.0

    def meets(run: Evaluated) -> bool:  # the bar, on the metric's right side, with no episode cut short
        full = all(length >= args.full_length for length in run.lengths)
        return full and (run.metric <= args.bar if args.lower_is_better else run.metric >= args.bar)

    header = f"{'arm':<12} {'seed':>4} {args.metric:>14} {'full episodes':>14} {'training total':>14}"
    print(header + "".join(f" {t:>17}" for t in terms))
    for name, runs in evaluated.items():
        for run in sorted(runs, key=lambda r: r.seed):
            full = sum(length >= args.full_length for length in run.lengths)
            cells = "".join(f" {run.returns.get(t, float('nan')):17.2f}" for t in terms)
            episodes = f"{full} of {len(run.lengths)}"
            print(f"{name:<12} {run.seed:>4} {run.metric:>14.3f} {episodes:>14} {run.final_total:14.2f}{cells}")
    print()
    for name, runs in evaluated.items():
        point, low, high = mean_interval(np.array([run.metric for run in runs]))
        falls = sum(any(length < args.full_length for length in run.lengths) for run in runs)
        line = f"{name:<12} mean {point:.3f} [{low:.3f}, {high:.3f}] over {len(runs)} seeds; {falls} fall"
        if args.bar is not None:
            line += f"; {sum(meets(run) for run in runs)} meet the bar ({args.bar:g}, every episode full)"
        if stuck_term is not None:
            stuck = sum(run.returns[stuck_term] < stuck_below for run in runs)
            line += f"; {stuck} stuck ({stuck_term} below {stuck_below:g})"
        print(line)
        point, low, high = mean_interval(np.array([run.final_total for run in runs]))
        print(f"{'':<12} training total, last bin: {point:.2f} [{low:.2f}, {high:.2f}]")
    print()
    for first, second in itertools.combinations(evaluated, 2):
        x = sign * np.array([run.metric for run in evaluated[first]])
        y = sign * np.array([run.metric for run in evaluated[second]])
        point, low, high = improvement_probability(x, y)
        x_total = np.array([run.final_total for run in evaluated[first]])
        y_total = np.array([run.final_total for run in evaluated[second]])
        total, total_low, total_high = improvement_probability(x_total, y_total)
        print(
            f"P({first} better than {second}) = {point:.2f} [{low:.2f}, {high:.2f}] in {args.metric}, "
            f"{total:.2f} [{total_low:.2f}, {total_high:.2f}] in the training total"
        )


if __name__ == "__main__":
    main(sys.argv[1:])
