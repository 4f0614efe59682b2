"""Sweep reports: from the runs of a sweep (read by :mod:`torchrl_ahrs.app.runs`), compute the
paper-style tables (final return mean ± std over seeds, bootstrap CI, IQM, change against PPO) and draw
the figures.

``records`` holds the per-run record, ``stats`` the pure statistics, ``tables`` the table rows and Markdown,
``figures`` the PNGs; ``python -m torchrl_ahrs.report <sweep dir>`` puts them together.
"""

from torchrl_ahrs.reporting.records import Run
from torchrl_ahrs.reporting.stats import bootstrap_ci, change_percent, final_return, interquartile_mean, mean_std

__all__ = [
    "Run",
    "bootstrap_ci",
    "change_percent",
    "final_return",
    "interquartile_mean",
    "mean_std",
]
