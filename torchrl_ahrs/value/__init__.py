"""Multi-head critics and the weighted per-component advantage estimator."""

from torchrl_ahrs.value.critic import AutocastMLP, HeadwiseLinear, MultiHeadCritic, make_mlp, set_compute_dtype
from torchrl_ahrs.value.functional import (
    effective_shares,
    mix_advantages,
    normalize_components,
    scale_by,
    stack_components,
)
from torchrl_ahrs.value.gae import WeightedMultiGAE

__all__ = [
    "AutocastMLP",
    "HeadwiseLinear",
    "MultiHeadCritic",
    "WeightedMultiGAE",
    "effective_shares",
    "make_mlp",
    "mix_advantages",
    "normalize_components",
    "scale_by",
    "set_compute_dtype",
    "stack_components",
]
