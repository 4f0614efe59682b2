"""The train command's run: pick the run directory (new, the one ``resume=<run dir>`` names, or a sweep
job's existing one) and train; the command line's checks; the errors that end a run with one line.

Declared as ``python -m torchrl_ahrs.train`` (and, in ``--multirun`` mode, ``python -m torchrl_ahrs.sweep``)
by :func:`~torchrl_ahrs.app.shared.cli.hydra_command` in the root modules.
"""

from __future__ import annotations

from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from torchrl_ahrs.app.shared.config import load_saved_config, refuse_renamed
from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.app.train.iteration import train
from torchrl_ahrs.app.train.preflight import check_command_line
from torchrl_ahrs.rewards.auxiliary import AuxiliaryRewardError

__all__ = ["ERRORS", "check_arguments", "run"]

# a user's mistake or a run that cannot go on: one line on stderr, exit status 2
ERRORS = {
    ConfigError: (2, "{}"),
    FileNotFoundError: (2, "{}"),
    FloatingPointError: (2, "{}"),
    AuxiliaryRewardError: (2, "{}; training stopped, its last state is in the checkpoint"),
}


def check_arguments(arguments: list[str]) -> None:
    """Refuses renamed keys, and keys no shipped config has (with or without ``+``), on the command line
    (Hydra would say "not in struct" in five lines, or accept ``+key`` and store it).

    Example:
        >>> check_arguments(["task=point_reach", "trainer.lr=1e-3"])
    """
    refuse_renamed(argument.split("=", 1)[0] for argument in arguments if "=" in argument)
    check_command_line(arguments)


def run(cfg: DictConfig) -> float:
    """One run; returns its last ``return/total`` (what ``hydra/sweeper=optuna`` maximises, docs/optuna.md)."""
    hydra_cfg = HydraConfig.get()
    run_dir = Path(cfg.resume) if cfg.get("resume") else Path(hydra_cfg.runtime.output_dir)
    # a sweep job whose directory already holds a run continues it (or, finished, skips it): rerunning
    # an interrupted sweep command resumes it where it stopped (its job directories are deterministic)
    directory = RunDirectory(run_dir)
    in_sweep = hydra_cfg.mode == RunMode.MULTIRUN and (directory.checkpoint.is_file() or directory.finished.is_file())
    if cfg.get("resume") or in_sweep:
        cfg = load_saved_config(run_dir, hydra_cfg.overrides.task)
    return train(cfg, run_dir).get("return/total", float("nan"))  # nan: no episode ended (an optuna trial fails)
