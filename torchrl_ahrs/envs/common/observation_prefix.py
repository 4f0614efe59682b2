"""Keeping only the leading entries of an observation vector, with its spec.

Gymnasium's MuJoCo tasks append optional parts to the end of their observation (Ant-v5 appends the
clipped external contact forces ``cfrc_ext`` after ``qpos[2:]`` and ``qvel``; its
``include_cfrc_ext_in_observation=False`` drops them without touching the reward). EnvPool only offers
the Ant-v4 switch ``use_contact_force``, which removes the contact cost from the reward as well; cutting
the observation here keeps Ant-v5's reward exactly.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Bounded, TensorSpec, Unbounded
from torchrl.envs.transforms import ObservationTransform


class KeepObservationPrefix(ObservationTransform):
    """Keeps ``observation[..., :size]`` (and cuts its spec to match), at reset and at every step.

    Args:
        size: entries kept from the start of the last dimension.
        in_keys: observation entries to cut (default ``["observation"]``).

    Example (EnvPool's Ant-v5: 27 = qpos[2:] (13) + qvel (14), before 78 contact-force entries):
        >>> from torchrl.envs import TransformedEnv
        >>> from torchrl_ahrs.envs.backends.envpool import EnvPoolEnv
        >>> env = TransformedEnv(EnvPoolEnv("Ant-v5", num_envs=2, seed=0), KeepObservationPrefix(27))
        >>> env.observation_spec["observation"].shape, env.rollout(3)["next", "observation"].shape
        (torch.Size([2, 27]), torch.Size([2, 3, 27]))
    """

    def __init__(self, size: int, in_keys: list | None = None):
        if size <= 0:
            raise ValueError(f"KeepObservationPrefix needs a positive size, got {size}")
        in_keys = in_keys or ["observation"]
        super().__init__(in_keys=in_keys, out_keys=list(in_keys))
        self.size = int(size)

    def _apply_transform(self, observation: torch.Tensor) -> torch.Tensor:
        return observation[..., : self.size]  # o' = o[:size]

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: TensorSpec) -> TensorSpec:
        for key in self.in_keys:
            spec = observation_spec[key]
            if spec.shape[-1] < self.size:
                raise ValueError(f"{key!r} has {spec.shape[-1]} entries, fewer than the {self.size} to keep")
            shape = spec.shape[:-1] + (self.size,)
            if isinstance(spec, Bounded):
                low, high = spec.space.low[..., : self.size], spec.space.high[..., : self.size]
                observation_spec[key] = Bounded(low, high, shape=shape, dtype=spec.dtype, device=spec.device)
            else:
                observation_spec[key] = Unbounded(shape=shape, dtype=spec.dtype, device=spec.device)
        return observation_spec
