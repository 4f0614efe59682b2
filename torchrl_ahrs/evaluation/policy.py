"""A trained run's policy, rebuilt from its ``config.yaml`` and ``checkpoint.pt``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf
from torchrl.modules import ProbabilisticActor

from torchrl_ahrs.config import resolve_components
from torchrl_ahrs.envs.registry import make_env
from torchrl_ahrs.rewards.auxiliary import task_with_auxiliary
from torchrl_ahrs.training.models import RunningNorm, build_actor

CONFIG_FILE = "config.yaml"
CHECKPOINT_FILE = "checkpoint.pt"


class EvaluationError(RuntimeError):
    """A run directory that cannot be evaluated; the message is one line saying why."""


@dataclass
class TrainedPolicy:
    """What an evaluation needs from a run: its config, the task config, the K components and the actor."""

    cfg: DictConfig
    task: dict[str, Any]
    components: list[str]
    actor: ProbabilisticActor


def load_policy(run_dir: str | Path) -> TrainedPolicy:
    """Rebuilds the actor of ``run_dir`` (network shapes from its config, weights and observation
    statistics from its checkpoint).

    Raises:
        EvaluationError: no such directory, no config, no or unreadable checkpoint, or weights that do
            not fit the network the config describes.

    Example:
        >>> load_policy("/nonexistent")
        Traceback (most recent call last):
        ...
        torchrl_ahrs.evaluation.policy.EvaluationError: no run directory at /nonexistent
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise EvaluationError(f"no run directory at {run_dir}")
    config_path, checkpoint_path = run_dir / CONFIG_FILE, run_dir / CHECKPOINT_FILE
    if not config_path.is_file():
        raise EvaluationError(f"no {CONFIG_FILE} in {run_dir}: not a training run directory")
    if not checkpoint_path.is_file():
        raise EvaluationError(
            f"no checkpoint at {checkpoint_path}: the run has not finished or ran with trainer.checkpoint=false"
        )
    cfg = OmegaConf.load(config_path)
    try:
        checkpoint = torch.load(checkpoint_path, map_location="cpu", weights_only=False)
    except Exception as error:  # torch raises many types for a damaged file
        raise EvaluationError(f"cannot read checkpoint {checkpoint_path}: {_one_line(error)}") from error
    if not isinstance(checkpoint, dict) or "actor" not in checkpoint:
        raise EvaluationError(f"checkpoint {checkpoint_path} has no 'actor' entry")

    task = task_with_auxiliary(cfg, check=False)
    components = list(checkpoint.get("components") or resolve_components(cfg))
    probe = make_env(task, 1, int(cfg.seed), components=components)
    obs_dim = probe.observation_spec["observation"].shape[-1]
    action_spec = probe.full_action_spec[probe.action_key]
    probe.close()
    model = cfg.model
    actor = build_actor(
        RunningNorm(obs_dim), obs_dim, action_spec, model.hidden_sizes, model.activation, model.init_log_std
    )
    try:
        actor.load_state_dict(checkpoint["actor"])  # includes the RunningNorm buffers mean, var, count
    except RuntimeError as error:
        raise EvaluationError(
            f"checkpoint {checkpoint_path} does not fit the actor described by {config_path} "
            f"(task {task['name']}, observation {obs_dim}, hidden {list(model.hidden_sizes)}): {_one_line(error)}"
        ) from error
    actor.eval()
    return TrainedPolicy(cfg, task, components, actor)


def _one_line(error: BaseException) -> str:
    text = " ".join(str(error).split())
    return text if len(text) <= 300 else text[:297] + "..."
