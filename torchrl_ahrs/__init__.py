"""torchrl_ahrs: Automated Hybrid Reward Scheduling on TorchRL.

The pieces, each usable on its own in a TorchRL pipeline, are importable from here::

    from torchrl_ahrs import (RewardComponents, ComponentRewardSum, with_info_reward_terms,
                              MultiHeadCritic, WeightedMultiGAE, HybridClipPPOLoss,
                              RuleScheduler, build_scheduler, SchedulerSettings, BanditSelector, ...)

* :class:`RewardComponents` — the reward as a key tree of named components (``env.reward_key`` stays
  the native total ``("reward", "total")``); :class:`ComponentRewardSum` — their episode returns;
  :func:`with_info_reward_terms` — a gym-like env's ``info`` reward terms as components;
* :class:`MultiHeadCritic` — one value head per component;
* :class:`WeightedMultiGAE` — per-component GAE in one pass, mixed by weights;
* :class:`HybridClipPPOLoss` — PPO on the mixed advantage (builds its ``WeightedMultiGAE`` when needed);
* :class:`RuleScheduler` — a trainer hook that reschedules the weights, with the selectors
  :class:`ConstantSelector`, :class:`FixedSelector`, :class:`RandomSelector`, :class:`BanditSelector`,
  :class:`LLMRuleSelector` (AHRS) and :class:`DirectWeightSelector` (AHRS-D), and the
  :class:`WeightMapping` from a rule's scores to the weights; :func:`build_scheduler` builds one from typed
  :class:`SchedulerSettings` (:class:`ScheduleSettings`, :class:`SelectionSettings`).

Names are resolved on first use, so ``import torchrl_ahrs`` stays cheap (no torch, MuJoCo or litellm).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

# public name -> the module that defines it (documented place)
_EXPORTS = {
    "RewardComponents": "torchrl_ahrs.rewards",
    "ComponentRewardSum": "torchrl_ahrs.rewards",
    "with_info_reward_terms": "torchrl_ahrs.rewards",
    "MultiHeadCritic": "torchrl_ahrs.value",
    "WeightedMultiGAE": "torchrl_ahrs.value",
    "HybridClipPPOLoss": "torchrl_ahrs.training",
    "RuleScheduler": "torchrl_ahrs.scheduling",
    "build_scheduler": "torchrl_ahrs.scheduling",
    "SchedulerSettings": "torchrl_ahrs.scheduling",
    "ScheduleSettings": "torchrl_ahrs.scheduling",
    "SelectionSettings": "torchrl_ahrs.scheduling",
    "load_repository": "torchrl_ahrs.scheduling",
    "ConstantSelector": "torchrl_ahrs.scheduling",
    "FixedSelector": "torchrl_ahrs.scheduling",
    "RandomSelector": "torchrl_ahrs.scheduling",
    "BanditSelector": "torchrl_ahrs.scheduling",
    "LLMRuleSelector": "torchrl_ahrs.scheduling",
    "DirectWeightSelector": "torchrl_ahrs.scheduling",
    "WeightMapping": "torchrl_ahrs.scheduling",
}

__all__ = [  # literal, so linters and type checkers see the public names
    "BanditSelector",
    "ComponentRewardSum",
    "ConstantSelector",
    "DirectWeightSelector",
    "FixedSelector",
    "HybridClipPPOLoss",
    "LLMRuleSelector",
    "MultiHeadCritic",
    "RandomSelector",
    "RewardComponents",
    "RuleScheduler",
    "ScheduleSettings",
    "SchedulerSettings",
    "SelectionSettings",
    "WeightMapping",
    "WeightedMultiGAE",
    "__version__",
    "build_scheduler",
    "load_repository",
    "with_info_reward_terms",
]

if TYPE_CHECKING:  # for type checkers and IDEs; at run time names load lazily below
    from torchrl_ahrs.rewards import ComponentRewardSum, RewardComponents, with_info_reward_terms
    from torchrl_ahrs.scheduling import (
        BanditSelector,
        ConstantSelector,
        DirectWeightSelector,
        FixedSelector,
        LLMRuleSelector,
        RandomSelector,
        RuleScheduler,
        SchedulerSettings,
        ScheduleSettings,
        SelectionSettings,
        WeightMapping,
        build_scheduler,
        load_repository,
    )
    from torchrl_ahrs.training import HybridClipPPOLoss
    from torchrl_ahrs.value import MultiHeadCritic, WeightedMultiGAE


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value  # resolved once
        return value
    raise AttributeError(f"module 'torchrl_ahrs' has no attribute {name!r}")


def __dir__() -> list[str]:
    return list(__all__)
