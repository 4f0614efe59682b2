"""Pure tensor functions behind :class:`~torchrl_ahrs.value.WeightedMultiGAE`."""

from __future__ import annotations

import torch


def normalize_components(advantages: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """Standardises each component's advantage over every batch entry: ``[*B, K] -> [*B, K]``.

    Without it, a component whose rewards are 100x larger dominates the mix whatever its weight;
    with it, the weights alone set each component's share of the policy gradient.
    """
    flat = advantages.reshape(-1, advantages.shape[-1])
    mean = flat.mean(0)  # mu_k = E[A_k]
    std = flat.std(0) if flat.shape[0] > 1 else torch.ones_like(mean)  # sigma_k = std[A_k]
    return (advantages - mean) / (std + eps)  # A_k <- (A_k - mu_k) / (sigma_k + eps)


def scale_by(advantages: torch.Tensor, std: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """Divides each component's advantage by a given scale: ``[*B, K], [K] -> [*B, K]`` (no centring).

    Example:
        >>> scale_by(torch.tensor([[2.0, 30.0]]), torch.tensor([2.0, 10.0]))
        tensor([[1., 3.]])
    """
    return advantages / (std + eps)  # A_k <- A_k / (sigma_k + eps)


def effective_shares(advantages: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Each component's share of the mixed advantage's spread: ``[*B, K], [K] -> [K]``, summing to 1.

    ``share_k = |w_k| std(A_k) / sum_j |w_j| std(A_j)``, with ``A`` the advantages as they are mixed.

    Example:
        >>> a = torch.tensor([[1.0, 10.0], [-1.0, -10.0]])
        >>> effective_shares(a, torch.tensor([1.0, 1.0])).tolist()
        [0.09090909361839294, 0.9090909361839294]
    """
    flat = advantages.reshape(-1, advantages.shape[-1])
    spread = flat.std(0) if flat.shape[0] > 1 else flat.abs().mean(0)  # std(A_k) over the batch
    contribution = weights.abs() * spread  # |w_k| std(A_k)
    total = contribution.sum()  # sum_j |w_j| std(A_j)
    uniform = torch.full_like(contribution, 1.0 / contribution.numel())  # no spread at all: uniform
    spread_out = torch.isfinite(total) & (total > 0)  # a tensor test, not a Python branch: no device sync
    return torch.where(spread_out, contribution / total, uniform)  # share_k


def mix_advantages(advantages: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Weighted sum over components: ``[*B, K], [K] -> [*B, 1]``.

    Example:
        >>> mix_advantages(torch.tensor([[1.0, 2.0]]), torch.tensor([0.5, 1.5]))
        tensor([[3.5000]])
    """
    if weights.dim() != 1 or advantages.shape[-1] != weights.shape[0]:
        raise ValueError(
            f"weights of shape {tuple(weights.shape)} do not match advantages with K={advantages.shape[-1]} "
            "components; expected weights of shape [K]"
        )
    return (advantages * weights).sum(-1, keepdim=True)  # A = sum_k w_k A_k


def anchored_coefficients(weights: torch.Tensor) -> torch.Tensor:
    """The anchored mix's coefficients on ``[A_1 .. A_K, A_Σ]``: ``[K] -> [K + 1]``.

    ``A = w̄ A_Σ + Σ_k (w_k - w̄) A_k``, with ``A_Σ`` the advantage of the summed reward from a critic of its own:
    the K-head critic enters only through the weights' deviations from their mean, so equal weights give
    ``w̄ A_Σ``, PPO's advantage up to a scale, whatever the K heads have learnt. GAE is linear, so when every
    critic is exact (``A_Σ = Σ_k A_k``) this is ``Σ_k w_k A_k``, the unanchored mix.

    Example:
        >>> anchored_coefficients(torch.tensor([0.5, 1.0, 1.5])).tolist()
        [-0.5, 0.0, 0.5, 1.0]
        >>> anchored_coefficients(torch.tensor([0.6, 0.6])).tolist()  # equal weights: the anchor alone
        [0.0, 0.0, 0.6000000238418579]
    """
    mean = weights.mean(-1, keepdim=True)  # w̄ = Σ_k w_k / K
    return torch.cat([weights - mean, mean], dim=-1)  # [w_1 - w̄, ..., w_K - w̄, w̄]


def stack_components(leaves: list[torch.Tensor]) -> torch.Tensor:
    """K leaves ``[*B, 1]`` (or ``[*B]``) -> ``[*B, K]``, refusing leaves of different shapes."""
    shapes = {tuple(leaf.shape) for leaf in leaves}
    if len(shapes) != 1:
        raise ValueError(f"reward components have different shapes {sorted(shapes)}; expected one [*B, 1] shape")
    if leaves[0].shape[-1:] != (1,):
        leaves = [leaf.unsqueeze(-1) for leaf in leaves]
    return torch.cat(leaves, dim=-1)
