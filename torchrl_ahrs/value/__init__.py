"""Multi-head critics and the weighted per-component advantage estimator."""

from torchrl_ahrs.value.critic import HeadwiseLinear, MultiHeadCritic, make_mlp
from torchrl_ahrs.value.functional import (
    effective_shares,
    mix_advantages,
    normalize_components,
    scale_by,
    stack_components,
)
from torchrl_ahrs.value.gae import WeightedMultiGAE

__all__ = [
    "HeadwiseLinear",
    "MultiHeadCritic",
    "WeightedMultiGAE",
    "effective_shares",
    "make_mlp",
    "mix_advantages",
    "normalize_components",
    "scale_by",
    "stack_components",
]
