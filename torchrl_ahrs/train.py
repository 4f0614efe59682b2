"""Hybrid-reward PPO training: ``python -m torchrl_ahrs.train task=<task> method=<method>``.

The whole algorithm, in the order it runs::

    env        = make_env(task)                   reward split into ("reward", c) leaves, c = 1..K
    actor      = TanhNormal policy                critic = K-head MLP  (one value per component)
    estimator  = WeightedMultiGAE(components)     A_k per component, A = Σ_k w_k A_k
    loss       = ClipPPOLoss on A, critic regressed on all K value targets
    trainer    = torchrl Trainer(Collector, Adam) + hooks:
                   PPOMinibatches     advantage recomputed each epoch, shuffled minibatches
                   RuleScheduler      every `scheduler.interval` iterations: stats -> rule -> w
                   ObservationNorm    running mean/var updated after each update
                   LinearLRDecay, UpdateWeights, ComponentReturnLog
    run dir    = config.yaml (resolved, no secrets), CSV + TensorBoard metrics, checkpoint.pt
                 (written atomically every `checkpoint.interval` iterations; `resume=<run dir>` continues)

PPO is this loop with K = 1 on ("reward", "total"); HD-PPO and the AHRS variants differ only in the
components and the selector that sets ``w``.
"""

# ruff: noqa: E402  (the GL backend must be chosen before the imports below load mujoco)
from __future__ import annotations

from torchrl_ahrs.evaluation.render import select_gl_backend

select_gl_backend()  # MuJoCo reads MUJOCO_GL once, at import: choose offscreen GL before anything imports it

import logging
import sys
from pathlib import Path
from typing import Any

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig
from torchrl.collectors import Collector, MultiAsyncCollector, MultiSyncCollector
from torchrl.trainers import Trainer, UpdateWeights

from torchrl_ahrs.config import ConfigError, load_saved_config, resolve_components, save_config, validate_config
from torchrl_ahrs.envs.registry import make_env
from torchrl_ahrs.rewards.auxiliary import task_with_auxiliary
from torchrl_ahrs.scheduling import build_scheduler
from torchrl_ahrs.scheduling.scheduler import DECISIONS_FILE
from torchrl_ahrs.training.checkpoint import (
    CHECKPOINT_FILE,
    CheckpointHook,
    load_checkpoint,
    rng_state,
    set_rng_state,
    truncate_jsonl,
    truncate_metrics,
)
from torchrl_ahrs.training.hooks import (
    ComponentReturnLog,
    FiniteGuard,
    LinearLRDecay,
    ObservationNormUpdate,
    PPOMinibatches,
    loss_metrics,
)
from torchrl_ahrs.training.kl_schedule import AdaptiveKLLR
from torchrl_ahrs.training.loggers import build_logger
from torchrl_ahrs.training.loss import HybridClipPPOLoss
from torchrl_ahrs.training.models import RunningNorm, build_actor, build_critic
from torchrl_ahrs.training.value_norm import ValueTargetNormalization, denormalized_critic, make_value_norm
from torchrl_ahrs.training.video import register_video_log
from torchrl_ahrs.value import WeightedMultiGAE

log = logging.getLogger("torchrl_ahrs.train")


def make_collector(cfg: DictConfig, policy, components: list[str], remaining_frames: int):
    """``sync``: the envs step in this process between updates. ``multi``: ``workers`` processes each
    step ``num_envs / workers`` envs, all waiting for the update. ``async``: the worker processes keep
    collecting while the learner updates (each iteration trains on one worker's batch of
    ``num_envs / workers × rollout_steps`` frames, gathered with the previous iteration's policy)."""
    trainer_cfg = cfg.trainer
    frames_per_batch = trainer_cfg.num_envs * trainer_cfg.rollout_steps
    task = task_with_auxiliary(cfg, check=False)  # checked once in train()
    if trainer_cfg.collector == "sync":
        env = make_env(task, trainer_cfg.num_envs, cfg.seed, components=components)
        return Collector(
            env,
            policy,
            frames_per_batch=frames_per_batch,
            total_frames=remaining_frames,
            auto_register_policy_transforms=False,
        )
    envs_per_worker = trainer_cfg.num_envs // trainer_cfg.workers
    env_fns = [
        _EnvFactory(task, envs_per_worker, cfg.seed + 1000 * worker, components)
        for worker in range(trainer_cfg.workers)
    ]
    if trainer_cfg.collector == "async":
        return MultiAsyncCollector(
            env_fns, policy, frames_per_batch=envs_per_worker * trainer_cfg.rollout_steps, total_frames=remaining_frames
        )
    return MultiSyncCollector(
        env_fns, policy, frames_per_batch=frames_per_batch, total_frames=remaining_frames, cat_results=0
    )


class _EnvFactory:
    """Picklable env constructor for collector worker processes."""

    def __init__(self, task: dict, num_envs: int, seed: int, components: list[str]):
        self.task, self.num_envs, self.seed, self.components = task, num_envs, seed, components

    def __call__(self):
        return make_env(self.task, self.num_envs, self.seed, components=self.components)


def train(cfg: DictConfig, run_dir: Path) -> dict[str, Any]:
    """Runs one training job (or continues it, when ``run_dir`` holds a checkpoint and ``cfg.resume``
    names it) and returns the last logged metrics."""
    validate_config(cfg)
    run_dir.mkdir(parents=True, exist_ok=True)
    resumed = load_checkpoint(run_dir) if cfg.get("resume") else None
    if resumed is None:
        save_config(cfg, run_dir / "config.yaml")
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.trainer.torch_threads)
    components = resolve_components(cfg)
    task = task_with_auxiliary(cfg)  # + the sandbox-checked auxiliary reward when the method uses one
    log.info("task %s, method %s, K=%d components %s", task["name"], cfg.method.name, len(components), components)

    # --- networks: shapes from a one-env probe of the task -----------------------------------------
    probe = make_env(task, 1, cfg.seed, components=components)
    obs_dim = probe.observation_spec["observation"].shape[-1]
    critic_key = task.get("critic_observation") or "observation"  # e.g. privileged_state: asymmetric actor-critic
    if critic_key not in probe.observation_spec.keys():
        raise ConfigError(f"task.critic_observation={critic_key!r} is not an observation of task {task['name']!r}")
    critic_obs_dim = probe.observation_spec[critic_key].shape[-1]
    action_spec = probe.full_action_spec[probe.action_key]
    probe.close()
    model = cfg.model
    obs_norm = RunningNorm(obs_dim)
    critic_norm = obs_norm if critic_key == "observation" else RunningNorm(critic_obs_dim)
    actor = build_actor(obs_norm, obs_dim, action_spec, model.hidden_sizes, model.activation, model.init_log_std)
    loss_critic = build_critic(
        critic_norm,
        critic_obs_dim,
        len(components),
        model.hidden_sizes,
        model.activation,
        model.separate_heads,
        in_key=critic_key,
    )
    # value_norm: the loss regresses loss_critic's normalised heads; GAE (and the checkpoint) use `critic`,
    # the same network with each head mapped back to reward units (training/value_norm.py)
    value_norm = make_value_norm(cfg.ppo.get("value_norm"), len(components))
    critic = denormalized_critic(loss_critic, value_norm) if value_norm is not None else loss_critic

    # --- advantage, loss, optimiser ---------------------------------------------------------------
    ppo = cfg.ppo
    estimator = WeightedMultiGAE(
        components,
        gamma=ppo.gamma,
        lmbda=ppo.lmbda,
        value_network=critic,
        normalize_components=ppo.normalize_components,
    )
    loss = HybridClipPPOLoss(
        actor,
        loss_critic,
        clip_epsilon=ppo.clip_epsilon,
        entropy_bonus=ppo.entropy_coef > 0,
        entropy_coeff=ppo.entropy_coef,
        critic_coeff=ppo.critic_coef,
        loss_critic_type="l2",
        normalize_advantage=ppo.normalize_advantage,
        clip_value=ppo.get("clip_value"),  # in normalised units when value_norm is on
        # the modules are called as they are: the functional parameter swap (to_module per call) cost ~1 ms
        # per minibatch, a third of a small-minibatch loss step, and nothing here needs functional calls
        functional=False,
    )
    # fused: one kernel for all parameters; the per-tensor Python loop cost 1.7 ms per step against 0.27 ms
    # (measured with [64, 64] networks, one thread), as much as the loss forward at small minibatches
    optimizer = torch.optim.Adam(loss.parameters(), lr=cfg.trainer.lr, eps=1e-5, fused=True)

    # --- collection and the trainer ---------------------------------------------------------------
    done_frames = resumed["collected_frames"] if resumed else 0
    if resumed:
        log.info("resuming %s at %d frames (iteration %d)", run_dir, done_frames, resumed["iteration"])
        truncate_metrics(run_dir / "metrics", done_frames)
        truncate_jsonl(run_dir / DECISIONS_FILE, done_frames)
    collector = make_collector(cfg, actor, components, remaining_frames=cfg.trainer.total_frames - done_frames)
    logger = build_logger(cfg.logger.backends, run_dir, "metrics")
    trainer = Trainer(
        collector=collector,
        total_frames=cfg.trainer.total_frames,
        frame_skip=1,
        optim_steps_per_batch=cfg.trainer.num_minibatches,
        loss_module=loss,
        optimizer=optimizer,
        logger=logger,
        clip_grad_norm=True,
        clip_norm=cfg.trainer.max_grad_norm,
        progress_bar=cfg.trainer.progress_bar,
        seed=cfg.seed + done_frames,
        num_epochs=cfg.trainer.num_epochs,
        log_interval=0,
        save_trainer_interval=sys.maxsize,
        auto_log_optim_steps=False,
    )
    trainer.register_op("batch_process", FiniteGuard(components))
    minibatches = PPOMinibatches(
        estimator,
        cfg.trainer.num_minibatches,
        seed=cfg.seed,
        keys=[*loss.in_keys, "advantage", "value_target", "state_value", "loc", "scale"],
        post_estimate=ValueTargetNormalization(value_norm) if value_norm is not None else None,
    )
    minibatches.register(trainer)
    scheduler = make_scheduler(cfg, estimator, components, run_dir, logger)
    scheduler.register(trainer, "rule_scheduler")
    ObservationNormUpdate(obs_norm).register(trainer)
    if critic_norm is not obs_norm:
        ObservationNormUpdate(critic_norm, critic_key).register(trainer, "critic_obs_norm")
    lr_decay = LinearLRDecay(optimizer, cfg.trainer.total_frames)
    if ppo.get("kl_target"):  # adaptive KL schedule (training/kl_schedule.py) replaces the linear decay
        AdaptiveKLLR(optimizer, actor.module[0].module, target=ppo.kl_target).register(trainer)
    elif cfg.trainer.anneal_lr:
        lr_decay.register(trainer)
    UpdateWeights(collector, update_weights_interval=1).register(trainer)
    returns_log = ComponentReturnLog(components, estimator)
    returns_log.register(trainer)
    trainer.register_op("post_optim_complete_log", loss_metrics)
    register_video_log(trainer, cfg, actor, components, run_dir)

    def training_state() -> dict[str, Any]:
        return {
            "actor": actor.state_dict(),
            "critic": critic.state_dict(),
            "estimator": estimator.state_dict(),
            "optimizer": optimizer.state_dict(),
            "scheduler": scheduler.state_dict(),
            "minibatches": minibatches.state_dict(),
            "rng": rng_state(),
            "collected_frames": trainer.collected_frames,
            "components": components,
            "llm_log_lines": count_lines(run_dir / "llm_calls.jsonl"),
        }

    checkpoint = CheckpointHook(run_dir / CHECKPOINT_FILE, cfg.checkpoint.interval or sys.maxsize, training_state)
    checkpoint.register(trainer)  # last post_steps hook: saves the state the next iteration starts from
    if resumed:
        actor.load_state_dict(resumed["actor"])
        critic.load_state_dict(resumed["critic"])
        estimator.load_state_dict(resumed["estimator"])
        optimizer.load_state_dict(resumed["optimizer"])
        scheduler.load_state_dict(resumed["scheduler"])
        minibatches.load_state_dict(resumed["minibatches"])
        checkpoint.load_state_dict(resumed)
        set_rng_state(resumed["rng"])
        trainer.collected_frames = done_frames
        if not ppo.get("kl_target"):
            lr_decay()  # the learning rate the interrupted run had reached (the adaptive one is in the optimizer)
        collector.update_policy_weights_()

    if done_frames < cfg.trainer.total_frames:
        trainer.train()
    checkpoint.save()
    log.info("finished: %d frames, last metrics %s", trainer.collected_frames, returns_log.latest)
    return dict(returns_log.latest)


def make_scheduler(cfg: DictConfig, estimator: WeightedMultiGAE, components: list[str], run_dir: Path, logger):
    """``build_scheduler`` with every rule tried once on K-shaped statistics, so a rule file that
    cannot serve this task fails at start as a :class:`ConfigError` rather than at the first decision."""
    try:
        scheduler = build_scheduler(cfg, estimator, components, run_dir, logger)
    except (ValueError, KeyError, FileNotFoundError, ImportError, SyntaxError) as error:
        raise ConfigError(f"scheduler setup failed: {error}") from error
    num_components = len(components)
    statistics = (torch.linspace(-1.0, 1.0, num_components), torch.ones(num_components))
    history = torch.zeros(cfg.scheduler.history_length, num_components)
    misfits = []
    for rule in scheduler.repository.rules:
        try:
            rule.scores(*statistics, history, estimator.weights.clone())
        except Exception as error:  # a rule file is user input: any failure is a misfit, reported by name
            misfits.append(f"{rule.key}: {error}")
    if misfits:
        raise ConfigError(f"rules that do not fit K={num_components} components {components}: " + "; ".join(misfits))
    return scheduler


def count_lines(path: Path) -> int:
    return sum(1 for _ in path.open()) if path.exists() else 0


@hydra.main(config_path="pkg://torchrl_ahrs.conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    try:
        if cfg.get("resume"):
            run_dir = Path(cfg.resume)
            cfg = load_saved_config(run_dir, HydraConfig.get().overrides.task)
        else:
            run_dir = Path(HydraConfig.get().runtime.output_dir)
        train(cfg, run_dir)
    except (ConfigError, FileNotFoundError, FloatingPointError) as error:
        print(f"error: {error}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
