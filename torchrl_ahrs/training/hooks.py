"""TorchRL trainer hooks that make the plain ``Trainer`` run PPO with a weighted multi-GAE.

One iteration of :class:`torchrl.trainers.Trainer` with these hooks::

    batch [N, T] from the collector
    for epoch in num_epochs:
        PPOMinibatches.pre_epoch      advantage_components, value_target, advantage = WeightedMultiGAE(batch)
        for minibatch in num_minibatches:
            PPOMinibatches.next_minibatch   -> HybridClipPPOLoss -> Adam step (clipped gradient)
    ObservationNormUpdate             running mean/var absorb the batch just trained on
    LinearLRDecay                     lr_i = lr_0 * (1 - frames_i / total_frames)
    ComponentReturnLog                every component's finished-episode return, every weight
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.trainers import Trainer, TrainerHookBase

from torchrl_ahrs.rewards.components import TOTAL, finished_episode_returns
from torchrl_ahrs.training.models import RunningNorm
from torchrl_ahrs.value import WeightedMultiGAE


class PPOMinibatches(TrainerHookBase):
    """Recomputes the advantage with the current critic before every epoch and serves minibatches.

    Each epoch visits every transition exactly once, in a fresh random order (sampling without
    replacement), which is what PPO's epochs mean. Register with ``optim_steps_per_batch =
    num_minibatches`` on the trainer.

    Args:
        estimator: ``batch -> batch`` writing advantage and value targets (``WeightedMultiGAE``).
        num_minibatches: minibatches per epoch.
        seed: the shuffling generator's seed.
        keys: the entries the loss (and the per-minibatch hooks) read; only these are gathered into
            minibatches (the batch also holds ``next``, ``info``, episode accumulators... that the loss
            never reads, and gathering them cost more than the loss step itself at small minibatches).
            ``None`` gathers everything.
        post_estimate: ``(batch, new_batch: bool) -> batch`` applied after each epoch's estimate, e.g.
            :class:`~torchrl_ahrs.training.value_norm.ValueTargetNormalization`; ``new_batch`` is true on
            the first epoch of each collected batch.
        device: where the permutation is drawn (the batch's device: no index copy per epoch; a CUDA
            generator draws other permutations than the CPU one for the same seed).

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> hook = PPOMinibatches(estimator=lambda td: td, num_minibatches=4, seed=0)
        >>> batch = TensorDict({"x": torch.arange(16.0).reshape(2, 8)}, [2, 8])
        >>> _ = hook.pre_epoch(batch)
        >>> sorted(torch.cat([hook.next_minibatch(batch)["x"] for _ in range(4)]).tolist()) == list(range(16))
        True
    """

    def __init__(self, estimator, num_minibatches: int, seed: int = 0, keys=None, post_estimate=None, device="cpu"):
        if num_minibatches < 1:
            raise ValueError(f"num_minibatches must be at least 1, got {num_minibatches}")
        self.estimator = estimator
        self.num_minibatches = num_minibatches
        self.device = torch.device(device)
        self.generator = torch.Generator(device=self.device).manual_seed(seed)
        self.keys = list(keys) if keys is not None else None
        self.post_estimate = post_estimate
        self._minibatches: list[TensorDictBase] = []
        self._new_batch = True

    def pre_epoch(self, batch: TensorDictBase) -> TensorDictBase:
        with torch.no_grad():
            batch = self.estimator(batch)
        new_batch, self._new_batch = self._new_batch, False
        # select: a new tensordict sharing the tensors, so post_estimate's rewrites stay out of `batch`
        selected = batch.select(*self.keys, strict=False) if self.keys is not None else batch.clone(False)
        if self.post_estimate is not None:
            selected = self.post_estimate(selected, new_batch)
        flat = selected.reshape(-1)
        order = torch.randperm(flat.shape[0], generator=self.generator, device=self.device)
        sizes = [len(chunk) for chunk in order.chunk(self.num_minibatches)]
        # one gather per epoch, then contiguous views: a gather per minibatch costs a TensorDict index per key
        self._minibatches = list(flat[order].split(sizes, 0))
        return batch

    def start_batch(self) -> None:
        """``pre_optim_steps``: a new collected batch begins (its first epoch comes next)."""
        self._new_batch = True

    def next_minibatch(self, batch: TensorDictBase) -> TensorDictBase:
        if not self._minibatches:
            raise StopIteration
        return self._minibatches.pop()

    def state_dict(self) -> dict[str, Any]:
        return {"generator": self.generator.get_state()}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.generator.set_state(state_dict["generator"])

    def register(self, trainer: Trainer, name: str = "ppo_minibatches") -> None:
        trainer.register_op("pre_optim_steps", self.start_batch)
        trainer.register_op("pre_epoch", self.pre_epoch)
        trainer.register_op("process_optim_batch", self.next_minibatch)
        trainer.register_module(name, self)


class ObservationNormUpdate(TrainerHookBase):
    """Feeds each batch's observations to a :class:`RunningNorm` *after* the PPO update on it.

    Updating after the update keeps the log-probabilities stored at collection time consistent with
    the policy being optimised; the next collection then sees the new statistics.
    """

    def __init__(self, obs_norm: RunningNorm, in_key: str = "observation"):
        self.obs_norm = obs_norm
        self.in_key = in_key
        self._pending: torch.Tensor | None = None

    def remember(self, batch: TensorDictBase) -> TensorDictBase:
        self._pending = batch.get(self.in_key)
        return batch

    def apply(self) -> None:
        if self._pending is not None:
            self.obs_norm.update(self._pending)
            self._pending = None

    def state_dict(self) -> dict[str, Any]:
        return {}  # the statistics are buffers of the networks, saved with them

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        pass

    def register(self, trainer: Trainer, name: str = "obs_norm") -> None:
        trainer.register_op("batch_process", self.remember)
        trainer.register_op("post_steps", self.apply)
        trainer.register_module(name, self)


class LinearLRDecay(TrainerHookBase):
    """``lr = lr_0 * max(0, 1 - frames / total_frames)``, applied after every iteration."""

    def __init__(self, optimizer: torch.optim.Optimizer, total_frames: int):
        self.optimizer = optimizer
        self.total_frames = total_frames
        self.initial_lrs = [group["lr"] for group in optimizer.param_groups]
        self.trainer: Trainer | None = None

    def __call__(self) -> None:
        if self.trainer is None:  # called directly: there are no frames to decay against
            raise RuntimeError("LinearLRDecay runs as a trainer hook: register(trainer) first")
        progress = min(1.0, self.trainer.collected_frames / self.total_frames)
        for group, initial_lr in zip(self.optimizer.param_groups, self.initial_lrs, strict=True):
            group["lr"] = initial_lr * (1.0 - progress)  # lr_i = lr_0 (1 - f_i / F)

    def state_dict(self) -> dict[str, Any]:
        return {"initial_lrs": self.initial_lrs}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.initial_lrs = state_dict["initial_lrs"]

    def register(self, trainer: Trainer, name: str = "lr_decay") -> None:
        self.trainer = trainer
        trainer.register_op("post_steps", self)
        trainer.register_module(name, self)


class ComponentReturnLog(TrainerHookBase):
    """Logs each component's reward and episode return, and the weights, once per batch.

    Keys: ``reward/<c>`` (mean reward per step over the batch, logged every iteration, so long
    episodes show progress before the first one ends), ``return/<c>`` and ``return/total`` (means over
    the episodes that ended in this batch, when any did), ``episodes``, ``weight/<c>``,
    ``frames_per_second``.
    """

    def __init__(self, components: Sequence[str], estimator: WeightedMultiGAE):
        self.components = list(components)
        self.tracked = self.components + ([TOTAL] if TOTAL not in self.components else [])
        self.estimator = estimator
        self.last_time = time.perf_counter()
        self.latest: dict[str, float] = {}

    def __call__(self, batch: TensorDictBase) -> dict[str, float]:
        now = time.perf_counter()
        metrics = {"frames_per_second": batch.numel() / max(now - self.last_time, 1e-9)}
        self.last_time = now
        for name in self.tracked:
            metrics[f"reward/{name}"] = batch.get(("next", "reward", name)).mean().item()
        returns = finished_episode_returns(batch, self.tracked)  # [M, K+1]
        if returns.shape[0]:
            metrics["episodes"] = float(returns.shape[0])
            for name, column in zip(self.tracked, returns.mean(0).tolist(), strict=True):
                metrics[f"return/{name}"] = column
        for name, weight in zip(self.components, self.estimator.weights.tolist(), strict=True):
            metrics[f"weight/{name}"] = weight
        self.latest.update(metrics)
        return metrics

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        pass

    def register(self, trainer: Trainer, name: str = "component_returns") -> None:
        trainer.register_op("pre_steps_log", self)
        trainer.register_module(name, self)


class ComponentShareLog:
    """Logs each component's effective share of the mixed advantage, ``share/<c>``, once per iteration.

    Registered at ``post_optim_complete_log`` (after the epochs, before the ``post_steps`` checkpoint, so
    an interrupted and resumed run logs the same rows as an uninterrupted one), it reads the estimator's
    ``shares [K]``, ``w_k std(A'_k) / sum_j w_j std(A'_j)`` from the last advantage computation of the
    iteration.

    Example:
        >>> import torch
        >>> class Estimator:
        ...     shares = torch.tensor([0.25, 0.75])
        >>> ComponentShareLog(["a", "b"], Estimator())(None)
        {'share/a': 0.25, 'share/b': 0.75}
    """

    def __init__(self, components: Sequence[str], estimator: Any):
        self.components = list(components)
        self.estimator = estimator

    def __call__(self, batch: TensorDictBase | None) -> dict[str, float]:
        shares = self.estimator.shares.tolist()
        return {f"share/{name}": share for name, share in zip(self.components, shares, strict=True)}

    def after_epochs(self, optim_steps: int, average_losses: TensorDictBase | None) -> dict[str, float]:
        """The ``post_optim_complete_log`` hook: ``share/<c>`` of this iteration's update."""
        return self(None)

    def register(self, trainer: Trainer) -> None:
        trainer.register_op("post_optim_complete_log", self.after_epochs)


def loss_metrics(optim_steps: int, average_losses: TensorDictBase | None) -> dict[str, float] | None:
    """PPO diagnostics averaged over the iteration's minibatches, under ``train/``."""
    if average_losses is None:
        return None
    return {f"train/{key}": value.mean().item() for key, value in average_losses.items() if value.numel()}


class FiniteGuard:
    """Stops training with a clear error when a batch carries NaN or inf in observations or rewards.

    A single non-finite reward poisons every advantage through the GAE recursion and the running
    observation statistics forever after, so the run is stopped at the first bad batch, naming the
    entry and how many values were bad, instead of training on garbage.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> guard = FiniteGuard(["a"])
        >>> batch = TensorDict({"observation": torch.zeros(2, 3),
        ...                     "next": {"reward": {"a": torch.tensor([[1.0], [float("nan")]])}}}, [2])
        >>> guard(batch)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        FloatingPointError: 1 non-finite value(s) in ('next', 'reward', 'a') of the collected batch; ...
    """

    def __init__(self, components: Sequence[str], observation_key: str = "observation"):
        self.keys = [observation_key, ("next", observation_key)] + [("next", "reward", name) for name in components]

    def __call__(self, batch: TensorDictBase) -> TensorDictBase:
        for key in self.keys:
            values = batch.get(key, None)
            if values is None:
                continue
            bad = (~torch.isfinite(values)).sum().item()
            if bad:
                raise FloatingPointError(
                    f"{bad} non-finite value(s) in {key} of the collected batch; the environment produced NaN/inf "
                    "(check the task's reward terms and physics stability); training stopped before using it"
                )
        return batch
