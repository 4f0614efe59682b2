"""A trained run's policy, rebuilt from its saved config and checkpoint (:mod:`torchrl_ahrs.app.shared.run_dir`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf
from torchrl.modules import ProbabilisticActor

from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.app.shared.settings import override_task
from torchrl_ahrs.app.train.build import EnvFactory, build_networks, env_factory
from torchrl_ahrs.envs.settings import TaskSettings


class EvaluationError(RuntimeError):
    """A run directory that cannot be evaluated; the message is one line saying why."""


@dataclass
class TrainedPolicy:
    """What an evaluation needs from a run: its config, its environments, the K components and the actor."""

    cfg: DictConfig
    make_envs: EnvFactory
    actor: ProbabilisticActor

    @property
    def components(self) -> list[str]:
        return self.make_envs.components

    @property
    def task(self) -> TaskSettings:
        return self.make_envs.task


def load_policy(run_dir: str | Path, task_overrides: Mapping[str, Any] | None = None) -> TrainedPolicy:
    """Rebuilds the actor of ``run_dir`` (network shapes from its config, weights and observation
    statistics from its checkpoint).

    ``task_overrides`` (nested, like ``{"commands": {"resampling_time_s": 10.0}}``) replaces settings of the
    run's task for this policy's environments only, the way legged_gym's ``play.py`` edits ``env_cfg``
    before it plays a policy: a run trained on a changed task is then measured on the task as defined.
    Each key must already be a setting of the run's task; the run directory is not changed.

    Raises:
        EvaluationError: no such directory, no config, no or unreadable checkpoint, weights that do
            not fit the network the config describes, or an override naming no setting of the task.

    Example:
        >>> load_policy("/nonexistent")
        Traceback (most recent call last):
        ...
        torchrl_ahrs.app.evaluate.policy.EvaluationError: no run directory at /nonexistent
    """
    run = RunDirectory(run_dir)
    if not run.path.is_dir():
        raise EvaluationError(f"no run directory at {run.path}")
    config_path, checkpoint_path = run.config, run.checkpoint
    if not config_path.is_file():
        raise EvaluationError(f"no {config_path.name} in {run.path}: not a training run directory")
    if not checkpoint_path.is_file():
        raise EvaluationError(
            f"no checkpoint at {checkpoint_path}: the run has not reached its first checkpoint "
            "(every checkpoint.interval iterations, and at the end)"
        )
    cfg = OmegaConf.load(config_path)
    if not isinstance(cfg, DictConfig):  # a YAML list would fail below with an unrelated message
        raise EvaluationError(f"{config_path} is not a run configuration (not a mapping)")
    if task_overrides:
        try:
            cfg.task = override_task(cfg.task, task_overrides)
        except ConfigError as error:
            raise EvaluationError(str(error)) from None
    try:
        checkpoint = torch.load(checkpoint_path, map_location="cpu", weights_only=False)
    except Exception as error:  # torch raises many types for a damaged file
        raise EvaluationError(f"cannot read checkpoint {checkpoint_path}: {_one_line(error)}") from error
    if not isinstance(checkpoint, dict) or "actor" not in checkpoint:
        raise EvaluationError(f"checkpoint {checkpoint_path} has no 'actor' entry")

    make_envs = env_factory(cfg, check_aux=False)
    actor = build_networks(cfg, make_envs, with_critic=False).actor
    model = cfg.model
    try:
        actor.load_state_dict(checkpoint["actor"])  # includes the RunningNorm buffers mean, var, count
    except RuntimeError as error:
        raise EvaluationError(
            f"checkpoint {checkpoint_path} does not fit the actor described by {config_path} "
            f"(task {cfg.task.name}, hidden {list(model.hidden_sizes)}): {_one_line(error)}"
        ) from error
    actor.eval()
    return TrainedPolicy(cfg, make_envs, actor)


def _one_line(error: BaseException) -> str:
    text = " ".join(str(error).split())
    return text if len(text) <= 300 else text[:297] + "..."
