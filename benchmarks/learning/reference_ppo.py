"""TorchRL's reference PPO for MuJoCo (``sota-implementations/ppo``), written here from its description.

One builder shared by the throughput benchmark (``bench_pipeline.py``, our batch geometry) and the learning
benchmark (``learning.py``, the reference's own MuJoCo settings). The pipeline: gymnasium's ``Ant-v5``
through ``GymEnv`` (one env, or N in a ``ParallelEnv``), ``VecNorm`` + ``ClipTransform`` + ``RewardSum`` +
``StepCounter`` + ``DoubleToFloat``, a ``Collector``, ``GAE`` recomputed every epoch, ``ClipPPOLoss``, a
``TensorDictReplayBuffer`` with ``SamplerWithoutReplacement``, Adam with the learning rate annealed
linearly over the network updates.

:class:`ReferenceConfig`'s defaults are the numbers of pytorch/rl's ``sota-implementations/ppo``
(``config_mujoco.yaml``, ``ppo_mujoco.py``, ``utils_mujoco.py`` at commit ae9719f1, 2026-08-22): one
environment (``env.num_envs: 1``; gym backend), ``frames_per_batch: 2048``, ``total_frames: 1_000_000``,
``mini_batch_size: 64``, ``ppo_epochs: 10``, ``lr: 3e-4`` with ``anneal_lr: True`` (per network update),
Adam ``eps=1e-5``, no gradient clipping, ``gamma: 0.99``, ``gae_lambda: 0.95``, ``clip_epsilon: 0.2``,
``critic_coeff: 0.25``, ``entropy_coeff: 0.0``, ``loss_critic_type: l2``, advantages normalised; actor and
critic MLPs ``[64, 64]`` tanh, orthogonal initialisation (gain 1.0 actor, 0.01 critic, zero biases);
``VecNorm(decay=0.99999, eps=1e-2)`` and observations clipped to ±10. The reference keeps two Adam
optimisers (actor, critic) grouped into one step; one Adam over both parameter sets is the same update
(Adam is per parameter and both use the same learning rate).
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.envs import (
    ClipTransform,
    DoubleToFloat,
    ParallelEnv,
    RewardSum,
    SerialEnv,
    StepCounter,
    TransformedEnv,
    VecNorm,
)
from torchrl.envs.libs.gym import GymEnv
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

OBS_CLIP = 10.0  # ClipTransform(low=-10, high=10) after VecNorm


@dataclass
class ReferenceConfig:
    """The reference pipeline's settings; the defaults are TorchRL's sota MuJoCo PPO (module docstring).

    Example:
        >>> config = ReferenceConfig()
        >>> config.frames_per_batch // config.mini_batch_size * config.epochs  # network updates per batch
        320
    """

    env_name: str = "Ant-v5"
    env_kwargs: dict[str, Any] = field(default_factory=dict)  # gymnasium.make's (ours_gymnasium_kwargs: our task's)
    num_envs: int = 1  # gymnasium envs; >1: a ParallelEnv of `workers` processes
    workers: int = 4  # ParallelEnv worker processes when num_envs > 1 (each a SerialEnv of num_envs / workers)
    frames_per_batch: int = 2048
    total_frames: int = 1_000_000  # also the learning-rate annealing horizon
    mini_batch_size: int = 64
    epochs: int = 10
    lr: float = 3e-4
    anneal_lr: bool = True
    max_grad_norm: float | None = None  # None: no clipping (the reference's setting)
    gamma: float = 0.99
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    critic_coeff: float = 0.25
    entropy_coeff: float = 0.0
    entropy_bonus: bool = True  # the reference keeps ClipPPOLoss's entropy term (with coefficient 0)
    hidden: list[int] = field(default_factory=lambda: [64, 64])
    orthogonal_init: bool = True


def ours_gymnasium_kwargs(task: str = "ant_v5") -> dict[str, Any]:
    """``gymnasium.make`` keyword arguments that give gymnasium's Ant-v5 the observation of our ``task``.

    Our ``ant_v5`` preset leaves the contact forces out (27 entries, as gymnasium's Ant-v4 and CleanRL's runs);
    gymnasium's Ant-v5 includes them by default (105). A peer trained on the default could not be evaluated on
    our env, and would not be learning the same problem.

    Example:
        >>> ours_gymnasium_kwargs("ant_v5")
        {'include_cfrc_ext_in_observation': False}
    """
    from torchrl_ahrs.app.shared.settings import load_task_settings
    from torchrl_ahrs.envs.settings import AntV5Settings

    settings = load_task_settings(task)
    if not isinstance(settings, AntV5Settings):
        raise ValueError(f"gymnasium's Ant-v5 mirrors task ant_v5, not {task!r}")
    return {"include_cfrc_ext_in_observation": settings.include_cfrc_ext_in_observation}


def make_gym_env(env_name: str = "Ant-v5", env_kwargs: dict[str, Any] | None = None) -> GymEnv:
    """One gymnasium environment through TorchRL's ``GymEnv`` (a module-level function: picklable for workers)."""
    return GymEnv(env_name, **(env_kwargs or {}))


def make_reference_env(config: ReferenceConfig, seed: int) -> TransformedEnv:
    """The reference's training env: batch size ``[]`` (one env), ``[N]`` or ``[W, N/W]`` (``ParallelEnv`` of
    ``SerialEnv``), with VecNorm, ClipTransform, RewardSum, StepCounter and DoubleToFloat."""
    make_one = functools.partial(make_gym_env, config.env_name, config.env_kwargs)
    if config.num_envs == 1:
        base = make_one()
    elif config.workers >= config.num_envs:
        base = ParallelEnv(config.num_envs, make_one)
    else:
        if config.num_envs % config.workers:
            raise ValueError(f"num_envs {config.num_envs} must be a multiple of workers {config.workers}")
        base = ParallelEnv(config.workers, functools.partial(SerialEnv, config.num_envs // config.workers, make_one))
    env = TransformedEnv(base)
    env.append_transform(VecNorm(in_keys=["observation"], decay=0.99999, eps=1e-2))
    env.append_transform(ClipTransform(in_keys=["observation"], low=-OBS_CLIP, high=OBS_CLIP))
    env.append_transform(RewardSum())
    env.append_transform(StepCounter())
    env.append_transform(DoubleToFloat(in_keys=["observation"]))
    env.set_seed(seed)
    return env


def make_reference_models(
    env: TransformedEnv, hidden: list[int], orthogonal_init: bool = False
) -> tuple[ProbabilisticActor, ValueOperator]:
    """TanhNormal actor (state-independent scale, initially 1) and a one-output critic, both tanh MLPs.

    ``orthogonal_init``: the reference's initialisation (weights orthogonal with gain 1.0 for the actor and
    0.01 for the critic, biases 0); otherwise PyTorch's default.
    """
    obs_dim = env.observation_spec["observation"].shape[-1]
    action_dim = env.action_spec_unbatched.shape[-1]
    loc_net = MLP(in_features=obs_dim, out_features=action_dim, num_cells=hidden, activation_class=nn.Tanh)
    value_net = MLP(in_features=obs_dim, out_features=1, num_cells=hidden, activation_class=nn.Tanh)
    if orthogonal_init:
        for net, gain in ((loc_net, 1.0), (value_net, 0.01)):
            for layer in net.modules():
                if isinstance(layer, nn.Linear):
                    nn.init.orthogonal_(layer.weight, gain)
                    nn.init.zeros_(layer.bias)
    actor = ProbabilisticActor(
        TensorDictModule(
            nn.Sequential(loc_net, AddStateIndependentNormalScale(action_dim, scale_lb=1e-8)),
            in_keys=["observation"],
            out_keys=["loc", "scale"],
        ),
        in_keys=["loc", "scale"],
        spec=env.full_action_spec_unbatched,
        distribution_class=TanhNormal,
        distribution_kwargs={
            "low": env.action_spec_unbatched.space.low,
            "high": env.action_spec_unbatched.space.high,
            "tanh_loc": False,
        },
        return_log_prob=True,
    )
    return actor, ValueOperator(value_net, in_keys=["observation"])


class ReferencePPO:
    """TorchRL's reference PPO pipeline; :meth:`batches` trains and hands out each collected batch.

    Args:
        config: the settings (:class:`ReferenceConfig`).
        seed: seeds torch and the environments.

    Example:
        >>> ppo = ReferencePPO(ReferenceConfig(frames_per_batch=8, total_frames=16, mini_batch_size=4, epochs=1), seed=0)
        >>> [batch.numel() for batch in ppo.batches()]
        [8, 8]
        >>> ppo.evaluation_policy()(TensorDict(observation=torch.zeros(3, 105))).get("action").shape
        torch.Size([3, 8])
    """

    def __init__(self, config: ReferenceConfig, seed: int):
        torch.manual_seed(seed)
        self.config = config
        self.env = make_reference_env(config, seed)
        self.actor, self.critic = make_reference_models(self.env, config.hidden, config.orthogonal_init)
        self.collector = Collector(
            self.env,
            self.actor,
            frames_per_batch=config.frames_per_batch,
            total_frames=config.total_frames,
            max_frames_per_traj=-1,
        )
        self.buffer = TensorDictReplayBuffer(
            storage=LazyTensorStorage(config.frames_per_batch),
            sampler=SamplerWithoutReplacement(),
            batch_size=config.mini_batch_size,
        )
        self.advantage = GAE(gamma=config.gamma, lmbda=config.lmbda, value_network=self.critic, average_gae=False)
        self.loss = ClipPPOLoss(
            self.actor,
            self.critic,
            clip_epsilon=config.clip_epsilon,
            entropy_bonus=config.entropy_bonus,
            entropy_coeff=config.entropy_coeff,
            critic_coeff=config.critic_coeff,
            loss_critic_type="l2",
            normalize_advantage=True,
        )
        self.optimizer = torch.optim.Adam(self.loss.parameters(), lr=config.lr, eps=1e-5)
        updates_per_batch = config.epochs * (config.frames_per_batch // config.mini_batch_size)
        self.total_updates = (config.total_frames // config.frames_per_batch) * updates_per_batch
        self.updates = 0
        self.collected_frames = 0

    def batches(self) -> Iterator[TensorDictBase]:
        """Yields each collected batch ``[T]`` (one env) or ``[N, T]``, then runs the PPO update on it when the
        consumer asks for the next one. Breaking out of the loop skips that batch's update and shuts the
        collector down, so the actor is the one updated on every batch before the last."""
        try:
            for data in self.collector:
                self.collected_frames += data.numel()
                yield data
                self.update(data)
                self.collector.update_policy_weights_()
        finally:
            self.collector.shutdown()

    def update(self, data: TensorDictBase) -> None:
        """``epochs`` passes of GAE (with the current critic) and shuffled minibatch steps over ``data``."""
        config = self.config
        for _ in range(config.epochs):
            with torch.no_grad():
                data = self.advantage(data)
            self.buffer.extend(data.reshape(-1))
            for minibatch in self.buffer:
                if config.anneal_lr:
                    alpha = max(0.0, 1.0 - self.updates / max(self.total_updates, 1))  # α = 1 − u / U
                    for group in self.optimizer.param_groups:
                        group["lr"] = config.lr * alpha  # lr_u = lr_0 · α
                losses = self.loss(minibatch)
                total = losses["loss_objective"] + losses["loss_critic"]
                if "loss_entropy" in losses.keys():
                    total = total + losses["loss_entropy"]
                self.optimizer.zero_grad(set_to_none=True)
                total.backward()
                if config.max_grad_norm is not None:
                    nn.utils.clip_grad_norm_(self.loss.parameters(), config.max_grad_norm)
                self.optimizer.step()
                self.updates += 1

    def evaluation_policy(self):
        """A callable ``td -> td`` for raw (unnormalised) observations ``[..., obs_dim]`` of any float dtype:
        normalises them with VecNorm's current statistics (TorchRL's ``VecNorm.to_observation_norm``), clips
        them to ±10 and writes the actor's ``"action"`` (its mean under ``ExplorationType.DETERMINISTIC``)."""
        vecnorm = next(t for t in self.env.transform if isinstance(t, VecNorm))
        norm = vecnorm.to_observation_norm()
        actor = self.actor

        @torch.no_grad()
        def policy(td: TensorDictBase) -> TensorDictBase:
            raw = TensorDict(observation=td.get("observation").to(torch.float64), batch_size=td.batch_size)
            obs = norm(raw).get("observation").clamp(-OBS_CLIP, OBS_CLIP).to(torch.float32)  # clip((o − μ) / σ)
            action = actor(TensorDict(observation=obs, batch_size=td.batch_size)).get("action")
            return td.set("action", action)

        return policy
