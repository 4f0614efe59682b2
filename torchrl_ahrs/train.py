"""``python -m torchrl_ahrs.train task=<task> method=<method> [key=value ...]``: train one run.

The iteration itself is :mod:`torchrl_ahrs.app.iteration`; this entry point only composes the Hydra
config, picks the run directory (new, or the one ``resume=<run dir>`` names) and turns configuration
errors into one line on stderr with exit status 2. Any other crash is printed here, with every secret of the
config and the command line replaced by ``<redacted>`` (Hydra's own "Error executing job with overrides"
line would print ``llm.api_key=...`` in clear), and exits with status 1.
"""

# ruff: noqa: E402  (the GL backend must be chosen before the imports below load mujoco)
from __future__ import annotations

from torchrl_ahrs.evaluation.render import select_gl_backend

select_gl_backend()  # MuJoCo reads MUJOCO_GL once, at import: choose offscreen GL before anything imports it

import os
import sys
import traceback
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from torchrl_ahrs.app.config import ConfigError, load_saved_config, refuse_renamed
from torchrl_ahrs.app.iteration import train
from torchrl_ahrs.app.preflight import check_command_line
from torchrl_ahrs.app.redaction import secret_values
from torchrl_ahrs.app.run_dir import REDACTED, RunDirectory
from torchrl_ahrs.rewards.auxiliary import AuxiliaryRewardError

__all__ = ["main", "redact", "train"]


class _RedactingStream:
    """A text stream that replaces each of ``secrets`` before writing: Hydra's own messages (a composition error
    quotes the override, ``+llm.api_key=sk-...``) are printed before any of our code could catch them."""

    def __init__(self, stream: Any, secrets: set[str]):
        self.stream, self.secrets = stream, sorted(secrets, key=len, reverse=True)

    def write(self, text: str) -> int:
        for secret in self.secrets:
            text = text.replace(secret, REDACTED)
        return self.stream.write(text)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


def main() -> None:
    """Refuses renamed keys, and keys no shipped config has (with or without ``+``), on the command line
    (Hydra would say "not in struct" in five lines, or accept ``+key`` and store it), then runs."""
    secrets = secret_values({}, sys.argv[1:])
    if secrets:  # every line this process prints, Hydra's included, without the command line's secrets
        sys.stdout, sys.stderr = _RedactingStream(sys.stdout, secrets), _RedactingStream(sys.stderr, secrets)
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
        print(f"error: {redact(str(error), cfg)}", file=sys.stderr)
        sys.exit(2)
    except AuxiliaryRewardError as error:
        print(
            f"error: {redact(str(error), cfg)}; training stopped, its last state is in the checkpoint", file=sys.stderr
        )
        sys.exit(2)
    except Exception:  # noqa: BLE001 (printed here, redacted, instead of by Hydra with the overrides in clear)
        print(redact(traceback.format_exc(), cfg), file=sys.stderr)
        sys.exit(1)


def redact(text: str, cfg: DictConfig) -> str:
    """``text`` with every secret of ``cfg``, the command line and credential-like environment variables replaced.

    Example:
        >>> from omegaconf import OmegaConf
        >>> redact("key sk-abcdef failed", OmegaConf.create({"llm": {"api_key": "sk-abcdef"}}))
        'key <redacted> failed'
    """
    secrets = secret_values(cfg, sys.argv[1:])
    secrets |= {
        value
        for name, value in os.environ.items()
        if any(mark in name.upper() for mark in ("KEY", "TOKEN", "SECRET", "PASSWORD")) and len(value) > 7
    }
    for secret in sorted(secrets, key=len, reverse=True):
        text = text.replace(secret, REDACTED)
    return text


if __name__ == "__main__":
    main()
