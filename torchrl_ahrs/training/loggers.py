"""One TorchRL logger that writes to several backends (CSV, TensorBoard, wandb, mlflow)."""

from __future__ import annotations

import importlib.util
import logging
from collections.abc import Sequence
from pathlib import Path

from torchrl.record.loggers import Logger, get_logger

log = logging.getLogger(__name__)

BACKENDS = ("csv", "tensorboard", "wandb", "mlflow")
_PACKAGES = {"tensorboard": "tensorboard", "wandb": "wandb", "mlflow": "mlflow"}


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
        loggers.append(get_logger(name, logger_name=str(run_dir), experiment_name=exp_name))
    return FanoutLogger(loggers, exp_name=exp_name)
