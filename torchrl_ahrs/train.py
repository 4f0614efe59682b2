"""``python -m torchrl_ahrs.train task=<task> method=<method> [key=value ...]``: train one run.

The iteration itself is :mod:`torchrl_ahrs.app.iteration`; this entry point only composes the Hydra
config, picks the run directory (new, or the one ``resume=<run dir>`` names) and turns configuration
errors into one line on stderr with exit status 2.
"""

# ruff: noqa: E402  (the GL backend must be chosen before the imports below load mujoco)
from __future__ import annotations

from torchrl_ahrs.evaluation.render import select_gl_backend

select_gl_backend()  # MuJoCo reads MUJOCO_GL once, at import: choose offscreen GL before anything imports it

import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from torchrl_ahrs.app.config import ConfigError, load_saved_config, refuse_renamed
from torchrl_ahrs.app.iteration import train
from torchrl_ahrs.app.preflight import check_command_line
from torchrl_ahrs.app.run_dir import RunDirectory

__all__ = ["main", "train"]


def main() -> None:
    """Refuses renamed keys, and keys no shipped config has (with or without ``+``), on the command line
    (Hydra would say "not in struct" in five lines, or accept ``+key`` and store it), then runs."""
    try:
        refuse_renamed(argument.split("=", 1)[0] for argument in sys.argv[1:] if "=" in argument)
        check_command_line(sys.argv[1:])
    except ConfigError as error:
        print(f"error: {error}", file=sys.stderr)
        sys.exit(2)
    hydra_main()


@hydra.main(config_path="pkg://torchrl_ahrs.conf", config_name="config", version_base="1.3")
def hydra_main(cfg: DictConfig) -> float:
    """One run; returns its last ``return/total`` (what ``hydra/sweeper=optuna`` maximises, docs/optuna.md)."""
    try:
        hydra_cfg = HydraConfig.get()
        run_dir = Path(cfg.resume) if cfg.get("resume") else Path(hydra_cfg.runtime.output_dir)
        # a sweep job whose directory already holds a run continues it (or, finished, skips it): rerunning
        # an interrupted sweep command resumes it where it stopped (its job directories are deterministic)
        directory = RunDirectory(run_dir)
        in_sweep = hydra_cfg.mode == RunMode.MULTIRUN and (
            directory.checkpoint.is_file() or directory.finished.is_file()
        )
        if cfg.get("resume") or in_sweep:
            cfg = load_saved_config(run_dir, hydra_cfg.overrides.task)
        return train(cfg, run_dir).get("return/total", float("nan"))  # nan: no episode ended (an optuna trial fails)
    except (ConfigError, FileNotFoundError, FloatingPointError) as error:
        print(f"error: {error}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
