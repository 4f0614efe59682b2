"""One training run: builds the parts from the config, loads a checkpoint when resuming, and hands them
to :func:`torchrl_ahrs.training.loop.learn`, the iteration written as one function.

The run's state has one registry, ``{name: object with state_dict / load_state_dict}`` (the entries are listed
in :mod:`.checkpoint`): the checkpoint saves it, a resumed run loads it after every part has been built, and a
resumed run is bit-identical to an uninterrupted one on CPU.
"""

from __future__ import annotations

import logging
import random
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from torchrl_ahrs.app.shared.config import (
    collection_threads,
    network_precision,
    num_minibatches,
    save_config,
    validate_config,
)
from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.run_dir import METRICS, RunDirectory
from torchrl_ahrs.app.train.build import (
    build_checked_scheduler,
    build_collector,
    build_estimator_and_loss,
    build_mirror,
    build_networks,
    build_optimizer,
    env_factory,
    resolve_devices,
)
from torchrl_ahrs.app.train.checkpoint import (
    CheckpointHook,
    GeneratorState,
    GlobalRNG,
    collected_frames,
    load_checkpoint,
    load_registry,
    mark_finished,
    registry_state,
    truncate_jsonl,
    truncate_metrics,
)
from torchrl_ahrs.app.train.preflight import check_config, check_task_rewards, inductor_failure
from torchrl_ahrs.app.train.video import register_video_log
from torchrl_ahrs.envs.registry import simulation_device
from torchrl_ahrs.training.loggers import ConsoleProgress, build_logger
from torchrl_ahrs.training.loop import learn
from torchrl_ahrs.training.models import native_bfloat16, precision_name
from torchrl_ahrs.training.run import LoopSettings, Progress, TrainingRun

log = logging.getLogger("torchrl_ahrs.train")


def train(cfg: DictConfig, run_dir: Path) -> dict[str, Any]:
    """Runs one training job (or continues it, when ``cfg.resume`` names ``run_dir``, which holds a
    checkpoint) and returns the last logged metrics."""
    started = time.monotonic()
    check_config(cfg)  # the start-up checks: before anything is built or written (app/train/preflight.py)
    validate_config(cfg)
    compile_loss = bool(cfg.trainer.get("compile", False))
    if compile_loss and (why := inductor_failure()) is not None:  # no C++ compiler: train eagerly, and say so
        log.warning(
            "trainer.compile=true, but torch.compile cannot build on this machine (%s); the loss runs eagerly", why
        )
        compile_loss = False
    run = RunDirectory(run_dir).mkdir()
    done = collected_frames(run.path) if cfg.get("resume") else None
    if done is not None and done >= cfg.trainer.total_frames:
        log.info("%s is finished (%d of %d frames), nothing to do", run_dir, done, cfg.trainer.total_frames)
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
    # + the sandbox-checked auxiliary reward when the method uses one; trainer.task_overrides change the training
    # environments only, so that evaluate (which reads `task`) scores the task as defined
    task_overrides = cfg.trainer.get("task_overrides")
    make_envs = env_factory(cfg, device=devices.envs, task_overrides=task_overrides)
    components = make_envs.components
    # a misspelt term, or components that miss part of the native reward, fail here, on a few real steps
    check_task_rewards(make_envs, int(cfg.seed), sums_to_native=bool(cfg.task.get("components_sum_to_native", True)))
    log.info("task %s, method %s, K=%d components %s", cfg.task.name, cfg.method.name, len(components), components)
    log.info("learner on %s, environments on %s", devices.learner, devices.envs)
    if task_overrides:
        log.info("training on the task changed by trainer.task_overrides %s", OmegaConf.to_container(task_overrides))
    backend = make_envs.task.backend
    physics = simulation_device(backend) if backend == "mjx" else devices.envs
    if physics != devices.envs:  # e.g. JAX on a GPU with trainer.device=cpu
        log.warning("MJX steps on %s, its env on %s: every control step copies the state across", physics, devices.envs)
    networks = build_networks(cfg, make_envs, device=devices.learner)
    log.info(
        "hidden layers: actor in %s, critic in %s (model.precision=%s)",
        precision_name(networks.actor_dtype),
        precision_name(networks.critic_dtype),
        cfg.model.get("precision", "float32"),
    )
    for network in ("actor", "critic"):
        if network_precision(cfg.model, network) == "bfloat16" and not native_bfloat16(devices.learner):
            log.warning(
                "the %s in bfloat16, but %s has no bfloat16 arithmetic in hardware: it is emulated, slower than"
                " float32 (model.precision=auto chooses float32 here)",
                network,
                devices.learner,
            )
    estimator, loss = build_estimator_and_loss(cfg, networks, components, devices.learner)
    optimizer = build_optimizer(cfg, loss, networks.critic)  # Adam; the critic's own group with ppo.kl_adapts=actor
    augment = build_mirror(cfg, make_envs.task, loss, networks.critic_key)  # ppo.mirror: each minibatch + its image

    done_frames = int(resumed["state"]["collected_frames"]) if resumed else 0
    collector = build_collector(cfg, networks.actor, make_envs, devices.learner)
    logger = build_logger(cfg.logger.backends, run.path, METRICS)
    if resumed is None:  # TensorBoard's HParams tab and the config as text, once per run (from the redacted file)
        logger.log_run_config(run.config.read_text())
    # the environments' seeds, then every global generator from the seed they return (what TorchRL's
    # Trainer(seed=) did when it ran the loop: kept, so a seed draws the numbers it drew then); what has a state
    # is overwritten by load_registry below, and on resume what has none (EnvPool's simulators) starts episodes
    # different from the first run's
    env_seed = collector.set_seed(int(cfg.seed) + done_frames, static_seed=False)
    torch.manual_seed(env_seed)
    np.random.seed(env_seed)
    scheduler = build_checked_scheduler(cfg, estimator, components, run, logger)
    generator = torch.Generator(device=devices.learner).manual_seed(int(cfg.seed))  # the minibatch permutations
    console = None
    if cfg.trainer.progress_bar:  # one short line per iteration, a per-component table now and then
        table_interval = int(cfg.trainer.get("table_interval", 10))
        console = ConsoleProgress(
            cfg.trainer.total_frames, components, estimator, scheduler, table_interval, start_frames=done_frames
        )
    video = register_video_log(None, cfg, networks.actor, make_envs, run.path)  # a clip every video_interval
    norms = [(networks.actor_norm, "observation")]
    if networks.critic_norm is not networks.actor_norm:  # privileged critic observations have their own statistics
        norms.append((networks.critic_norm, networks.critic_key))
    if cfg.model.get("observation_norm", "running") == "none":  # the normalisers stay the identity
        norms = []
    progress = Progress()
    settings = LoopSettings(
        total_frames=cfg.trainer.total_frames,
        num_epochs=cfg.trainer.num_epochs,
        num_minibatches=num_minibatches(cfg),
        max_grad_norm=cfg.trainer.max_grad_norm,
        anneal_lr=bool(cfg.trainer.anneal_lr),
        kl_target=cfg.ppo.get("kl_target"),  # the adaptive-KL rule, in place of the anneal
        advantage_pass=cfg.ppo.get("advantage_pass", "every_epoch"),  # a run saved before the key: every epoch
        compile=compile_loss,
        collection_threads=collection_threads(cfg.trainer),
    )
    # the run's state: one entry per owner (listed in app/train/checkpoint.py); saved after the iteration's last step
    registry: dict[str, Any] = {
        "state": progress,
        "collector": collector,
        "actor": networks.actor,
        "critic": networks.critic,
        "estimator": estimator,
        "optimizer": optimizer,
        "minibatches": GeneratorState(generator),
        "rule_scheduler": scheduler,
        **({"video_log": video} if video is not None else {}),
        "rng": GlobalRNG(devices.learner),
    }
    checkpoint = CheckpointHook(
        run.checkpoint,
        cfg.checkpoint.interval or sys.maxsize,
        lambda: registry_state(registry),
        components,
        is_last=lambda: progress.collected_frames >= cfg.trainer.total_frames,
        state_after_failure=lambda: registry_state(registry, skip_failed=True),
    )
    registry["checkpoint"] = checkpoint
    if resumed:
        # last, after everything that draws random numbers while being built; from here to the first
        # collection nothing draws, so the resumed run continues the saved one bit for bit
        try:
            load_registry(registry, resumed, run.checkpoint)
        except ConfigError:  # a checkpoint of an older layout: nothing was changed, release what was opened
            collector.shutdown()
            logger.close()
            raise
        collector.update_policy_weights_()
        log.info("resuming %s at %d frames", run_dir, done_frames)
        truncate_metrics(run.metrics, done_frames)  # rows and decisions of the iterations lost after the checkpoint
        truncate_jsonl(run.decisions, done_frames)

    training_run = TrainingRun(
        collector=collector,
        loss=loss,
        estimator=estimator,
        optimizer=optimizer,
        scheduler=scheduler,
        logger=logger,
        settings=settings,
        generator=generator,
        observation_norms=norms,
        value_norm=getattr(estimator, "value_norm", None),
        augment=augment,
        # after each iteration, in this order; the checkpoint last, so it holds the state the next one starts from
        after_iteration=[after for after in (console, video, checkpoint) if after is not None],
        after_failure=checkpoint.save_after_failure,  # an auxiliary reward's failure: keep what was learnt so far
        progress=progress,
    )
    latest: dict[str, float] = {}
    try:
        if done_frames < cfg.trainer.total_frames:
            latest = learn(training_run)  # its last iteration writes the final checkpoint
    finally:
        logger.close()  # TensorBoard's writer thread would otherwise still be writing after we return
    if progress.collected_frames >= cfg.trainer.total_frames:
        mark_finished(run.path, progress.collected_frames, cfg.trainer.total_frames)
    final_return = latest.get("return/total")
    log.info(
        "done: %d frames in %s, final return %s, run directory %s",
        progress.collected_frames,
        _clock(time.monotonic() - started),
        "n/a (no episode ended)" if final_return is None else f"{final_return:.4g}",
        run.path,
    )
    return latest


def _clock(seconds: float) -> str:
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"
