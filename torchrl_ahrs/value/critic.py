"""Critics with one value output per reward component."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


def make_mlp(
    in_features: int, hidden_sizes: Sequence[int], out_features: int, activation: str = "tanh"
) -> nn.Sequential:
    """A plain MLP ``in -> hidden... -> out`` with orthogonal init (PPO's usual choice)."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"unknown activation {activation!r}; choose from {sorted(ACTIVATIONS)}")
    layers: list[nn.Module] = []
    width = in_features
    for hidden in hidden_sizes:
        layers += [_orthogonal(nn.Linear(width, hidden), math.sqrt(2)), ACTIVATIONS[activation]()]
        width = hidden
    layers.append(_orthogonal(nn.Linear(width, out_features), 1.0))
    return nn.Sequential(*layers)


def _orthogonal(layer: nn.Linear, gain: float) -> nn.Linear:
    nn.init.orthogonal_(layer.weight, gain)
    nn.init.zeros_(layer.bias)
    return layer


class HeadwiseLinear(nn.Module):
    """K independent linear layers applied in one batched contraction.

    Input ``[*B, in]`` shared by all heads (``shared_input=True``) or ``[*B, K, in]``; output
    ``[*B, K, out]``.

    Example:
        >>> layer = HeadwiseLinear(num_heads=3, in_features=4, out_features=2, shared_input=True)
        >>> layer(torch.zeros(5, 7, 4)).shape
        torch.Size([5, 7, 3, 2])
    """

    def __init__(self, num_heads: int, in_features: int, out_features: int, gain: float = 1.0, shared_input=False):
        super().__init__()
        self.shared_input = shared_input
        self.weight = nn.Parameter(torch.empty(num_heads, in_features, out_features))
        self.bias = nn.Parameter(torch.zeros(num_heads, out_features))
        for head in range(num_heads):
            nn.init.orthogonal_(self.weight.data[head], gain)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.shared_input:
            return torch.einsum("...i,kio->...ko", x, self.weight) + self.bias  # y_k = x W_k + b_k
        return torch.einsum("...ki,kio->...ko", x, self.weight) + self.bias  # y_k = x_k W_k + b_k


class MultiHeadCritic(nn.Module):
    """State-value network with K outputs, one per reward component.

    ``separate_heads=False``: a shared trunk whose last layer has K outputs (cheap, shared features).
    ``separate_heads=True``: K independent MLPs evaluated as one batched computation (no loop over K).
    ``anchor_head=True``: one more value, from an MLP of its own (``anchor_hidden_sizes`` wide), appended as column
    K + 1: the anchored mix's value of the summed reward (:class:`~torchrl_ahrs.value.WeightedMultiGAE` with
    ``anchored=True``), learnt apart from the K heads as PPO's one critic is.

    Args:
        in_features: observation size.
        num_heads: K.
        hidden_sizes: widths of the hidden layers.
        activation: ``"tanh"``, ``"relu"`` or ``"elu"``.
        separate_heads: one MLP per component instead of a shared trunk.
        anchor_head: append the anchor's value from a separate MLP.
        anchor_hidden_sizes: the anchor's widths; ``None``: ``hidden_sizes``. The anchor is PPO's critic, so its
            widths are PPO's, while the K heads, read only through a schedule's departures from equal weights, may
            be narrower (``model.component_hidden_sizes``).

    Shapes: ``observation [*B, in] -> state_value [*B, K]`` (``[*B, K + 1]`` with ``anchor_head``).

    Example:
        >>> critic = MultiHeadCritic(in_features=8, num_heads=4, hidden_sizes=[32, 32])
        >>> critic(torch.zeros(10, 8)).shape
        torch.Size([10, 4])
        >>> MultiHeadCritic(8, 4, [32], separate_heads=True)(torch.zeros(10, 8)).shape
        torch.Size([10, 4])
        >>> MultiHeadCritic(8, 4, [32], anchor_head=True)(torch.zeros(10, 8)).shape
        torch.Size([10, 5])
        >>> MultiHeadCritic(8, 4, [16], anchor_head=True, anchor_hidden_sizes=[32]).anchor[0].out_features
        32
    """

    def __init__(
        self,
        in_features: int,
        num_heads: int,
        hidden_sizes: Sequence[int] = (256, 256),
        activation: str = "tanh",
        separate_heads: bool = False,
        anchor_head: bool = False,
        anchor_hidden_sizes: Sequence[int] | None = None,
    ):
        super().__init__()
        if num_heads < 1:
            raise ValueError(f"num_heads must be >= 1, got {num_heads}")
        self.num_heads = num_heads
        self.separate_heads = separate_heads
        # built first: for a seed, the anchor starts from the weights PPO's one-head critic starts from (the same
        # draws at the same point), so an anchored method at equal weights begins where PPO begins
        anchor_sizes = hidden_sizes if anchor_hidden_sizes is None else anchor_hidden_sizes
        self.anchor = make_mlp(in_features, anchor_sizes, 1, activation) if anchor_head else None
        if not separate_heads:
            self.net = make_mlp(in_features, hidden_sizes, num_heads, activation)
            return
        widths = [in_features, *hidden_sizes]
        layers: list[nn.Module] = []
        for depth, (width_in, width_out) in enumerate(zip(widths[:-1], widths[1:], strict=True)):
            layer = HeadwiseLinear(num_heads, width_in, width_out, math.sqrt(2), shared_input=depth == 0)
            layers += [layer, ACTIVATIONS[activation]()]
        layers.append(HeadwiseLinear(num_heads, widths[-1], 1, 1.0, shared_input=not hidden_sizes))
        self.net = nn.Sequential(*layers)

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        values = self.net(observation)
        values = values.squeeze(-1) if self.separate_heads else values  # [*B, K]
        if self.anchor is None:
            return values
        return torch.cat([values, self.anchor(observation)], dim=-1)  # [*B, K + 1]: V_1 .. V_K, V_Σ
