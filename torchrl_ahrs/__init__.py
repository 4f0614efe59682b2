"""torchrl_ahrs: Automated Hybrid Reward Scheduling on TorchRL.

The pieces, each usable on its own in a TorchRL pipeline:

* :class:`~torchrl_ahrs.rewards.RewardComponents` — the reward as a key tree of named components;
* :class:`~torchrl_ahrs.value.MultiHeadCritic` — one value head per component;
* :class:`~torchrl_ahrs.value.WeightedMultiGAE` — per-component GAE in one pass, mixed by weights;
* :class:`~torchrl_ahrs.scheduling.RuleScheduler` — a trainer hook that reschedules the weights.
"""

__version__ = "0.1.0"
