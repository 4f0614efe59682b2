"""Per-head value normalisation: the critic learns standardised values, GAE sees them in reward units.

Why: the K critic heads regress returns whose scales differ by orders of magnitude between components
(and drift by orders of magnitude during training: Ant's return goes from ~-100 to ~+3000). A plain
MSE on raw returns lets the largest head dominate the shared trunk's gradient and makes the critic's
effective step size depend on the reward scale. rl_games (``normalize_value: True``) and rsl_rl
(``empirical_normalization``) standardise value targets with running statistics; here the statistics
are kept per head (``[K]``), so each component is regressed on a unit scale.

The data flow, for ``value_norm = make_value_norm("running", K)``::

    critic_net(obs)                  -> v_n   [*B, K]   normalised units (what the loss regresses)
    Denormalize(value_norm)(v_n)     -> v     [*B, K]   v = v_n * sigma + mu   (what GAE bootstraps on)
    WeightedMultiGAE                 -> value_target, state_value in reward units
    training/loop.py, every epoch    -> both rewritten as (x - mu) / sigma for the loss (a copy: the
                                        batch keeps reward units); the statistics absorb each batch once

The statistics are TorchRL's (``RunningValueNorm``: exact running mean/variance as rl_games' running
mean-std; or ``PopArtValueNorm``'s EMA), with ``shape=K``: one mean and one variance per head. As in
rl_games, the network's output is not rescaled when the statistics move (PopArt's output-preserving
update is not applied): they are updated once per batch from ~10^3 targets, so the jump is small.
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import PopArtValueNorm, RunningValueNorm
from torchrl.modules.value_norm import ValueNorm

VALUE_NORMS = {"running": RunningValueNorm, "popart": PopArtValueNorm}


def make_value_norm(kind: str | None, num_heads: int) -> ValueNorm | None:
    """TorchRL's value normaliser with per-head statistics (``shape=K``): ``"running"`` (exact Welford
    mean/variance, :class:`~torchrl.modules.RunningValueNorm`), ``"popart"`` (debiased EMA,
    :class:`~torchrl.modules.PopArtValueNorm`), or ``None``/``False`` (no normalisation).

    Example:
        >>> make_value_norm("running", 3).mean.shape
        torch.Size([3])
    """
    if not kind:
        return None
    kind = "running" if kind is True else kind  # ppo.value_norm=true: the default kind
    if kind not in VALUE_NORMS:
        raise ValueError(f"unknown ppo.value_norm {kind!r}; choose from {sorted(VALUE_NORMS)} or null")
    return VALUE_NORMS[kind](shape=num_heads)


class Denormalize(nn.Module):
    """``v_n [*B, K] -> v = v_n * sigma + mu [*B, K]`` with a TorchRL :class:`~torchrl.modules.ValueNorm`'s statistics.

    Example:
        >>> import torch
        >>> norm = make_value_norm("running", 2)
        >>> norm.update(torch.tensor([[0.0, 100.0], [2.0, 300.0]]))
        >>> Denormalize(norm)(torch.tensor([[1.0, -1.0]]))
        tensor([[  2., 100.]])
    """

    def __init__(self, value_norm: ValueNorm):
        super().__init__()
        self.value_norm = value_norm

    def forward(self, normalized: torch.Tensor) -> torch.Tensor:
        return self.value_norm.denormalize(normalized)  # v = v_n * sigma + mu


def denormalized_critic(critic: TensorDictModule, value_norm: ValueNorm) -> TensorDictModule:
    """The critic as GAE must see it: ``critic``'s normalised output mapped to reward units.

    Shares every parameter with ``critic`` (the loss trains ``critic``; GAE reads this one), and its
    ``state_dict`` holds the network *and* the statistics, so a checkpoint of it is complete.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> net = TensorDictModule(torch.nn.Linear(3, 2), in_keys=["observation"], out_keys=["state_value"])
        >>> norm = make_value_norm("running", 2)
        >>> norm.update(torch.tensor([[0.0, 10.0], [2.0, 30.0]]))
        >>> td = denormalized_critic(net, norm)(TensorDict({"observation": torch.zeros(4, 3)}, [4]))
        >>> td["state_value"].shape
        torch.Size([4, 2])
    """
    return TensorDictModule(
        nn.Sequential(critic.module, Denormalize(value_norm)),
        in_keys=list(critic.in_keys),
        out_keys=list(critic.out_keys),
    )
