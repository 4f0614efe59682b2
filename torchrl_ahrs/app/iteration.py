"""One training run: TorchRL's ``Trainer`` with the hooks of a hybrid-reward PPO iteration, registered
in one place, in the order they run.

One iteration, step by step (``Trainer.train``'s hook points in brackets)::

    1. collect         Collector steps N envs × T steps with the current policy   -> batch [N, T]
    2. rewards         RewardComponents / AuxiliaryReward already wrote ("next", "reward", c), c = 1..K
       [batch_process] FiniteGuard: stop on NaN/inf; ObservationNormUpdate.remember(batch)
       [pre_steps_log] ComponentReturnLog: reward/<c>, return/<c>, weight/<c>, frames_per_second
       [pre_steps_log] ConsoleProgress: one line (frames, frames/s, ETA, return, rule); a table at decisions
    3. advantages      [pre_epoch] PPOMinibatches: WeightedMultiGAE(batch) with the current critic
                       -> advantage_components [N,T,K], value_target [N,T,K], advantage = Σ_k w_k A_k
    4. PPO epochs      [process_optim_batch] shuffled minibatches -> HybridClipPPOLoss -> Adam (clipped)
       [post_optim_complete_log] loss_metrics: train/<loss term>
       [post_optim_complete_log] ComponentShareLog: share/<c> = w_k std(A'_k) / sum_j w_j std(A'_j)
    5. after update    [post_steps] ObservationNormUpdate.apply, LinearLRDecay, UpdateWeights (collector)
    6. schedule        [post_steps] RuleScheduler: every `interval` iterations stats -> rule -> w_k
    7. checkpoint      [post_steps] CheckpointHook: everything in the trainer's registry, atomically

Steps 5–7 share the ``post_steps`` hook point, where TorchRL runs hooks in registration order:
:func:`register_iteration` is the only place that registers them, and :func:`check_order` verifies
the resulting order before training starts.

Checkpointed state has one owner, the trainer's registry (``Trainer.state_dict``): the loss module
(actor, critic, observation statistics), the optimiser (with the current learning rate), the collector,
and every module registered below under its name (the full list is in :mod:`.checkpoint`). Saving and
resuming both go through it, and a resumed run is bit-identical to an uninterrupted one on CPU.
"""

from __future__ import annotations

import logging
import random
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig
from torchrl.trainers import Trainer, TrainerHookBase, UpdateWeights

from torchrl_ahrs.app.build import (
    build_checked_scheduler,
    build_collector,
    build_estimator_and_loss,
    build_networks,
    env_factory,
    resolve_devices,
)
from torchrl_ahrs.app.checkpoint import (
    CheckpointHook,
    collected_frames,
    load_checkpoint,
    mark_finished,
    truncate_jsonl,
    truncate_metrics,
)
from torchrl_ahrs.app.config import num_minibatches, save_config, validate_config
from torchrl_ahrs.app.run_dir import METRICS, RunDirectory
from torchrl_ahrs.app.video import register_video_log
from torchrl_ahrs.envs.registry import simulation_device
from torchrl_ahrs.training.console import ConsoleProgress
from torchrl_ahrs.training.hooks import (
    ComponentReturnLog,
    ComponentShareLog,
    FiniteGuard,
    LinearLRDecay,
    ObservationNormUpdate,
    PPOMinibatches,
    loss_metrics,
)
from torchrl_ahrs.training.kl_schedule import AdaptiveKLLR
from torchrl_ahrs.training.loggers import build_logger
from torchrl_ahrs.training.value_norm import ValueTargetNormalization

log = logging.getLogger("torchrl_ahrs.train")

# The post_steps hooks in the order one iteration must run them (steps 5-7 of the module docstring).
POST_STEPS_ORDER = (
    "obs_norm",
    "critic_obs_norm",
    "lr_decay",
    "update_weights",
    "rule_scheduler",
    "video_log",
    "checkpoint",
)


class GlobalRNG(TrainerHookBase):
    """Python's, NumPy's and torch's global generators as one registered piece of state (with the learner's
    CUDA generator, which samples the policy's actions, when it runs on a GPU)."""

    def __init__(self, device: torch.device | str = "cpu"):
        self.device = torch.device(device)

    def state_dict(self) -> dict[str, Any]:
        state = {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state()}
        if self.device.type == "cuda":
            state["cuda"] = torch.cuda.get_rng_state(self.device)
        return state

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        random.setstate(state_dict["python"])
        np.random.set_state(state_dict["numpy"])
        torch.set_rng_state(state_dict["torch"])
        if "cuda" in state_dict and self.device.type == "cuda":
            torch.cuda.set_rng_state(state_dict["cuda"], self.device)

    def register(self, trainer: Trainer, name: str = "rng") -> None:
        trainer.register_module(name, self)


def register_iteration(trainer: Trainer, parts: dict[str, Any]) -> None:
    """Registers every hook of one iteration on ``trainer``, in the order of the module docstring.

    ``parts`` holds the run's pieces by name (``components``, ``estimator``, ``loss``, ``networks``, ``optimizer``,
    ``scheduler``, ``collector``, ``checkpoint``, ``cfg``, ``run_dir``, ``device``); optional hooks (critic
    normaliser, LR decay, video) are registered only when the run uses them.
    """
    cfg, networks = parts["cfg"], parts["networks"]
    # 2. rewards: guard and remember the batch's observations
    trainer.register_op("batch_process", FiniteGuard(parts["components"]))
    obs_norm = ObservationNormUpdate(networks.actor_norm)
    critic_norm = None
    if networks.critic_norm is not networks.actor_norm:
        critic_norm = ObservationNormUpdate(networks.critic_norm, networks.critic_key)
    returns_log = ComponentReturnLog(parts["components"], parts["estimator"])
    returns_log.register(trainer)
    if cfg.trainer.progress_bar:  # one short line per iteration, a per-component table now and then
        ConsoleProgress(
            cfg.trainer.total_frames,
            parts["components"],
            parts["estimator"],
            parts["scheduler"],
            table_interval=int(cfg.trainer.get("table_interval", 10)),
            start_frames=int(parts.get("done_frames", 0)),
        ).register(trainer)
    # 3-4. advantages and PPO epochs
    estimator, loss = parts["estimator"], parts["loss"]
    value_norm = getattr(estimator, "value_norm", None)
    PPOMinibatches(
        estimator,
        num_minibatches(cfg),
        seed=int(cfg.seed),
        keys=[*loss.in_keys, "advantage", "value_target", "state_value", "loc", "scale"],
        post_estimate=ValueTargetNormalization(value_norm) if value_norm is not None else None,
        device=parts.get("device", "cpu"),
    ).register(trainer)
    if cfg.ppo.get("kl_target"):  # adaptive KL schedule (training/kl_schedule.py), in place of the linear decay
        AdaptiveKLLR(parts["optimizer"], target=cfg.ppo.kl_target).register(trainer)  # reads the loss's "kl"
    trainer.register_op("post_optim_complete_log", loss_metrics)
    ComponentShareLog(parts["components"], parts["estimator"]).register(trainer)  # share/<c> after the epochs
    # 5. after the update: normalisers absorb the batch, learning rate, policy weights to the collector
    obs_norm.register(trainer)
    if critic_norm is not None:
        critic_norm.register(trainer, "critic_obs_norm")
    if cfg.trainer.anneal_lr and not cfg.ppo.get("kl_target"):
        LinearLRDecay(parts["optimizer"], cfg.trainer.total_frames).register(trainer)
    update_weights = UpdateWeights(parts["collector"], update_weights_interval=1)
    update_weights.register(trainer)
    # 6. schedule
    parts["scheduler"].register(trainer, "rule_scheduler")
    register_video_log(trainer, cfg, networks.actor, parts["make_envs"], parts["run_dir"])
    # 7. checkpoint: last, so it saves the state the next iteration starts from
    GlobalRNG(parts.get("device", "cpu")).register(trainer)
    parts["checkpoint"].register(trainer)
    check_order(trainer)


def check_order(trainer: Trainer) -> None:
    """Raises ``RuntimeError`` when the registered ``post_steps`` hooks do not follow :data:`POST_STEPS_ORDER`."""
    names = [_hook_name(trainer, op) for op, _ in trainer._post_steps_ops]
    ranks = [POST_STEPS_ORDER.index(name) for name in names if name in POST_STEPS_ORDER]
    if ranks != sorted(ranks) or ranks[-1:] != [POST_STEPS_ORDER.index("checkpoint")]:
        raise RuntimeError(f"post_steps hooks out of order: {names}; expected the order {POST_STEPS_ORDER}")


def _hook_name(trainer: Trainer, op) -> str:
    target = getattr(op, "__wrapped__", op)
    target = getattr(target, "__self__", target)
    for name, module in trainer._modules.items():
        if module is target:
            return name
    return getattr(target, "__name__", type(target).__name__)


def train(cfg: DictConfig, run_dir: Path) -> dict[str, Any]:
    """Runs one training job (or continues it, when ``cfg.resume`` names ``run_dir``, which holds a
    checkpoint) and returns the last logged metrics."""
    validate_config(cfg)
    run = RunDirectory(run_dir).mkdir()
    done = collected_frames(run.path) if cfg.get("resume") else None
    if done is not None and done >= cfg.trainer.total_frames:
        log.info("%s is finished (%d of %d frames); nothing to do", run_dir, done, cfg.trainer.total_frames)
        return {}
    resumed = load_checkpoint(run.checkpoint) if cfg.get("resume") else None
    if resumed is None:
        save_config(cfg, run.config)
        # a sweep job restarted in a directory that a run left before its first checkpoint: its rows are stale
        truncate_metrics(run.metrics, -1)
        truncate_jsonl(run.decisions, -1)
    random.seed(cfg.seed)  # every global generator, so a run does not depend on what its process did before
    np.random.seed(cfg.seed)
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.trainer.torch_threads)

    devices = resolve_devices(cfg)
    # + the sandbox-checked auxiliary reward when the method uses one
    make_envs = env_factory(cfg, device=devices.envs)
    components = make_envs.components
    log.info("task %s, method %s, K=%d components %s", cfg.task.name, cfg.method.name, len(components), components)
    log.info("learner on %s, environments on %s", devices.learner, devices.envs)
    physics = simulation_device(cfg.task) if cfg.task.get("backend", "cpu") == "mjx" else devices.envs
    if physics != devices.envs:  # e.g. JAX on a GPU with trainer.device=cpu
        log.warning("MJX steps on %s, its env on %s: every control step copies the state across", physics, devices.envs)
    networks = build_networks(cfg, make_envs, device=devices.learner)
    estimator, loss = build_estimator_and_loss(cfg, networks, components, devices.learner)
    # fused: one kernel for all parameters; the per-tensor Python loop cost 1.7 ms per step against 0.27 ms
    # (measured with [64, 64] networks, one thread), as much as the loss forward at small minibatches
    optimizer = torch.optim.Adam(loss.parameters(), lr=cfg.trainer.lr, eps=1e-5, fused=True)

    done_frames = resumed["state"]["collected_frames"] if resumed else 0
    if resumed:
        log.info("resuming %s at %d frames", run_dir, done_frames)
        truncate_metrics(run.metrics, done_frames)
        truncate_jsonl(run.decisions, done_frames)
    collector = build_collector(cfg, networks.actor, make_envs, devices.learner)
    logger = build_logger(cfg.logger.backends, run.path, METRICS)
    trainer = Trainer(
        collector=collector,
        total_frames=cfg.trainer.total_frames,
        frame_skip=1,
        optim_steps_per_batch=num_minibatches(cfg),
        loss_module=loss,
        optimizer=optimizer,
        logger=logger,
        clip_grad_norm=True,
        clip_norm=cfg.trainer.max_grad_norm,
        progress_bar=False,  # ConsoleProgress prints the run's line (TorchRL's bar shows every pbar metric)
        # what has a state is overwritten by load_state_dict below; on resume, what has none (EnvPool's
        # simulators) starts episodes different from the first run's
        seed=cfg.seed + done_frames,
        num_epochs=cfg.trainer.num_epochs,
        log_interval=0,
        save_trainer_interval=sys.maxsize,
        auto_log_optim_steps=False,
    )
    scheduler = build_checked_scheduler(cfg, estimator, components, run, logger)
    trainer.register_module("estimator", estimator)
    trainer.register_module("actor", networks.actor)  # also inside the loss; kept by name for evaluation
    checkpoint = CheckpointHook(run.checkpoint, cfg.checkpoint.interval or sys.maxsize, trainer.state_dict, components)
    parts = dict(
        cfg=cfg, run_dir=run.path, components=components, make_envs=make_envs, networks=networks, estimator=estimator,
        optimizer=optimizer, collector=collector, scheduler=scheduler, checkpoint=checkpoint, done_frames=done_frames,
        loss=loss, device=devices.learner,
    )  # fmt: skip
    register_iteration(trainer, parts)
    if resumed:
        # last, after everything that draws random numbers while being built; from here to the first
        # collection nothing draws, so the resumed run continues the saved one bit for bit
        trainer.load_state_dict(resumed)
        collector.update_policy_weights_()

    try:
        if done_frames < cfg.trainer.total_frames:
            trainer.train()  # its last iteration writes the final checkpoint
    finally:
        logger.close()  # TensorBoard's writer thread would otherwise still be writing after we return
    if trainer.collected_frames >= cfg.trainer.total_frames:
        mark_finished(run.path, trainer.collected_frames, cfg.trainer.total_frames)
    returns_log = trainer._modules["component_returns"]
    log.info("finished: %d frames, last metrics %s", trainer.collected_frames, returns_log.latest)
    return dict(returns_log.latest)
