"""PPO pieces: the hybrid loss, the trainer hooks of one iteration, actor/critic builders, loggers."""

from torchrl_ahrs.training.hooks import (
    ComponentReturnLog,
    FiniteGuard,
    LinearLRDecay,
    ObservationNormUpdate,
    PPOMinibatches,
)
from torchrl_ahrs.training.loss import HybridClipPPOLoss
from torchrl_ahrs.training.models import RunningNorm, build_actor, build_critic

__all__ = [
    "ComponentReturnLog",
    "FiniteGuard",
    "HybridClipPPOLoss",
    "LinearLRDecay",
    "ObservationNormUpdate",
    "PPOMinibatches",
    "RunningNorm",
    "build_actor",
    "build_critic",
]
