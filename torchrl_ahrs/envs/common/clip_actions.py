"""Clipping the policy's action into the environment's bounds on the way in, as CleanRL's ``ClipAction``.

A policy with an unbounded Gaussian (``model.distribution: normal``) samples actions outside the
bounds. The environment must receive the clipped action (EnvPool's MuJoCo tasks charge their control
cost on the action they are given), while the rollout must keep the sample itself: PPO's ratio uses
its log-probability, and the clipped value has none under the Gaussian. TorchRL's inverse transforms
do exactly that — they rewrite the action in the copy handed to the base environment only.
"""

from __future__ import annotations

import torch
from torchrl.data import TensorSpec
from torchrl.envs import Transform


class ClipActionToSpec(Transform):
    """Clamps ``action_key`` into the parent environment's action bounds before each step.

    Unlike TorchRL's ``ClipTransform`` (one scalar bound for every dimension) the bounds are the
    parent's action spec, per dimension; the action spec the policy sees is left unchanged.

    Args:
        action_key: the action entry (TorchRL's ``"action"``).

    Example (EnvPool's Ant-v5 charges 0.5 · Σ a² for control, on the action it receives):
        >>> import torch
        >>> from torchrl_ahrs.envs import make_env
        >>> from torchrl_ahrs.app.shared.settings import load_task_settings
        >>> env = make_env(load_task_settings("ant_v5"), num_envs=1, transforms=[ClipActionToSpec])
        >>> td = env.reset()
        >>> td["action"] = torch.full((1, 8), 5.0)
        >>> out = env.step(td)
        >>> out["action"].max().item(), out["next", "reward", "ctrl"].item()  # kept 5; charged 0.5 · 8 · 1², not 100
        (5.0, -4.0)
    """

    def __init__(self, action_key: str = "action"):
        super().__init__(in_keys_inv=[action_key], out_keys_inv=[action_key])

    def _inv_apply_transform(self, action: torch.Tensor) -> torch.Tensor:
        space = self._action_spec().space
        return action.clamp(space.low.to(action.device), space.high.to(action.device))  # a_env = clip(a, low, high)

    def _action_spec(self) -> TensorSpec:
        if self.parent is None:
            raise RuntimeError("ClipActionToSpec must sit in a TransformedEnv to know the action bounds")
        return self.parent.full_action_spec[self.in_keys_inv[0]]
