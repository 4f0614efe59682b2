"""Mirror-symmetry data augmentation of PPO minibatches (``ppo.mirror``).

A robot whose body, task and reward are symmetric about its sagittal plane has a mirror image for every
transition: the mirrored state, the mirrored action, the same reward. PPO can learn from both at the price of
one collection (rsl_rl's ``symmetry_cfg.use_data_augmentation``; Mittal et al., "Symmetry Considerations for
Learning Task Symmetric Robot Policies", ICRA 2024). The maps are the task's
(:class:`~torchrl_ahrs.envs.common.mirror.SignedPermutation`); this module is their keyed wrapper, TensorDict in
and out, which the training loop applies to each minibatch.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey

from torchrl_ahrs.envs.common.mirror import SignedPermutation


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
