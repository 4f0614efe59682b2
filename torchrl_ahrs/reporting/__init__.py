"""Sweep reports: from the runs of a sweep (read by :mod:`torchrl_ahrs.app.train.runs`), compute the
paper-style tables (final return over seeds, IQM and intervals from rliable, probabilities of improvement,
change against PPO) and draw the figures.

``records`` holds the per-run record, ``stats`` the statistics of one run's curve, ``intervals`` the
aggregates over seeds (rliable), ``tables`` the table rows and Markdown, ``figures`` the PNGs;
``python -m torchrl_ahrs.report <sweep dir>`` puts them together.
"""

from torchrl_ahrs.reporting.intervals import improvement_probability, iqm_interval, mean_interval
from torchrl_ahrs.reporting.records import Run
from torchrl_ahrs.reporting.stats import change_percent, final_return, mean_std

__all__ = [
    "Run",
    "change_percent",
    "final_return",
    "improvement_probability",
    "iqm_interval",
    "mean_interval",
    "mean_std",
]
