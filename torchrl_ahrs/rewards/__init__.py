"""Reward components as a TensorDict key tree."""

from torchrl_ahrs.rewards.components import (
    TOTAL,
    RewardComponents,
    component_reward_keys,
    episode_return_keys,
    finished_episode_returns,
)

__all__ = ["TOTAL", "RewardComponents", "component_reward_keys", "episode_return_keys", "finished_episode_returns"]
