"""PPO pieces: the hybrid loss, the training loop, actor/critic builders, the resumable collector, loggers."""

from torchrl_ahrs.training.loop import FiniteGuard, adaptive_kl_lr, epoch_minibatches, learn
from torchrl_ahrs.training.loss import HybridClipPPOLoss
from torchrl_ahrs.training.models import RunningNorm, build_actor, build_critic
from torchrl_ahrs.training.run import LoopSettings, Progress, TrainingRun

__all__ = [
    "FiniteGuard",
    "HybridClipPPOLoss",
    "LoopSettings",
    "Progress",
    "RunningNorm",
    "TrainingRun",
    "adaptive_kl_lr",
    "build_actor",
    "build_critic",
    "epoch_minibatches",
    "learn",
]
