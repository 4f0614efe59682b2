"""HD-PPO's weight rule as a one-rule repository (used by ``method=hdppo`` and ``method=hdppo_a``).

provenance: hand-written for torchrl_ahrs; our reading of the HDPG rule (Huang et al. 2022), whose
exact formula is not published with the AHRS paper. It is also the example rule shown to the LLM in
the rule-generation prompt. Format: see ``default_rules.py``.
"""

import torch

EPS = 1e-6  # keeps divisions finite


def hdpg(mean_returns, var_returns, history, previous_weights):
    """HDPG Improvement Rate (HD-PPO)

    Our reading of HD-PPO's rule: prioritise the components whose returns accumulate fastest, i.e. the
    improvement of each mean return relative to its previous summary.

    math: s_k = (mu_k - H_{-1,k}) / (|H_{-1,k}| + eps)
    """
    previous = history[-1]
    return (mean_returns - previous) / (torch.abs(previous) + EPS)  # (mu - H_-1) / (|H_-1| + eps)
