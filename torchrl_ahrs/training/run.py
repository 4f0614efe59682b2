"""What :func:`~torchrl_ahrs.training.loop.learn` iterates with, built by the caller (the app from the Hydra config,
or by hand): the parts (:class:`TrainingRun`), the numbers it reads (:class:`LoopSettings`) and its counters
(:class:`Progress`, checkpointed as ``"state"``). Nothing here runs during an iteration; the iteration itself is
:mod:`torchrl_ahrs.training.loop`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from tensordict import TensorDictBase

from torchrl_ahrs.training.models import RunningNorm

# when the advantages and value targets are estimated: before every PPO epoch with the critic as it is then
# (TorchRL's sota PPO; "What matters in on-policy RL" recommends it), or once per batch before the first epoch
# with the collecting critic (CleanRL, rsl_rl, rl_games): E - 1 fewer critic passes over the batch
ADVANTAGE_PASSES = ("every_epoch", "once_per_batch")
# the parameters whose rate the adaptive-KL rule sets: all (rsl_rl: actor and critic) | actor (the critic's
# group is built with kl_adaptive=False and keeps its rate)
KL_ADAPTS = ("all", "actor")


@dataclass(frozen=True)
class LoopSettings:
    """The numbers :func:`~torchrl_ahrs.training.loop.learn` reads (the app fills them from ``trainer.*`` and
    ``ppo.kl_target``; TorchRL's names).

    ``anneal_lr``: ``lr_i = lr_0 (1 - frames_i / total_frames)`` after every iteration; ``kl_target``: instead,
    :func:`~torchrl_ahrs.training.loop.adaptive_kl_lr` sets the rate from every minibatch's KL (the loss must be
    built with ``kl=True``); ``max_grad_norm``: the global gradient norm is clipped to it (None: not clipped);
    ``advantage_pass``: ``"every_epoch"`` re-estimates advantages and value targets with the current critic
    before each epoch, ``"once_per_batch"`` only before the first (the same update with one epoch; a value clip
    then clips around the collecting critic's values, as rl_games' does, not the epoch's); ``compile``: the
    loss's forward (actor, critic and the PPO terms) runs through ``torch.compile`` (inductor), compiled at the
    first minibatch; ``collection_threads``: torch's intra-op threads while the collector steps the environments
    (``None``: the update's, those set when the loop starts), restored for the update.

    Example:
        >>> LoopSettings(total_frames=4096, num_minibatches=0)
        Traceback (most recent call last):
        ...
        ValueError: num_minibatches must be at least 1, got 0
    """

    total_frames: int
    num_epochs: int = 5
    num_minibatches: int = 4
    max_grad_norm: float | None = 1.0
    anneal_lr: bool = True
    kl_target: float | None = None
    advantage_pass: str = "every_epoch"
    compile: bool = False
    collection_threads: int | None = None

    def __post_init__(self):
        for name in ("total_frames", "num_epochs", "num_minibatches"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.collection_threads is not None and self.collection_threads < 1:
            raise ValueError(f"collection_threads must be at least 1, got {self.collection_threads}")
        if self.kl_target is not None and self.kl_target <= 0:
            raise ValueError(f"the KL target must be positive, got {self.kl_target}")
        if self.advantage_pass not in ADVANTAGE_PASSES:
            raise ValueError(
                f"advantage_pass must be one of {', '.join(ADVANTAGE_PASSES)}, got {self.advantage_pass!r}"
            )


@dataclass
class Progress:
    """Frames collected and optimiser steps taken so far: the loop's counters, checkpointed as ``"state"``."""

    collected_frames: int = 0
    optim_steps: int = 0

    def state_dict(self) -> dict[str, int]:
        return {"collected_frames": self.collected_frames, "optim_steps": self.optim_steps}

    def load_state_dict(self, state_dict: dict[str, int]) -> None:
        self.collected_frames = int(state_dict["collected_frames"])
        self.optim_steps = int(state_dict["optim_steps"])


@dataclass
class TrainingRun:
    """Everything :func:`~torchrl_ahrs.training.loop.learn` iterates with, built and (on resume) loaded by the
    caller.

    Args:
        collector: a TorchRL collector yielding batches ``[N, T]`` (``update_policy_weights_``, ``shutdown``).
        loss: the PPO loss (:class:`~torchrl_ahrs.training.loss.HybridClipPPOLoss`) on the mixed advantage.
        estimator: :class:`~torchrl_ahrs.value.WeightedMultiGAE`: ``weights [K]``, ``shares [K]``.
        optimizer: over the loss's parameters.
        scheduler: a :class:`~torchrl_ahrs.scheduling.RuleScheduler` (``observe_batch``, ``step``, ``close``).
        logger: a TorchRL logger (``log_scalar``).
        settings: :class:`LoopSettings`.
        generator: draws the minibatch permutations (on the batch's device).
        observation_norms: ``(normaliser, observation key)`` pairs updated after each update.
        value_norm: the critic heads' TorchRL ``ValueNorm`` (``ppo.value_norm``): the loss regresses value targets
            standardised with it (:mod:`~torchrl_ahrs.training.value_norm`), GAE reads the critic in reward units.
        augment: applied to each minibatch before the loss, ``[B] -> [B']`` (``ppo.mirror``: the minibatch and
            its mirror image, :class:`~torchrl_ahrs.envs.common.mirror.MirrorAugmentation`); ``None``: as drawn.
        after_iteration: called in this order as ``after(batch, metrics)`` once the iteration's scalars are
            logged (the app's: the console line, the video clip, the checkpoint, which is last so that it holds
            the state the next iteration starts from).
        after_failure: called when an :class:`~torchrl_ahrs.rewards.auxiliary.AuxiliaryRewardError` stops the
            run, before the collector shuts down (the app's: the checkpoint of what was learnt so far).
        progress: the loop's counters (loaded on resume).

    Example:
        >>> import tempfile, torch
        >>> from tensordict.nn import NormalParamExtractor, TensorDictModule
        >>> from torchrl.collectors import Collector
        >>> from torchrl.envs import TransformedEnv
        >>> from torchrl.modules import MLP, ProbabilisticActor, TanhNormal
        >>> from torchrl.record.loggers import CSVLogger
        >>> from torchrl_ahrs import ComponentRewardSum, HybridClipPPOLoss, MultiHeadCritic, RewardComponents
        >>> from torchrl_ahrs import RandomSelector, RuleScheduler, load_repository
        >>> from torchrl_ahrs.envs.tasks.point_reach import PointReachEnv
        >>> from torchrl_ahrs.training.loop import learn
        >>> names = ["distance", "arrival", "ctrl"]
        >>> env = TransformedEnv(PointReachEnv(num_envs=4, max_episode_steps=8),
        ...     RewardComponents(names, term_keys={c: ("info", f"reward_{c}") for c in names}))
        >>> _ = env.append_transform(ComponentRewardSum([*names, "total"]))
        >>> actor = ProbabilisticActor(TensorDictModule(torch.nn.Sequential(MLP(6, 4, num_cells=[16]),
        ...     NormalParamExtractor()), ["observation"], ["loc", "scale"]), in_keys=["loc", "scale"],
        ...     distribution_class=TanhNormal, return_log_prob=True)
        >>> critic = TensorDictModule(MultiHeadCritic(6, 3, hidden_sizes=[16]), ["observation"], ["state_value"])
        >>> loss = HybridClipPPOLoss(actor, critic, components=names).make_value_estimator(gamma=0.99, lmbda=0.95)
        >>> scheduler = RuleScheduler(loss.value_estimator, selector=RandomSelector(load_repository(), seed=0),
        ...                           interval=1)
        >>> run = TrainingRun(Collector(env, actor, frames_per_batch=64, total_frames=128), loss,
        ...     loss.value_estimator, torch.optim.Adam(loss.parameters(), lr=3e-4), scheduler,
        ...     CSVLogger("demo", tempfile.mkdtemp()), LoopSettings(total_frames=128, num_epochs=2, num_minibatches=2))
        >>> metrics = learn(run)
        >>> run.progress.state_dict(), sorted(metrics)[:3]
        ({'collected_frames': 128, 'optim_steps': 8}, ['episodes', 'frames_per_second', 'return/arrival'])
    """

    collector: Any
    loss: Any
    estimator: Any
    optimizer: torch.optim.Optimizer
    scheduler: Any
    logger: Any
    settings: LoopSettings
    generator: torch.Generator = field(default_factory=lambda: torch.Generator().manual_seed(0))
    observation_norms: Sequence[tuple[RunningNorm, str]] = ()
    value_norm: Any = None
    augment: Callable[[TensorDictBase], TensorDictBase] | None = None
    after_iteration: Sequence[Callable[[TensorDictBase, dict[str, float]], Any]] = ()
    after_failure: Callable[[], Any] | None = None
    progress: Progress = field(default_factory=Progress)
