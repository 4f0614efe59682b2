"""PPO pieces: the hybrid loss, the training loop, actor/critic builders, the resumable collector, loggers."""

from torchrl_ahrs.training.loop import FiniteGuard, LoopSettings, TrainingRun, epoch_minibatches, learn
from torchrl_ahrs.training.loss import HybridClipPPOLoss
from torchrl_ahrs.training.models import RunningNorm, build_actor, build_critic

__all__ = [
    "FiniteGuard",
    "HybridClipPPOLoss",
    "LoopSettings",
    "RunningNorm",
    "TrainingRun",
    "build_actor",
    "build_critic",
    "epoch_minibatches",
    "learn",
]
