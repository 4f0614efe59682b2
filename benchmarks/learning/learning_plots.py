"""Learning-curve figures of ``learning.py``: smoothed training return against wall time or frames, one line per peer."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display on a server or in CI
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

GRID_POINTS = 200


def seed_band(xs: list[np.ndarray], ys: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Seeds' curves on one grid ``[G]``: (grid, mean, min, max), each seed interpolated inside its own range.

    Example:
        >>> grid, mean, low, high = seed_band([np.array([0.0, 2.0]), np.array([0.0, 1.0])],
        ...                                   [np.array([0.0, 2.0]), np.array([2.0, 4.0])])
        >>> float(mean[0]), float(low[0]), float(high[0]), bool(np.isnan(mean[-1]))
        (1.0, 0.0, 2.0, False)
    """
    grid = np.linspace(0.0, max(float(x.max()) for x in xs), GRID_POINTS)
    stacked = np.stack([np.interp(grid, x, y, left=np.nan, right=np.nan) for x, y in zip(xs, ys, strict=True)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-nan columns: grid points beyond every seed's range
        return grid, np.nanmean(stacked, 0), np.nanmin(stacked, 0), np.nanmax(stacked, 0)


def plot_curves(runs, smooth: dict, axis: str, path: Path, title: str) -> Path:
    """Writes ``path``: per peer the mean over seeds of the smoothed training return against ``axis``
    (``"wall"``, minutes, or ``"frames"``), with a min..max band when there are several seeds."""
    figure, ax = plt.subplots(figsize=(7, 4.5))
    for peer in dict.fromkeys(run.peer for run in runs):
        xs, ys = [], []
        for run in (r for r in runs if r.peer == peer):
            points = [
                (wall / 60 if axis == "wall" else frames, value)
                for (wall, frames, _, _), value in zip(run.curve, smooth[(run.peer, run.seed)], strict=True)
                if math.isfinite(value)
            ]
            if len(points) >= 2:
                x, y = np.array(points).T
                xs.append(x)
                ys.append(y)
        if not xs:
            continue
        grid, mean, low, high = seed_band(xs, ys)
        (line,) = ax.plot(grid, mean, label=f"{peer} ({len(xs)} seed{'s' if len(xs) > 1 else ''})")
        if len(xs) > 1:
            ax.fill_between(grid, low, high, color=line.get_color(), alpha=0.2, linewidth=0)
    ax.set_xlabel("wall time (min)" if axis == "wall" else "frames")
    ax.set_ylabel("training return (smoothed)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
