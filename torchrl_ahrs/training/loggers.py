"""One TorchRL logger that writes to several backends (CSV, TensorBoard, wandb, mlflow).

The CSV files start with a ``step,value`` header (:class:`HeaderCSVLogger`; TorchRL's ``CSVLogger`` writes
none); :meth:`FanoutLogger.log_run_config` gives TensorBoard the run's hyperparameters (its HParams tab) and
its config as text, wandb and mlflow the hyperparameters.
"""

from __future__ import annotations

import importlib.util
import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml
from torchrl.record.loggers import Logger, get_logger
from torchrl.record.loggers.csv import CSVExperiment, CSVLogger
from torchrl.record.loggers.tensorboard import TensorboardLogger

log = logging.getLogger(__name__)

BACKENDS = ("csv", "tensorboard", "wandb", "mlflow")
_PACKAGES = {"tensorboard": "tensorboard", "wandb": "wandb", "mlflow": "mlflow"}
CSV_HEADER = "step,value"
# the HParams tab compares runs on these scalars (logged every iteration under the same tags)
HPARAM_METRICS = ("return/total", "reward/total")


class _HeaderCSVExperiment(CSVExperiment):
    """TorchRL's CSV experiment, with a ``step,value`` header on every file it starts (a file that already has
    rows, a resumed run's, is appended to as it is)."""

    def add_scalar(self, name: str, value: float, global_step: int | None = None):
        path = os.path.join(self.log_dir, "scalars", f"{name}.csv")
        if path not in self.files:
            os.makedirs(os.path.dirname(path), exist_ok=True)
            starting = not os.path.isfile(path) or os.path.getsize(path) == 0
            self.files[path] = open(path, "a+")  # noqa: SIM115  (closed by CSVExperiment.__del__, as TorchRL's)
            if starting:
                self.files[path].write(CSV_HEADER + "\n")
        super().add_scalar(name, value, global_step)


class HeaderCSVLogger(CSVLogger):
    """TorchRL's :class:`~torchrl.record.loggers.CSVLogger` writing ``<log_dir>/<exp>/scalars/<name>.csv`` with a
    ``step,value`` header row.

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> logger = HeaderCSVLogger("metrics", log_dir=tempfile.mkdtemp())
        >>> logger.log_scalar("return/total", 1.5, step=64)
        >>> (Path(logger.log_dir) / "metrics/scalars/return/total.csv").read_text()
        'step,value\\n64,1.5\\n'
    """

    def _create_experiment(self) -> CSVExperiment:
        return _HeaderCSVExperiment(os.path.join(self.log_dir, self.exp_name), video_format=self.video_format)


def flat_hparams(config: Mapping[str, Any], prefix: str = "") -> dict[str, bool | int | float | str]:
    """``{"trainer.lr": 3e-4, ...}``: a nested config as the flat scalar values TensorBoard's HParams take
    (lists and None as their text).

    Example:
        >>> flat_hparams({"trainer": {"lr": 3e-4, "sizes": [64, 64]}, "seed": 1, "aux": None})
        {'trainer.lr': 0.0003, 'trainer.sizes': '[64, 64]', 'seed': 1, 'aux': 'None'}
    """
    flat: dict[str, bool | int | float | str] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flat_hparams(value, f"{name}."))
        else:
            flat[name] = value if isinstance(value, bool | int | float | str) else str(value)
    return flat


class FanoutLogger(Logger):
    """Forwards every call to each wrapped TorchRL logger.

    Example:
        >>> import tempfile
        >>> logger = build_logger(["csv"], tempfile.mkdtemp(), "demo")
        >>> logger.log_scalar("return/total", 1.5, step=0)
    """

    def __init__(self, loggers: Sequence[Logger], exp_name: str = "torchrl_ahrs"):
        self.loggers = list(loggers)
        super().__init__(exp_name=exp_name, log_dir="")

    def _create_experiment(self):
        return None

    def log_scalar(self, name: str, value: float, step: int | None = None) -> None:
        for logger in self.loggers:
            logger.log_scalar(name, value, step=step)

    def close(self) -> None:
        """Flushes and closes every backend that holds a writer (TensorBoard's event file thread)."""
        for logger in self.loggers:
            close = getattr(getattr(logger, "experiment", None), "close", None)
            if callable(close):
                close()

    def log_video(self, name: str, video, step: int | None = None, **kwargs) -> None:
        for logger in self.loggers:
            logger.log_video(name, video, step=step, **kwargs)

    def log_hparams(self, cfg) -> None:
        for logger in self.loggers:
            logger.log_hparams(cfg)

    def log_histogram(self, name: str, data, **kwargs) -> None:
        for logger in self.loggers:
            logger.log_histogram(name, data, **kwargs)

    def log_run_config(self, config_text: str) -> None:
        """The run's config, ``config_text`` (the YAML of ``config.yaml``, secrets redacted): TensorBoard gets its
        flat hyperparameters, compared on :data:`HPARAM_METRICS`, and the text under the tag ``config``; wandb
        and mlflow get the hyperparameters; CSV nothing (``config.yaml`` is in the run directory)."""
        hparams = flat_hparams(yaml.safe_load(config_text) or {})
        for logger in self.loggers:
            if isinstance(logger, TensorboardLogger):
                from torch.utils.tensorboard.summary import hparams as hparam_summaries

                writer = logger.experiment
                # written into the run's own event file (SummaryWriter.add_hparams would open a new one per call)
                for summary in hparam_summaries(hparams, {name: 0.0 for name in HPARAM_METRICS}):
                    writer.file_writer.add_summary(summary)
                indented = "\n".join("    " + line for line in config_text.splitlines())  # Markdown code block
                writer.add_text("config", indented, global_step=0)
                writer.flush()
            elif not isinstance(logger, CSVLogger):
                logger.log_hparams(hparams)

    def __repr__(self) -> str:
        return f"FanoutLogger({self.loggers})"


def build_logger(backends: Sequence[str], run_dir: str | Path, exp_name: str) -> FanoutLogger:
    """Loggers writing under ``run_dir``: ``csv`` → ``run_dir/<exp>/scalars/*.csv``, ``tensorboard`` →
    ``run_dir/<exp>/events*``. wandb and mlflow are used when installed and skipped with a warning
    otherwise; an unknown name is an error listing the accepted ones."""
    unknown = [name for name in backends if name not in BACKENDS]
    if unknown:
        raise ValueError(f"unknown logger backend(s) {unknown}; accepted: {', '.join(BACKENDS)}")
    loggers = []
    for name in backends:
        package = _PACKAGES.get(name)
        if package and importlib.util.find_spec(package) is None:
            log.warning("logger %s skipped: package %r is not installed", name, package)
            continue
        if name == "csv":
            loggers.append(HeaderCSVLogger(exp_name, log_dir=str(run_dir)))
        else:
            loggers.append(get_logger(name, logger_name=str(run_dir), experiment_name=exp_name))
    return FanoutLogger(loggers, exp_name=exp_name)
