"""Sweep reports: read the run directories of a sweep, compute the paper-style tables (final return
mean ± std over seeds, bootstrap CI, IQM, change against PPO) and draw the figures.

``runs`` reads directories, ``stats`` holds the pure statistics, ``tables`` the table rows and Markdown,
``figures`` the PNGs; ``python -m torchrl_ahrs.report <sweep dir>`` puts them together.
"""

from torchrl_ahrs.reporting.runs import Run, load_run, load_sweep
from torchrl_ahrs.reporting.stats import bootstrap_ci, change_percent, final_return, interquartile_mean, mean_std

__all__ = [
    "Run",
    "bootstrap_ci",
    "change_percent",
    "final_return",
    "interquartile_mean",
    "load_run",
    "load_sweep",
    "mean_std",
]
