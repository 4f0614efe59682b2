"""Reward components as a TensorDict key tree (the layout is documented in :mod:`.components`)."""

from torchrl_ahrs.rewards.components import (
    EPISODE_REWARD,
    TOTAL,
    ComponentLeaves,
    ComponentRewardSum,
    RewardComponents,
    component_reward_keys,
    episode_return_keys,
    finished_episode_returns,
)
from torchrl_ahrs.rewards.info_terms import InfoRewardTerms, with_info_reward_terms

__all__ = [
    "EPISODE_REWARD",
    "TOTAL",
    "ComponentLeaves",
    "ComponentRewardSum",
    "InfoRewardTerms",
    "RewardComponents",
    "component_reward_keys",
    "episode_return_keys",
    "finished_episode_returns",
    "with_info_reward_terms",
]
