"""PNG figures of a sweep (matplotlib, Agg backend): learning curves, weight and rule timelines,
per-component final returns. Every function writes one file and returns its path."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display on a server or in CI
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from torchrl_ahrs.reporting.intervals import performance_profiles  # noqa: E402
from torchrl_ahrs.reporting.records import Run, method_rank  # noqa: E402
from torchrl_ahrs.reporting.stats import mean_band, mean_std  # noqa: E402


def _by_method(runs: list[Run]) -> dict[str, list[Run]]:
    grouped: dict[str, list[Run]] = defaultdict(list)
    for run in runs:
        grouped[run.method].append(run)
    return dict(sorted(grouped.items(), key=lambda item: method_rank(item[0])))


def _plot_band(axis, grid: np.ndarray, mean: np.ndarray, std: np.ndarray, label: str, alpha: float) -> None:
    """The mean as a line and mean ± std as a band of the line's colour."""
    line = axis.plot(grid, mean, label=label)[0]
    axis.fill_between(grid, mean - std, mean + std, color=line.get_color(), alpha=alpha)


def _finish_axis(axis, fontsize: str) -> None:
    """Light grid; a legend only when something was labelled (matplotlib warns on an empty one)."""
    axis.grid(alpha=0.3)
    if axis.get_legend_handles_labels()[0]:
        axis.legend(fontsize=fontsize)


def _save(figure, path: Path, dpi: int) -> Path:
    figure.tight_layout()
    figure.savefig(path, dpi=dpi)
    plt.close(figure)  # pyplot keeps every open figure alive otherwise
    return path


def learning_curves(task: str, runs: list[Run], path: Path, scalar: str = "return/total") -> Path | None:
    """``scalar`` against frames for one task: per method the mean over its finished seeds (line) and
    ± one std over seeds (band), curves interpolated onto a common frame grid; None without a finished run."""
    finished = [r for r in runs if r.ok and scalar in r.curves]
    if not finished:
        return None
    figure, axis = plt.subplots(figsize=(6.4, 4.0))
    for method, group in _by_method(finished).items():
        grid, mean, std = mean_band([run.curves[scalar] for run in group])
        if grid.size == 0:
            continue
        _plot_band(axis, grid, mean, std, f"{method} (n={len(group)})", alpha=0.2)
    axis.set(title=f"{task}: {scalar} (mean ± std over seeds)", xlabel="frames", ylabel="episode return")
    _finish_axis(axis, "small")
    return _save(figure, path, dpi=90)


def performance_profile(task: str, runs: list[Run], path: Path) -> Path | None:
    """rliable's performance profile of the final return: the fraction of an arm's runs scoring above tau, with
    its 95 % band, for tau across the observed range (one line per arm)."""
    finals = {m: np.array([r.final_return for r in g if r.ok]) for m, g in _by_method(runs).items()}
    finals = {m: v[np.isfinite(v)] for m, v in finals.items() if np.isfinite(v).any()}
    if not finals:
        return None
    pooled = np.concatenate(list(finals.values()))
    taus = np.linspace(pooled.min(), pooled.max(), 101)
    profiles, bands = performance_profiles(finals, taus)
    figure, axis = plt.subplots(figsize=(6, 4))
    for method, profile in profiles.items():
        line = axis.plot(taus, profile, label=method)[0]
        axis.fill_between(taus, bands[method][0], bands[method][1], color=line.get_color(), alpha=0.15)
    axis.set_xlabel("final return tau")
    axis.set_ylabel("fraction of runs with final return > tau")
    axis.set_title(f"{task}: performance profiles")
    _finish_axis(axis, "small")
    return _save(figure, path, 120)


def weight_timelines(task: str, runs: list[Run], path: Path, kind: str = "weight") -> Path | None:
    """For each scheduled method (one with ``weight/<c>`` curves and scheduler decisions): the weight of
    every component against frames (mean over seeds, band = std), and below it the rule each seed's
    scheduler applied at each decision (one marker per decision, seeds offset vertically). With
    ``kind="share"``: the effective shares ``share/<c>`` instead of the weights."""
    scheduled = {m: g for m, g in _by_method([r for r in runs if r.scheduled]).items()}
    if not scheduled:
        return None
    figure, axes = plt.subplots(
        2, len(scheduled), figsize=(4.2 * len(scheduled), 5.6), squeeze=False, sharex="col", height_ratios=[2, 1]
    )
    for column, (method, group) in enumerate(scheduled.items()):
        weight_axis, rule_axis = axes[0, column], axes[1, column]
        logged = [name for name in group[0].curves if name.startswith(f"{kind}/")]
        ordered = [f"{kind}/{c}" for c in group[0].components]  # the task's K-axis order first
        components = [n for n in ordered if n in logged] + [n for n in logged if n not in ordered]
        for name in components:
            grid, mean, std = mean_band([run.curves[name] for run in group if name in run.curves])
            if grid.size:
                _plot_band(weight_axis, grid, mean, std, name.split("/", 1)[1], alpha=0.15)
        label = "w_k" if kind == "weight" else "w_k std(A_k) / sum_j w_j std(A_j)"
        weight_axis.set(title=f"{task} / {method}: {kind}s", ylabel=label)
        _finish_axis(weight_axis, "x-small")
        for offset, run in enumerate(sorted(group, key=lambda r: r.seed)):
            applied = [d for d in run.decisions if d.get("applied") and d.get("rule_id") is not None]
            frames = [d["frames"] for d in applied]
            rules = np.asarray([d["rule_id"] for d in applied], dtype=float) + 0.12 * (offset - 1)
            rule_axis.scatter(frames, rules, s=12, label=f"seed {run.seed}")
        rule_axis.set(xlabel="frames", ylabel="rule id")
        _finish_axis(rule_axis, "x-small")
    return _save(figure, path, dpi=80)


def share_timelines(task: str, runs: list[Run], path: Path) -> Path | None:
    """:func:`weight_timelines` of the effective shares ``share/<c>`` (None when no run logs them)."""
    if not any(name.startswith("share/") for run in runs for name in run.curves):
        return None
    return weight_timelines(task, runs, path, kind="share")


def component_returns(task: str, runs: list[Run], path: Path) -> Path | None:
    """Final return of each reward component (mean ± std over finished seeds), one bar per method that
    logs component returns; None when no run does."""
    finished = [r for r in runs if r.ok and r.components]  # PPO (K = 1) logs no component returns
    if not finished:
        return None
    components = max((r.components for r in finished), key=len)
    grouped = _by_method(finished)
    figure, axis = plt.subplots(figsize=(max(6.4, 1.1 * len(components) * len(grouped)), 4.0))
    width = 0.8 / max(len(grouped), 1)
    positions = np.arange(len(components))
    for index, (method, group) in enumerate(grouped.items()):
        stats = [mean_std([r.final.get(f"return/{c}", np.nan) for r in group]) for c in components]
        means = [m for m, _ in stats]
        stds = [0.0 if not np.isfinite(s) else s for _, s in stats]
        axis.bar(positions + index * width, means, width, yerr=stds, label=method, capsize=2)
    axis.set_xticks(positions + 0.4 - width / 2, components, rotation=20)
    axis.set(title=f"{task}: final return per component (mean ± std over seeds)", ylabel="return")
    axis.axhline(0.0, color="black", linewidth=0.6)
    axis.legend(fontsize="small")
    return _save(figure, path, dpi=90)
