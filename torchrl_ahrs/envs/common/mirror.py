"""Left-right mirror maps of a task's vectors (observation, action) as signed permutations.

The mirror of a vector about a robot's sagittal plane is a signed permutation: component ``i`` of the image is
``sign_i · x[index_i]`` (a left joint's angle becomes the right joint's; a roll or yaw angle, a sideways velocity
change sign). A task that is symmetric defines its maps next to its observation (``cassie_mirror``); the training
loop's :class:`~torchrl_ahrs.training.symmetry.MirrorAugmentation` applies them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class SignedPermutation:
    """``y[..., i] = signs[i] · x[..., indices[i]]``: a mirror map on a vector's last dimension.

    A mirror is its own inverse, so the map must satisfy ``M(M(x)) = x``; the constructor checks that, and that
    ``indices`` is a permutation of ``range(len(indices))`` and every sign is ±1, and raises a one-line
    ``ValueError`` otherwise (a wrong map would train on states the robot cannot reach).

    Args:
        indices: ``[D]``, where each component of the image comes from.
        signs: ``[D]``, ±1 per component of the image.

    Example:
        >>> swap = SignedPermutation(indices=(1, 0, 2), signs=(1, 1, -1))  # swap two legs, flip a yaw rate
        >>> swap(torch.tensor([[1.0, 2.0, 3.0]]))
        tensor([[ 2.,  1., -3.]])
        >>> swap(swap(torch.tensor([[1.0, 2.0, 3.0]])))
        tensor([[1., 2., 3.]])
    """

    indices: tuple[int, ...]
    signs: tuple[float, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "indices", tuple(int(i) for i in self.indices))
        object.__setattr__(self, "signs", tuple(float(s) for s in self.signs))
        size = len(self.indices)
        if len(self.signs) != size:
            raise ValueError(f"a signed permutation needs one sign per index, got {len(self.signs)} for {size}")
        if sorted(self.indices) != list(range(size)):
            raise ValueError(f"indices must be a permutation of 0..{size - 1}, got {list(self.indices)}")
        if any(sign not in (1.0, -1.0) for sign in self.signs):
            raise ValueError(f"signs must be +1 or -1, got {list(self.signs)}")
        for i, j in enumerate(self.indices):  # M(M(x))_i = s_i s_j x[idx[j]] must be x_i
            if self.indices[j] != i or self.signs[i] * self.signs[j] != 1.0:
                raise ValueError(f"not a mirror: applying it twice moves component {i} (index {j}, signs not paired)")

    @property
    def size(self) -> int:
        return len(self.indices)

    def unsigned(self) -> SignedPermutation:
        """The same permutation with every sign +1: how a Gaussian's standard deviation mirrors."""
        return SignedPermutation(self.indices, (1.0,) * self.size)

    @classmethod
    def concat(cls, parts: Sequence[SignedPermutation]) -> SignedPermutation:
        """The map of ``torch.cat(vectors, -1)`` when each block mirrors within itself by ``parts[b]``."""
        indices: list[int] = []
        signs: list[float] = []
        offset = 0
        for part in parts:
            indices += [offset + i for i in part.indices]
            signs += part.signs
            offset += part.size
        return cls(tuple(indices), tuple(signs))

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """``x [*B, D] -> [*B, D]``, the mirror image."""
        if x.shape[-1] != self.size:
            raise ValueError(f"this mirror maps vectors of {self.size} components, got shape {tuple(x.shape)}")
        index = torch.as_tensor(self.indices, device=x.device)
        signs = torch.as_tensor(self.signs, dtype=x.dtype, device=x.device)
        return x.index_select(-1, index) * signs  # y_i = s_i x_{idx_i}
