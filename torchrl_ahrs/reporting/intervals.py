"""Aggregates over seeds with 95 % intervals, from rliable (Agarwal et al., 2021), the field's kept library.

rliable does the statistics: the interquartile mean and the mean with stratified-bootstrap percentile
intervals (``rliable.library.get_interval_estimates``), the probability of improvement
``P(X > Y)`` (``rliable.metrics.probability_of_improvement``, the Mann-Whitney statistic, ties count half)
with its interval, and performance profiles (``rliable.library.create_performance_profile``). This module
only shapes one task's per-seed scores ``[S]`` into rliable's ``[runs, tasks]`` arrays and fixes the random
state, so a report is reproducible. What rliable has no function for stays in :mod:`.stats`: a run's final
return, AUC and frames to a threshold (they read one run's curve, not scores across seeds).

Example:
    >>> import numpy as np
    >>> iqm, low, high = iqm_interval(np.array([1.0, 2.0, 3.0, 4.0, 100.0, 5.0, 6.0, 7.0]), reps=200)
    >>> iqm, low <= iqm <= high
    (4.5, True)
    >>> p, low, high = improvement_probability(np.array([5.0, 6.0, 7.0]), np.array([1.0, 2.0, 3.0]), reps=200)
    >>> p, low, high
    (1.0, 1.0, 1.0)
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

REPS = 5_000  # bootstrap resamples (rliable's default is 50 000; 5 000 keeps a 100-run report under a minute)
CONFIDENCE = 0.95


def _rliable():
    from rliable import library, metrics  # type: ignore[import-untyped]  # imported on use: the report is the only user of rliable

    return library, metrics


def _quiet(call: Callable[[], Any]) -> Any:
    """Runs an rliable call without arch's FutureWarning about ``random_state`` (rliable 1.2 passes one; the
    warning is about arch's next major version, which rliable does not admit)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="random_state is deprecated", category=FutureWarning)
        return call()


def _interval(
    values: np.ndarray | Sequence[float], func: Callable[..., np.ndarray], reps: int, seed: int
) -> tuple[float, float, float]:
    """``func`` of one task's scores ``[S]`` with rliable's stratified-bootstrap percentile interval."""
    scores = np.asarray(values, dtype=float)
    scores = scores[np.isfinite(scores)]
    if scores.size == 0:
        return math.nan, math.nan, math.nan
    point = float(func(scores[:, None]))  # rliable scores: [runs, tasks] = [S, 1]
    if scores.size == 1:  # nothing to resample
        return point, point, point
    library, _ = _rliable()
    _, intervals = _quiet(lambda: library.get_interval_estimates(
        {"x": scores[:, None]}, func, reps=reps, confidence_interval_size=CONFIDENCE,
        random_state=np.random.RandomState(seed),
    ))  # fmt: skip
    low, high = intervals["x"].reshape(-1)[:2]
    return point, float(low), float(high)


def iqm_interval(scores: np.ndarray | Sequence[float], reps: int = REPS, seed: int = 0) -> tuple[float, float, float]:
    """Interquartile mean of per-seed scores ``[S]`` (the mean of the middle half) and its 95 % interval."""
    _, metrics = _rliable()
    return _interval(scores, metrics.aggregate_iqm, reps, seed)


def mean_interval(scores: np.ndarray | Sequence[float], reps: int = REPS, seed: int = 0) -> tuple[float, float, float]:
    """Mean of per-seed scores ``[S]`` and its 95 % stratified-bootstrap interval."""
    _, metrics = _rliable()
    return _interval(scores, metrics.aggregate_mean, reps, seed)


def improvement_probability(
    x: np.ndarray, y: np.ndarray, reps: int = REPS, seed: int = 0
) -> tuple[float, float, float]:
    """``P(X > Y)``: the probability that a run of arm X scores above a run of arm Y (ties count half),
    with its 95 % interval; NaN when either arm has no finished run."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    x, y = x[np.isfinite(x)], y[np.isfinite(y)]
    if x.size == 0 or y.size == 0:
        return math.nan, math.nan, math.nan
    library, metrics = _rliable()
    pair = {"x,y": (x[:, None], y[:, None])}
    points, intervals = _quiet(lambda: library.get_interval_estimates(
        pair, metrics.probability_of_improvement, reps=reps, confidence_interval_size=CONFIDENCE,
        random_state=np.random.RandomState(seed),
    ))  # fmt: skip
    low, high = intervals["x,y"].reshape(-1)[:2]
    return float(np.asarray(points["x,y"]).reshape(-1)[0]), float(low), float(high)


def performance_profiles(
    scores: Mapping[str, np.ndarray], taus: np.ndarray, reps: int = 2_000
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Score distributions ``P(score > tau)`` over ``taus [T]`` per arm (rliable's performance profile) and
    their 95 % intervals ``[2, T]``; arms without a finished run are left out."""
    library, _ = _rliable()
    arrays = {name: np.asarray(v, float)[np.isfinite(np.asarray(v, float))][:, None] for name, v in scores.items()}
    arrays = {name: v for name, v in arrays.items() if v.size}
    if not arrays:
        return {}, {}
    return _quiet(lambda: library.create_performance_profile(arrays, taus, reps=reps))
