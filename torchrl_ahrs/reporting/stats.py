"""Statistics of one run's curve (final return, AUC, frames to a threshold) and plain mean ± std over seeds.

Intervals, IQMs and probabilities of improvement come from rliable (:mod:`.intervals`). Pure functions on
1-D arrays; nothing here reads files. "Final return" of a run is defined once, in
:func:`final_return`, and used by every table and test.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

FINAL_WINDOW = 0.1  # the last 10 % of the frame budget


def final_window_mask(steps: np.ndarray, total_frames: float, window: float = FINAL_WINDOW) -> np.ndarray:
    """Which logged rows fall in the final window of the run: ``step > (1 - window) * total_frames``.

    Args:
        steps: frames at which each row was logged, shape [R].
        total_frames: the run's frame budget (``trainer.total_frames``).

    Example:
        >>> final_window_mask(np.array([100, 900, 950, 1000]), 1000).tolist()
        [False, False, True, True]
    """
    return np.asarray(steps, dtype=float) > (1.0 - window) * float(total_frames)  # step > 0.9 F


def final_return(steps: np.ndarray, values: np.ndarray, total_frames: float, window: float = FINAL_WINDOW) -> float:
    """The final return of one run: mean of the logged ``return/total`` rows with
    ``step > (1 - window) * total_frames`` (default: the last 10 % of the frame budget).

    Each row is the mean native return of the episodes that finished in one training iteration, so this
    averages the last ~10 % of iterations. NaN when no row lies in the window (the run is then reported
    as "too few metric rows", never silently dropped).

    Args:
        steps: frames at which each row was logged, shape [R].
        values: the logged returns, shape [R].
        total_frames: the run's frame budget.

    Example:
        >>> final_return(np.array([500, 950, 1000]), np.array([1.0, 2.0, 4.0]), 1000)
        3.0
    """
    in_window = final_window_mask(steps, total_frames, window)
    if not in_window.any():
        return math.nan
    return float(np.mean(np.asarray(values, dtype=float)[in_window]))  # (1/|W|) Σ_{r ∈ W} R_r


def mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (ddof = 1, NaN for a single value) over seeds.

    Example:
        >>> mean_std([1.0, 2.0, 3.0])
        (2.0, 1.0)
    """
    x = np.asarray(values, dtype=float)
    if x.size == 0:
        return math.nan, math.nan
    std = float(np.std(x, ddof=1)) if x.size > 1 else math.nan  # sqrt(Σ (x - x̄)² / (n - 1))
    return float(np.mean(x)), std


def change_percent(value: float, baseline: float) -> float:
    """Change of ``value`` against ``baseline`` in percent of |baseline| (sign = better/worse for returns
    that can be negative): 100 (value - baseline) / |baseline|. NaN for a zero or missing baseline.

    Example:
        >>> change_percent(-50.0, -100.0)
        50.0
    """
    if not math.isfinite(baseline) or baseline == 0.0 or not math.isfinite(value):
        return math.nan
    return 100.0 * (value - baseline) / abs(baseline)  # Δ% = 100 (m - b) / |b|


def mean_band(curves: Sequence[tuple[np.ndarray, np.ndarray]], points: int = 100) -> tuple[np.ndarray, ...]:
    """Mean and std over seeds of learning curves logged at different steps.

    Each curve (steps [R_i], values [R_i]) is linearly interpolated onto a common grid of ``points``
    frames spanning the range every curve covers (latest first step to earliest last step).

    Returns:
        (grid [P], mean [P], std [P]); std is 0 for a single curve. Empty arrays when the curves do not
        overlap.

    Example:
        >>> grid, mean, std = mean_band([(np.array([0, 10]), np.array([0.0, 10.0])),
        ...                              (np.array([0, 10]), np.array([2.0, 12.0]))], points=3)
        >>> mean.tolist(), std.tolist()
        ([1.0, 6.0, 11.0], [1.0, 1.0, 1.0])
    """
    curves = [(np.asarray(s, float), np.asarray(v, float)) for s, v in curves if len(s) > 0]
    if not curves:
        return np.array([]), np.array([]), np.array([])
    start = max(float(s[0]) for s, _ in curves)
    stop = min(float(s[-1]) for s, _ in curves)
    if stop < start:
        return np.array([]), np.array([]), np.array([])
    grid = np.linspace(start, stop, points if stop > start else 1)
    stacked = np.stack([np.interp(grid, s, v) for s, v in curves])  # [S, P]
    return grid, stacked.mean(axis=0), stacked.std(axis=0)  # population std over seeds (band only)


def normalised_auc(steps: np.ndarray, values: np.ndarray) -> float:
    """Area under a learning curve divided by the frames it spans: the run's average return over
    training (trapezoids between logged rows; higher = learnt sooner and/or better). NaN without rows.

    Example:
        >>> normalised_auc(np.array([0.0, 10.0]), np.array([0.0, 2.0]))
        1.0
    """
    steps, values = np.asarray(steps, float), np.asarray(values, float)
    if steps.size == 0:
        return math.nan
    if steps.size == 1:
        return float(values[0])
    area = float(np.sum(np.diff(steps) * (values[1:] + values[:-1]) / 2.0))  # sum_i (s_i+1 - s_i)(v_i + v_i+1)/2
    return area / float(steps[-1] - steps[0])  # AUC / span


def frames_to_threshold(steps: np.ndarray, values: np.ndarray, threshold: float, smooth: int = 5) -> float:
    """First frame at which the running mean of the last ``smooth`` rows reaches ``threshold``; NaN if never.

    Example:
        >>> frames_to_threshold(np.array([1, 2, 3, 4]), np.array([0.0, 5.0, 9.0, 9.0]), 8.0, smooth=1)
        3.0
    """
    steps, values = np.asarray(steps, float), np.asarray(values, float)
    for index in range(values.size):
        window = values[max(0, index - smooth + 1) : index + 1]
        if window.mean() >= threshold:  # (1/w) sum of the last w rows >= threshold
            return float(steps[index])
    return math.nan


def movement_and_noise(runs_shares: Sequence[tuple[np.ndarray, np.ndarray, Sequence[float]]]) -> tuple[float, float]:
    """How far a component's share moves between decisions, against its seed-to-seed noise.

    Args:
        runs_shares: one entry per seed: (steps [R], shares [R], decision frames).

    Returns:
        (movement, noise): movement = mean over seeds of (max - min) of the per-period mean share
        (periods = the intervals between decisions); noise = mean over a common grid of the std of the
        share across seeds. NaN when undefined.

    Example:
        >>> steps = np.arange(1.0, 9.0)
        >>> a = (steps, np.array([0.1] * 4 + [0.5] * 4), [4.0])
        >>> b = (steps, np.array([0.1] * 4 + [0.5] * 4), [4.0])
        >>> movement_and_noise([a, b])
        (0.4, 0.0)
    """
    movements = []
    for steps, shares, decisions in runs_shares:
        edges = [-math.inf, *sorted(decisions), math.inf]
        means = [shares[(steps > lo) & (steps <= hi)].mean() for lo, hi in zip(edges[:-1], edges[1:], strict=True)
                 if ((steps > lo) & (steps <= hi)).any()]  # fmt: skip
        if len(means) > 1:
            movements.append(max(means) - min(means))  # range of period means
    movement = float(np.mean(movements)) if movements else math.nan
    if len(runs_shares) < 2:
        return round(movement, 12), math.nan
    _, _, std = mean_band([(steps, shares) for steps, shares, _ in runs_shares])
    noise = float(std.mean()) if std.size else math.nan  # mean over the grid of std over seeds
    return round(movement, 12), round(noise, 12)
