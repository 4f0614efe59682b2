"""Adaptive learning rate from the policy's KL divergence (the rule of rsl_rl and rl_games).

After each minibatch's loss, before its optimiser step (:func:`torchrl_ahrs.training.loop.learn` calls it)::

    KL = E_s[ KL( N(mu_old, sigma_old) || N(mu_new, sigma_new) ) ]      (summed over action dims)
    KL > 2 * target   ->  lr <- max(lr / 1.5, min_lr)
    KL < target / 2   ->  lr <- min(lr * 1.5, max_lr)

The factors 2, 1/2 and 1.5 are those of rsl_rl's ``PPO.update`` (``schedule="adaptive"``,
``desired_kl=0.01``, lr bounded to [1e-5, 1e-2]) and rl_games' ``AdaptiveScheduler``
(``kl_threshold``: 0.008 in its ``mujoco/ant_envpool.yaml``, bounds [1e-6, 1e-2]).

The KL is the ``"kl"`` output of :class:`~torchrl_ahrs.training.loss.HybridClipPPOLoss` built with ``kl=True``:
the closed form between the Gaussians *before* the tanh squash, from the ``loc``/``scale`` the collector's policy
wrote into the batch to those of the loss's own actor pass, as rsl_rl reads it from its loss forward pass (KL is
invariant under a bijection applied to both distributions, so it equals the KL of the squashed policies).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase


class AdaptiveKLLR:
    """``(minibatch, losses) -> losses``: adapts the optimiser's learning rate to keep KL near ``target``.

    The rate lives in the optimiser's param groups (and is checkpointed with the optimiser); this rule
    only changes it.

    Args:
        optimizer: its every param group gets the new learning rate.
        target: desired KL per minibatch.
        min_lr, max_lr: bounds of the learning rate.
        factor: multiplicative step (1.5 in rsl_rl and rl_games).
        kl_key: the loss output holding the minibatch's KL (``HybridClipPPOLoss`` writes ``"kl"``).

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> opt = torch.optim.Adam([torch.nn.Parameter(torch.zeros(2))], lr=1e-3)
        >>> hook = AdaptiveKLLR(opt, target=0.01)
        >>> _ = hook(TensorDict({}, []), TensorDict({"kl": torch.tensor(0.001)}, []))  # KL < target / 2: x 1.5
        >>> round(opt.param_groups[0]["lr"], 6)
        0.0015
    """

    def __init__(
        self,
        optimizer: torch.optim.Optimizer,
        target: float = 0.01,
        min_lr: float = 1e-5,
        max_lr: float = 1e-2,
        factor: float = 1.5,
        kl_key: str = "kl",
    ):
        if target <= 0:
            raise ValueError(f"the KL target must be positive, got {target}")
        self.optimizer = optimizer
        self.target, self.min_lr, self.max_lr, self.factor = target, min_lr, max_lr, factor
        self.kl_key = kl_key

    @property
    def lr(self) -> float:
        return self.optimizer.param_groups[0]["lr"]

    @torch.no_grad()
    def __call__(self, sub_batch: TensorDictBase, losses: TensorDictBase) -> TensorDictBase:
        if self.kl_key not in losses.keys():
            raise KeyError(f"AdaptiveKLLR reads the loss output {self.kl_key!r}, which the loss did not write")
        kl = losses.get(self.kl_key).item()
        lr = self.lr
        if kl > 2.0 * self.target:
            lr = max(lr / self.factor, self.min_lr)  # too far from the collecting policy: smaller steps
        elif kl < 0.5 * self.target:
            lr = min(lr * self.factor, self.max_lr)  # barely moved: larger steps
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        losses.set("lr", torch.tensor(lr))
        return losses
