"""Default AHRS rule repository (written in this project from the paper's rule descriptions).

provenance: hand-written for torchrl_ahrs, standing in for the paper's LLM-generated repository (its
figure 5 is an image we do not have). The paper's rule-selection prompt (appendix A) names rules 1-4
(Mean Returns Only, Variance Returns Only, Combined Mean and Variance Returns, Improvement Rate Only)
and figure 4 shows "Formula 1" (log means with adjusted variances) and "Formula 2" (alpha/beta
balance of mean and variance); they are rules 1-6 here, under those names. The paper's prompt asks
for one of 8 rules but does not name rules 7 and 8: ours are in the same spirit. HD-PPO's rule is not
in this repository (the paper's AHRS and AHRS-R choose among 8): it is ``hdpg_rule.py``, used by
``hdppo`` / ``hdppo_a``.

Format of a repository file (LLM-generated files use the same one): plain Python accepted by
``python -m torchrl_ahrs.sandbox check FILE --kind rule``. Every top-level function with four
arguments is a rule, numbered 1, 2, ... in file order. Arguments: ``mean_returns [K]`` and
``var_returns [K]`` (episode returns since the last decision), ``history [L, K]`` (earlier mean
returns, oldest first, ``history[-1]`` the previous summary; padded with the oldest available summary,
or with ``mean_returns`` before the first one), ``previous_weights [K]``. A rule returns raw scores
``[K]``; the scheduler normalises them (see ``torchrl_ahrs.scheduling.rules.normalise_scores``) and
adds the base weight. Docstring: first line = rule name, then the description, and a line
``math: ...`` with the formula that goes into prompts.
"""

import torch

ALPHA = 0.7  # Formula 2: share of the mean term
BETA = 0.3  # Formula 2: share of the variance term
EPS = 1e-6  # keeps divisions finite


def mean_returns_only(mean_returns, var_returns, history, previous_weights):
    """Mean Returns Only

    Prioritise components with higher mean returns (reinforce what already pays).

    math: s_k = mu_k
    """
    return mean_returns  # s_k = mu_k


def variance_returns_only(mean_returns, var_returns, history, previous_weights):
    """Variance Returns Only

    Prioritise components with higher return variance (the policy is still unsettled there).

    math: s_k = sigma2_k
    """
    return var_returns  # s_k = sigma2_k


def combined_mean_variance(mean_returns, var_returns, history, previous_weights):
    """Combined Mean and Variance Returns

    Use mean and variance together: weight = mean_returns + var_returns.

    math: s_k = mu_k + sigma2_k
    """
    return mean_returns + var_returns  # s_k = mu_k + sigma2_k


def improvement_rate_only(mean_returns, var_returns, history, previous_weights):
    """Improvement Rate Only

    Prioritise components whose mean return grew fastest over the history window.

    math: s_k = (mu_k - H_{0,k}) / L
    """
    return (mean_returns - history[0]) / history.shape[0]  # s_k = (mu_k - H_0k) / L


def log_mean_adjusted_variance(mean_returns, var_returns, history, previous_weights):
    """Log Mean with Adjusted Variance (Formula 1)

    Compress the scale of the mean with a logarithm and add the spread measured relative to it.

    math: s_k = log(1 + |mu_k|) + sqrt(sigma2_k) / (1 + |mu_k|)
    """
    magnitude = torch.abs(mean_returns)
    return torch.log1p(magnitude) + torch.sqrt(var_returns) / (1.0 + magnitude)  # log(1+|mu|) + sigma/(1+|mu|)


def balanced_mean_variance(mean_returns, var_returns, history, previous_weights):
    """Alpha-Beta Balance of Mean and Variance (Formula 2)

    Mix the mean (share alpha = 0.7) and the variance (share beta = 0.3), each scaled by its total.

    math: s_k = alpha * mu_k / (sum_j |mu_j| + eps) + beta * sigma2_k / (sum_j sigma2_j + eps)
    """
    mean_part = mean_returns / (torch.abs(mean_returns).sum() + EPS)  # mu_k / sum |mu|
    var_part = var_returns / (var_returns.sum() + EPS)  # sigma2_k / sum sigma2
    return ALPHA * mean_part + BETA * var_part  # alpha * mean_part + beta * var_part


def lagging_components_first(mean_returns, var_returns, history, previous_weights):
    """Lagging Components First

    Prioritise components with the lowest mean return, i.e. the skills not mastered yet.

    math: s_k = -mu_k
    """
    return -mean_returns  # s_k = -mu_k


def noise_adjusted_improvement(mean_returns, var_returns, history, previous_weights):
    """Noise-Adjusted Improvement

    Prioritise components whose last improvement is large compared with their return noise.

    math: s_k = (mu_k - H_{-1,k}) / sqrt(1 + sigma2_k)
    """
    return (mean_returns - history[-1]) / torch.sqrt(1.0 + var_returns)  # (mu - H_-1) / sqrt(1 + sigma2)
