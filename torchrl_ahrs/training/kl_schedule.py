"""Adaptive learning rate from the policy's KL divergence (the rule of rsl_rl and rl_games).

After each minibatch's loss, before its optimiser step::

    KL = E_s[ KL( N(mu_old, sigma_old) || N(mu_new, sigma_new) ) ]      (summed over action dims)
    KL > 2 * target   ->  lr <- max(lr / 1.5, min_lr)
    KL < target / 2   ->  lr <- min(lr * 1.5, max_lr)

The factors 2, 1/2 and 1.5 are those of rsl_rl's ``PPO.update`` (``schedule="adaptive"``,
``desired_kl=0.01``, lr bounded to [1e-5, 1e-2]) and rl_games' ``AdaptiveScheduler``
(``kl_threshold``: 0.008 in its ``mujoco/ant_envpool.yaml``, bounds [1e-6, 1e-2]).

The KL is the closed form between the Gaussians *before* the tanh squash: KL is invariant under a
bijection applied to both distributions, so it equals the KL of the squashed (TanhNormal) policies.
``mu_old, sigma_old`` are the ``loc``/``scale`` the collector's policy wrote into the batch.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn


def gaussian_kl(loc_old: torch.Tensor, scale_old: torch.Tensor, loc_new: torch.Tensor, scale_new: torch.Tensor):
    """``KL(N(loc_old, scale_old) || N(loc_new, scale_new))`` summed over the last (action) dim: ``[*B, A] -> [*B]``.

    Example:
        >>> import torch
        >>> gaussian_kl(torch.zeros(1, 2), torch.ones(1, 2), torch.ones(1, 2), torch.ones(1, 2))
        tensor([1.])
    """
    log_ratio = torch.log(scale_new / scale_old)  # log(sigma_1 / sigma_0)
    spread = (scale_old**2 + (loc_old - loc_new) ** 2) / (2.0 * scale_new**2)  # (s0^2 + (m0 - m1)^2) / (2 s1^2)
    return (log_ratio + spread - 0.5).sum(-1)  # KL = sum_a [log(s1/s0) + spread - 1/2]


class AdaptiveKLLR:
    """Trainer ``process_loss`` hook: adapts the optimiser's learning rate to keep KL near ``target``.

    Args:
        optimizer: its every param group gets the new learning rate.
        policy_net: ``observation [*B, O] -> (loc [*B, A], scale [*B, A])``, the actor's Gaussian before
            its tanh squash (the network whose output the collector stored as ``"loc"``/``"scale"``).
        target: desired KL per minibatch.
        min_lr, max_lr: bounds of the learning rate.
        factor: multiplicative step (1.5 in rsl_rl and rl_games).

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from tensordict.nn import AddStateIndependentNormalScale
        >>> net = torch.nn.Sequential(torch.nn.Linear(3, 2), AddStateIndependentNormalScale(2, init_value=0.0))
        >>> opt = torch.optim.Adam(net.parameters(), lr=1e-3)
        >>> hook = AdaptiveKLLR(opt, net, target=0.01)
        >>> obs = torch.zeros(5, 3)
        >>> with torch.no_grad():
        ...     loc, scale = net(obs)
        >>> batch = TensorDict({"observation": obs, "loc": loc, "scale": scale}, [5])
        >>> _ = hook(batch, TensorDict({}, []))  # KL = 0 < target / 2: the rate grows by 1.5
        >>> round(opt.param_groups[0]["lr"], 6)
        0.0015
    """

    def __init__(
        self,
        optimizer: torch.optim.Optimizer,
        policy_net: nn.Module,
        target: float = 0.01,
        min_lr: float = 1e-5,
        max_lr: float = 1e-2,
        factor: float = 1.5,
        observation_key: str = "observation",
    ):
        if target <= 0:
            raise ValueError(f"the KL target must be positive, got {target}")
        self.optimizer, self.policy_net = optimizer, policy_net
        self.target, self.min_lr, self.max_lr, self.factor = target, min_lr, max_lr, factor
        self.observation_key = observation_key
        self.last_kl = 0.0

    @property
    def lr(self) -> float:
        return self.optimizer.param_groups[0]["lr"]

    @torch.no_grad()
    def __call__(self, sub_batch: TensorDictBase, losses: TensorDictBase) -> TensorDictBase:
        loc, scale = self.policy_net(sub_batch.get(self.observation_key))
        kl = gaussian_kl(sub_batch.get("loc"), sub_batch.get("scale"), loc, scale).mean().item()
        self.last_kl = kl
        lr = self.lr
        if kl > 2.0 * self.target:
            lr = max(lr / self.factor, self.min_lr)  # too far from the collecting policy: smaller steps
        elif kl < 0.5 * self.target:
            lr = min(lr * self.factor, self.max_lr)  # barely moved: larger steps
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        losses.set("kl", torch.tensor(kl))
        losses.set("lr", torch.tensor(lr))
        return losses

    def state_dict(self) -> dict[str, Any]:
        return {"lr": self.lr}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = state_dict["lr"]

    def register(self, trainer, name: str = "adaptive_kl_lr") -> None:
        trainer.register_op("process_loss", self)
        trainer.register_module(name, self)
