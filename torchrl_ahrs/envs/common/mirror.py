"""Left-right mirror maps of a task's vectors (observation, action) as signed permutations.

The mirror of a vector about a robot's sagittal plane is a signed permutation: component ``i`` of the image is
``sign_i · x[index_i]`` (a left joint's angle becomes the right joint's; a roll or yaw angle, a sideways velocity
change sign). A task that is symmetric defines its maps next to its observation (``cassie_mirror``).

:class:`MirrorAugmentation` applies them to a PPO minibatch, TensorDict in and out (``ppo.mirror``): a robot whose
body, task and reward are symmetric about its sagittal plane has a mirror image for every transition (the mirrored
state, the mirrored action, the same reward), so PPO can learn from both at the price of one collection (rsl_rl's
``symmetry_cfg.use_data_augmentation``; Mittal et al., "Symmetry Considerations for Learning Task Symmetric Robot
Policies", ICRA 2024). It lives with the maps because the symmetry is the task's, as IsaacLab's tasks provide the
augmentation function that rsl_rl's PPO calls on each minibatch.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey


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


class MirrorAugmentation:
    """A minibatch followed by its mirror image: ``[B] -> [2B]`` (rsl_rl's symmetry data augmentation).

    Each key in ``maps`` is mirrored with its map; every other entry (advantages, value targets, the collecting
    policy's log-probabilities, ...) is repeated unchanged. That is exact for a symmetric task: a mirrored state
    has the same value, and the mirrored action had, under the mirrored collecting policy, the probability the
    original had (a signed permutation has ``|det| = 1``, and a tanh squash is odd). Keep the collecting policy's
    Gaussian (``loc`` and ``scale``) in ``maps`` so that the KL from it (the adaptive learning rate's) is measured
    against the mirrored policy on the mirrored half; :meth:`for_policy` builds that set.

    Args:
        maps: ``{key: SignedPermutation}``; each key's tensor has the map's size as its last dimension.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_ahrs.envs.common.mirror import SignedPermutation
        >>> flip = SignedPermutation((0, 1), (1, -1))
        >>> augment = MirrorAugmentation.for_policy(observation=flip, action=flip)
        >>> batch = TensorDict({"observation": torch.tensor([[1.0, 2.0]]), "action": torch.tensor([[0.5, 0.5]]),
        ...     "loc": torch.zeros(1, 2), "scale": torch.ones(1, 2), "advantage": torch.ones(1, 1)}, [1])
        >>> out = augment(batch)
        >>> out.batch_size, out["observation"].tolist(), out["advantage"].tolist()
        (torch.Size([2]), [[1.0, 2.0], [1.0, -2.0]], [[1.0], [1.0]])
    """

    def __init__(self, maps: Mapping[NestedKey, SignedPermutation]):
        if not maps:
            raise ValueError("a mirror augmentation needs at least one key to mirror")
        self.maps = dict(maps)

    @classmethod
    def for_policy(
        cls,
        observation: SignedPermutation,
        action: SignedPermutation,
        observation_keys: Sequence[NestedKey] = ("observation",),
        action_key: NestedKey = "action",
        loc_key: NestedKey = "loc",
        scale_key: NestedKey = "scale",
    ) -> MirrorAugmentation:
        """The maps a PPO minibatch needs: each observation key the actor or critic reads, the action, and the
        collecting policy's Gaussian (``loc`` like the action, ``scale`` permuted without signs)."""
        maps: dict[NestedKey, SignedPermutation] = dict.fromkeys(observation_keys, observation)
        maps.update({action_key: action, loc_key: action, scale_key: action.unsigned()})
        return cls(maps)

    def __call__(self, batch: TensorDictBase) -> TensorDictBase:
        """``batch [B]`` -> ``[2B]``: the batch, then its mirror image. Keys of ``maps`` absent from the batch are
        skipped (a loss that reads no ``loc`` has none)."""
        mirrored = batch.copy()  # a new container over the same tensors: the repeated entries are not copied here
        for key, mirror in self.maps.items():
            value = batch.get(key, None)
            if value is not None:
                mirrored.set(key, mirror(value))
        return torch.cat([batch, mirrored], 0)
