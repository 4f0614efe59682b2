"""PPO loss on the mixed advantage, critic loss over all K heads."""

from __future__ import annotations

from tensordict import TensorDictBase
from torchrl.objectives import ClipPPOLoss


class HybridClipPPOLoss(ClipPPOLoss):
    """``ClipPPOLoss`` that refuses an un-mixed ``[*B, K]`` advantage.

    ``ClipPPOLoss`` silently broadcasts an advantage with K columns against the ``[*B, 1]`` log-ratio,
    which trains on the *equally weighted* sum and ignores the schedule. Here the advantage must be the
    ``[*B, 1]`` output of :class:`~torchrl_ahrs.value.WeightedMultiGAE`; the critic is regressed on all
    K columns of ``"value_target"``.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> td = TensorDict({"advantage": torch.zeros(4, 2)}, [4])
        >>> HybridClipPPOLoss.check_advantage(td, "advantage")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: the advantage has shape (4, 2) ...
    """

    @staticmethod
    def check_advantage(tensordict: TensorDictBase, key) -> None:
        advantage = tensordict.get(key, None)
        if advantage is not None and advantage.shape[-1] != 1:
            raise ValueError(
                f"the advantage has shape {tuple(advantage.shape)} ... ClipPPOLoss would broadcast its "
                f"{advantage.shape[-1]} columns as equal weights; pass the mixed [*B, 1] advantage of "
                "WeightedMultiGAE (per-component advantages belong in 'advantage_components')"
            )

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        self.check_advantage(tensordict, self.tensor_keys.advantage)
        return super().forward(tensordict)
