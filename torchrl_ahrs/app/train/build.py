"""Builds the parts of a training run from its config: environments, networks, estimator, loss,
optimiser, collector and scheduler. Nothing here runs an iteration (that is :mod:`.iteration`).

Devices (``trainer.device``, :func:`resolve_devices`): the learner — networks, observation and value
normalisers, the estimator's weights, the loss, the optimiser's state, the collected batch and the
minibatch shuffling — lives on one device. The environments live on it too when their backend computes on
its torch device (MJX); CPU backends stay on the CPU and the collector moves each step's observation to the
policy's device and the action back (TorchRL's ``policy_device`` / ``storing_device`` / ``env_device``)."""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from omegaconf import DictConfig
from torchrl.collectors import MultiAsyncCollector, MultiSyncCollector
from torchrl.envs import EnvBase
from torchrl.modules import ProbabilisticActor

from torchrl_ahrs.app.shared.auxiliary import TransformFactory, auxiliary_transform
from torchrl_ahrs.app.shared.config import network_precision, resolve_components
from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.run_dir import RunDirectory, calls_log
from torchrl_ahrs.app.shared.settings import override_task, scheduler_settings, task_settings
from torchrl_ahrs.envs.common.clip_actions import ClipActionToSpec
from torchrl_ahrs.envs.common.mirror import MirrorAugmentation
from torchrl_ahrs.envs.registry import env_device, make_env, simulation_device, task_mirror
from torchrl_ahrs.envs.settings import TaskSettings
from torchrl_ahrs.scheduling import RuleScheduler, build_scheduler
from torchrl_ahrs.training.collector import ResumableCollector
from torchrl_ahrs.training.loss import HybridClipPPOLoss
from torchrl_ahrs.training.models import (
    RunningNorm,
    build_actor,
    build_critic,
    compute_dtype,
    make_observation_norm,
    set_compute_dtype,
)
from torchrl_ahrs.training.value_norm import denormalized_critic, make_value_norm
from torchrl_ahrs.value import WeightedMultiGAE


@dataclass
class EnvFactory:
    """Picklable constructor of the run's environments (the task, its components and the extra
    transforms such as the auxiliary reward), so collector worker processes build exactly what the
    learner's probe saw."""

    task: TaskSettings  # the task's settings record (frozen; pickles to workers)
    components: list[str]
    transforms: tuple[TransformFactory, ...] = ()
    device: str = "cpu"  # the environments' torch device (a string: the factory is pickled to workers)

    def __call__(self, num_envs: int, seed: int) -> EnvBase:
        return make_env(
            self.task, num_envs, seed, device=self.device, components=self.components, transforms=self.transforms
        )


@dataclass(frozen=True)
class RunDevices:
    """Where a run's learner lives (``trainer.device``) and where its environments do."""

    learner: torch.device
    envs: torch.device


def resolve_devices(cfg: DictConfig) -> RunDevices:
    """``trainer.device`` (null: the simulation's device, :func:`~torchrl_ahrs.envs.registry.simulation_device`)
    and the environments' device (:func:`~torchrl_ahrs.envs.registry.env_device`).

    Raises:
        ConfigError: null resolves to a GPU (MJX on JAX's GPU) that torch cannot use here.
    """
    configured = cfg.trainer.get("device")
    if configured is not None:  # validate_config has checked it
        learner = torch.device(configured)
    else:
        learner = simulation_device(task_settings(cfg.task).backend)
        if learner.type == "cuda" and not torch.cuda.is_available():  # e.g. jax[cuda12] beside a CPU build of torch
            raise ConfigError(
                f"JAX steps on the GPU and trainer.device=null follows it ({learner}), but torch sees no CUDA "
                "device: install torch with CUDA, or set trainer.device=cpu (per-step copies between the two)"
            )
        if learner.type == "cuda" and cfg.trainer.collector != "sync":
            raise ConfigError(f"trainer.device=null is {learner} here (JAX's GPU), which needs trainer.collector=sync")
    return RunDevices(learner, env_device(task_settings(cfg.task).backend, learner))


def env_factory(
    cfg: DictConfig,
    check_aux: bool = True,
    device: torch.device | str = "cpu",
    task_overrides: Mapping[str, Any] | None = None,
) -> EnvFactory:
    """The run's :class:`EnvFactory` building environments on ``device`` for ``cfg.task`` with ``task_overrides``
    merged in (:func:`~torchrl_ahrs.app.shared.settings.override_task`: the training run passes
    ``trainer.task_overrides``); with ``check_aux`` the auxiliary reward file (when the method uses one) passes
    the sandbox on real transitions first."""
    aux = auxiliary_transform(cfg, check=check_aux)
    # an unsquashed Gaussian samples outside the bounds: the env gets the clipped action, the rollout the sample
    clip = ClipActionToSpec if cfg.model.get("distribution", "tanh_normal") == "normal" else None
    transforms = tuple(factory for factory in (clip, aux) if factory)
    task = override_task(cfg.task, task_overrides) if task_overrides else cfg.task
    return EnvFactory(task_settings(task), resolve_components(cfg), transforms, str(device))


@dataclass
class Networks:
    """The policy and the K-head critic with their observation normalisers (``critic_norm`` is
    ``actor_norm`` unless the task gives the critic privileged observations)."""

    actor: ProbabilisticActor
    critic: Any
    actor_norm: RunningNorm
    critic_norm: RunningNorm
    critic_key: str
    actor_dtype: torch.dtype | None = None  # model.actor_precision resolved: its hidden layers' dtype, None = float32
    critic_dtype: torch.dtype | None = None  # model.critic_precision resolved, for the K heads and the anchor alike


def build_networks(
    cfg: DictConfig, make_envs: EnvFactory, with_critic: bool = True, device: torch.device | str = "cpu"
) -> Networks:
    """Actor and critic shaped by a one-env probe of the task (observation sizes, action bounds), on ``device``
    (initialised on the CPU and moved, so a seed gives the same initial weights on every device).

    Raises:
        ConfigError: ``task.critic_observation`` names no observation of the task.
    """
    probe = make_envs(1, int(cfg.seed))
    try:
        obs_dim = probe.observation_spec["observation"].shape[-1]
        critic_key = cfg.task.get("critic_observation") or "observation"  # asymmetric actor-critic
        if critic_key not in probe.observation_spec.keys():
            raise ConfigError(f"task.critic_observation={critic_key!r} is not an observation of task {cfg.task.name!r}")
        critic_obs_dim = probe.observation_spec[critic_key].shape[-1]
        action_spec = probe.full_action_spec[probe.action_key].to(device)  # TanhNormal's bounds come from it
    finally:
        probe.close()
    model = cfg.model
    norm_kind = model.get("observation_norm", "running")
    actor_norm = make_observation_norm(obs_dim, norm_kind)
    critic_norm = actor_norm if critic_key == "observation" else make_observation_norm(critic_obs_dim, norm_kind)
    actor = build_actor(
        actor_norm,
        obs_dim,
        action_spec,
        model.hidden_sizes,
        model.activation,
        model.init_log_std,
        distribution=model.get("distribution", "tanh_normal"),
    )
    critic = None
    if with_critic:
        critic = build_critic(
            critic_norm,
            critic_obs_dim,
            len(make_envs.components),
            model.get("component_hidden_sizes") or model.hidden_sizes,  # the K heads' MLP
            model.activation,
            model.separate_heads,
            in_key=critic_key,
            anchor_head=anchored(cfg, len(make_envs.components)),  # the summed reward's value, an MLP of its own
            anchor_hidden_sizes=model.hidden_sizes,  # PPO's critic, as wide as PPO's
        )
    actor.to(device)  # moves actor_norm (and critic_norm when they are one module) too
    if critic is not None:
        critic.to(device)
    critic_norm.to(device)
    # the hidden layers' precision, the same in collection, advantages and loss (a run saved before the key: float32)
    actor_dtype = compute_dtype(network_precision(model, "actor"), device)
    critic_dtype = compute_dtype(network_precision(model, "critic"), device)
    set_compute_dtype(actor, actor_dtype)
    if critic is not None:
        set_compute_dtype(critic, critic_dtype)
    return Networks(actor, critic, actor_norm, critic_norm, critic_key, actor_dtype, critic_dtype)


def anchored(cfg: DictConfig, num_components: int) -> bool:
    """``ppo.mix=anchored`` over more than one component (a run saved before the key mixed ``sum``).

    With one component the summed reward is that component: the anchor would be a second critic of the same
    return and the anchored mix A = w A_1 is the sum's, so a task's preset can set the mix for every method,
    PPO's one head included, without giving PPO a critic it does not use."""
    return cfg.ppo.get("mix", "sum") == "anchored" and num_components > 1


def build_estimator_and_loss(
    cfg: DictConfig, networks: Networks, components: Sequence[str], device: torch.device | str = "cpu"
):
    """:class:`WeightedMultiGAE` over the K components and the PPO loss that trains on its mixed advantage,
    with every buffer (weights, shares, value-norm statistics, the loss's coefficients) on ``device``.

    With ``ppo.value_norm`` the loss regresses the critic's normalised heads while the estimator reads
    them mapped back to reward units (training/value_norm.py); the statistics live in the estimator's
    value network (checkpointed with it) and are reachable as ``estimator.value_norm``."""
    ppo = cfg.ppo
    anchor = anchored(cfg, len(components))
    value_norm = make_value_norm(ppo.get("value_norm"), len(components) + anchor)  # one per GAE column
    gae_critic = denormalized_critic(networks.critic, value_norm) if value_norm is not None else networks.critic
    estimator = WeightedMultiGAE(
        list(components),
        gamma=ppo.gamma,
        lmbda=ppo.lmbda,
        value_network=gae_critic,
        component_scale=ppo.component_scale,
        value_norm=value_norm,  # read by component_scale=value_norm; updated by the loop (training/loop.py)
        anchored=anchor,
    )
    estimator.to(device)  # the weights [K] and shares [K] buffers, and the value-norm statistics
    loss = HybridClipPPOLoss(
        networks.actor,
        networks.critic,
        clip_epsilon=ppo.clip_epsilon,
        entropy_bonus=ppo.entropy_coeff > 0,
        entropy_coeff=ppo.entropy_coeff,
        critic_coeff=ppo.critic_coeff,
        loss_critic_type="l2",
        normalize_advantage=ppo.normalize_advantage,
        clip_value=ppo.get("clip_value"),  # in normalised units when value_norm is on
        kl=ppo.get("kl_target") is not None,  # the adaptive-KL rule reads the loss's "kl"
        # the modules are called as they are: the functional parameter swap (to_module per call) cost ~1 ms
        # per minibatch, a third of a small-minibatch loss step, and nothing here needs functional calls
        functional=False,
    )
    return estimator, loss.to(device)


def build_optimizer(cfg: DictConfig, loss: torch.nn.Module, critic: torch.nn.Module) -> torch.optim.Adam:
    """Adam over the loss's parameters at ``trainer.lr``: one group, or with ``ppo.kl_adapts=actor`` the actor's
    and then the critic's, flagged ``kl_adaptive=False`` so the adaptive-KL rule (training/loop.py) leaves the
    critic's rate at ``trainer.lr`` (the KL measures how far the policy moved, not how the regression goes).

    fused: one kernel for all parameters; the per-tensor Python loop cost 1.7 ms per step against 0.27 ms
    (measured with [64, 64] networks, one thread), as much as the loss forward at small minibatches."""
    params = list(loss.parameters())
    groups: list[dict[str, Any]] = [{"params": params}]
    if cfg.ppo.get("kl_adapts", "all") == "actor":
        critic_ids = {id(param) for param in critic.parameters()}
        groups = [
            {"params": [param for param in params if id(param) not in critic_ids]},
            {"params": [param for param in params if id(param) in critic_ids], "kl_adaptive": False},
        ]
    return torch.optim.Adam(groups, lr=cfg.trainer.lr, eps=1e-5, fused=True)


def build_mirror(
    cfg: DictConfig, task: TaskSettings, loss: HybridClipPPOLoss, critic_key: str
) -> MirrorAugmentation | None:
    """``ppo.mirror=true``: the augmentation that follows each PPO minibatch with its mirror image, from the task's
    maps (envs/registry.py ``task_mirror``); ``None`` otherwise. A task without a mirror, or a critic that reads an
    observation the map does not cover, is a one-line ``ConfigError`` before anything trains."""
    if not cfg.ppo.get("mirror", False):
        return None
    try:
        maps = task_mirror(task)
    except ValueError as error:
        raise ConfigError(f"ppo.mirror=true: {error}") from None
    if critic_key != "observation":
        raise ConfigError(f"ppo.mirror=true: task {task.name!r} has no mirror for its critic's {critic_key!r}")
    keys = loss.tensor_keys
    return MirrorAugmentation.for_policy(
        maps["observation"], maps["action"], action_key=keys.action, loc_key=keys.loc, scale_key=keys.scale
    )


@dataclass
class _WorkerEnvs:
    """One collector worker's environments (picklable: a factory, a size and a seed)."""

    make_envs: EnvFactory
    num_envs: int
    seed: int

    def __call__(self) -> EnvBase:
        return self.make_envs(self.num_envs, self.seed)


def build_collector(cfg: DictConfig, policy, make_envs: EnvFactory, device: torch.device | str = "cpu"):
    """``sync``: the envs step in this process between updates, the policy acts and the batch is stored on
    ``device`` (TorchRL's ``policy_device`` / ``storing_device``; the env keeps its own device, and the
    collector casts between the two when they differ). ``multi``: ``workers`` processes each
    step ``num_envs / workers`` envs, all waiting for the update. ``async``: the worker processes keep
    collecting while the learner updates (each iteration trains on one worker's share of the batch,
    gathered with the previous iteration's policy). Each (worker's) collector is a
    :class:`ResumableCollector`: on resume the trainer's registry restores its frame counter (so
    ``total_frames`` is always the whole budget), its environments and the episodes they were in."""
    trainer_cfg = cfg.trainer
    frames_per_batch = trainer_cfg.frames_per_batch
    if trainer_cfg.collector == "sync":
        env = make_envs(trainer_cfg.num_envs, int(cfg.seed))
        return ResumableCollector(
            env,
            policy,
            frames_per_batch=frames_per_batch,
            total_frames=trainer_cfg.total_frames,
            auto_register_policy_transforms=False,
            env_device=env.device,
            policy_device=device,
            storing_device=device,
        )
    workers = trainer_cfg.workers
    env_fns = [
        _WorkerEnvs(make_envs, trainer_cfg.num_envs // workers, int(cfg.seed) + 1000 * worker)
        for worker in range(workers)
    ]
    if trainer_cfg.collector == "async":
        return MultiAsyncCollector(
            env_fns,
            policy,
            frames_per_batch=frames_per_batch // workers,
            total_frames=trainer_cfg.total_frames,
            collector_class=ResumableCollector,
            auto_register_policy_transforms=False,  # as the sync collector: the envs carry every transform
        )
    return MultiSyncCollector(
        env_fns,
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=trainer_cfg.total_frames,
        cat_results=0,
        collector_class=ResumableCollector,
        auto_register_policy_transforms=False,
        use_buffers=True,  # what TorchRL assumes (with a warning at the first batch) when it is not said
    )


def build_checked_scheduler(
    cfg: DictConfig, estimator: WeightedMultiGAE, components: list[str], run: RunDirectory | None, logger
) -> RuleScheduler:
    """``build_scheduler`` writing into ``run`` (decisions, LLM calls), with every rule tried once on
    K-shaped statistics, so a rule file that cannot serve this task fails at start as a
    :class:`ConfigError` rather than at the first decision. ``llm.replay_from`` may name a run directory."""
    if cfg.get("llm") and cfg.llm.get("replay_from"):
        cfg = copy.deepcopy(cfg)
        cfg.llm.replay_from = calls_log(cfg.llm.replay_from)
    decisions, llm_calls = (run.decisions, run.llm_calls) if run is not None else (None, None)
    try:
        scheduler = build_scheduler(scheduler_settings(cfg), estimator, components, decisions, logger, llm_calls)
    except (ValueError, KeyError, FileNotFoundError, ImportError, SyntaxError) as error:
        raise ConfigError(f"scheduler setup failed: {error}") from error
    num_components = len(components)
    statistics = (torch.linspace(-1.0, 1.0, num_components), torch.ones(num_components))
    history = torch.zeros(cfg.scheduler.history_length, num_components)
    misfits = []
    for rule in scheduler.repository.rules:
        try:
            rule.scores(*statistics, history, estimator.weights.to("cpu", copy=True))  # rules see CPU summaries
        except Exception as error:  # a rule file is user input: any failure is a misfit, reported by name
            misfits.append(f"{rule.key}: {error}")
    if misfits:
        raise ConfigError(f"rules that do not fit K={num_components} components {components}: " + "; ".join(misfits))
    return scheduler
