"""From a rule's raw scores ``s [K]`` to the mixing weights ``w [K]``: a named, configurable choice.

The paper (section IV, "Implementation details") writes every scheduled weight as
``w_k = w_base + w_calculated_k`` with ``w_base = 0.5``, where ``w_calculated`` is "the value computed by
the corresponding weight calculation rule", and says each weight "reflects its importance". It does not
say how a rule's output, which is in the units of returns (a mean return of 500, a variance of 1e4),
becomes a weight next to a base of 0.5. The reading chosen here, the default ``minshift_sum``:

    ``w_calculated_k = (s_k - min_j s_j) / sum_i (s_i - min_j s_j)``, so ``w_k = 0.5 + w_calculated_k``.

Why this reading:

- ``w_calculated`` must be free of the returns' units, or the base weight means nothing: with raw scores
  ``0.5 + 500`` is just ``500``. The paper's own Formula 2 (figure 4) divides each term by its total, so
  shares that sum to 1 are the paper's idiom;
- the shift by ``min s`` admits rules whose scores can be negative (an improvement rate, ``-mu``);
- the weights stay positive and bounded (``0.5 <= w_k <= 1.5``, ratio at most 3), so no schedule reverses
  a component's gradient or silences one: the base weight keeps every component in the update, which
  is what a base is for;
- equal scores give equal weights ``0.5 + 1/K``, which on raw advantages is PPO up to a constant factor
  (GAE is linear; ``ppo.normalize_advantage`` removes the factor): a schedule that learns nothing falls
  back to its control, never below it.

The other mappings are named ablations (``scheduler.weight_mapping``):

``softmax``
    ``z = (s - mean(s)) / std(s)``, ``w_k = base + K * softmax(z / temperature)_k``. Scale- and
    offset-free like ``minshift_sum``, but the ratio grows with ``1 / temperature`` and does not
    shrink with K: at equal scores every ``w_k = base + 1``. On ``ant`` it gave the saturated ``alive`` and
    ``heading`` terms weight 3.55 against 0.82 for ``progress`` (benchmarks/RESULTS.md, "Faithful defaults").
``plain_sum``
    ``w_k = clamp(base + s_k, clamp_min, clamp_max)``: the literal sum of the base and the rule's unscaled
    output. Rules on returns produce scores in the returns' units, so the clamp keeps weights
    non-negative (a negative weight would reverse a component's gradient) and bounded.

Direct weights (AHRS-D, ``x [K] >= 0``) use ``n = x / sum x`` in every mapping; ``softmax`` and
``plain_sum`` then scale ``n`` by K so equal answers give ``base + 1`` as their rule mappings do.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

MAPPINGS = ("minshift_sum", "softmax", "plain_sum")
DEFAULT_MAPPING = "minshift_sum"  # the paper's w_base + w_calculated, read as above; conf/config.yaml agrees (tested)
DEFAULT_BASE_WEIGHT = 0.5  # the paper's w_base


@dataclass(frozen=True)
class WeightMapping:
    """Maps raw scores ``[K]`` to weights ``[K]`` (see the module docstring for the formulas).

    Args:
        kind: ``minshift_sum`` (default: the paper's reading) | ``softmax`` | ``plain_sum``.
        base_weight: ``w_base`` added to every component.
        temperature: ``softmax`` only; smaller = sharper.
        clamp_min, clamp_max: ``plain_sum`` only; the final weights are clamped into this range.

    Example:
        >>> import torch
        >>> scores = torch.tensor([1.0, 2.0, 4.0])
        >>> WeightMapping("minshift_sum", 0.5)(scores).tolist()
        [0.5, 0.75, 1.25]
        >>> [round(w, 3) for w in WeightMapping("softmax", 0.5, temperature=0.5)(scores).tolist()]
        [0.523, 0.616, 3.361]
        >>> WeightMapping("plain_sum", 0.5, clamp_max=3.0)(scores).tolist()
        [1.5, 2.5, 3.0]
        >>> WeightMapping("softmax", 0.5)(torch.tensor([7.0, 7.0])).tolist()
        [1.5, 1.5]
    """

    kind: str = DEFAULT_MAPPING
    base_weight: float = DEFAULT_BASE_WEIGHT
    temperature: float = 1.0
    clamp_min: float = 0.0
    clamp_max: float = 10.0

    def __post_init__(self):
        if self.kind == "paper":
            raise ValueError(
                "weight mapping 'paper' was renamed 'plain_sum' (w = clamp(base + s)); the paper's w_base + "
                "w_calculated is the default, 'minshift_sum' (torchrl_ahrs/scheduling/mapping.py says why)"
            )
        if self.kind not in MAPPINGS:
            raise ValueError(f"unknown weight mapping {self.kind!r}; choose one of {', '.join(MAPPINGS)}")
        if not self.temperature > 0:
            raise ValueError(f"weight mapping temperature must be positive, got {self.temperature}")
        if not self.clamp_min <= self.clamp_max:
            raise ValueError(f"weight mapping clamp_min {self.clamp_min} exceeds clamp_max {self.clamp_max}")

    def __call__(self, scores: torch.Tensor) -> torch.Tensor:
        """Weights ``[K]`` (float32) from raw scores ``[K]``."""
        scores = scores.to(torch.float64)
        if self.kind == "minshift_sum":
            return (self.base_weight + minshift_sum(scores)).float()  # w = base + n
        if self.kind == "softmax":
            k = scores.numel()
            return (self.base_weight + k * standardized_softmax(scores, self.temperature)).float()  # base + K p
        weights = self.base_weight + scores  # w = base + s (plain_sum)
        return weights.clamp(self.clamp_min, self.clamp_max).float()  # clamp into [w_min, w_max]

    def direct(self, values: torch.Tensor) -> torch.Tensor:
        """Weights ``[K]`` from non-negative direct answers ``[K]`` with a positive sum (AHRS-D)."""
        values = values.to(torch.float64)
        shares = values / values.sum()  # n_k = x_k / sum_j x_j
        if self.kind == "minshift_sum":
            return (self.base_weight + shares).float()  # w = base + n
        weights = self.base_weight + values.numel() * shares  # w = base + K n
        if self.kind == "plain_sum":
            weights = weights.clamp(self.clamp_min, self.clamp_max)  # clamp into [w_min, w_max]
        return weights.float()

    def describe(self) -> str:
        """One line for prompts and logs, e.g. ``"w_k = 0.5 + K * softmax(z / 1)_k ..."``."""
        if self.kind == "minshift_sum":
            return (
                f"w_k = {self.base_weight:g} + n_k with n_k = (s_k - min_j s_j) / sum_i (s_i - min_j s_j), so n_k >= 0 "
                "and sum_k n_k = 1"
            )
        if self.kind == "softmax":
            return (
                f"w_k = {self.base_weight:g} + K * softmax(z / {self.temperature:g})_k with z the rule's scores "
                "standardised across components (mean 0, standard deviation 1)"
            )
        return (
            f"w_k = {self.base_weight:g} + s_k, clamped into [{self.clamp_min:g}, {self.clamp_max:g}], with s_k the "
            "rule's output"
        )


def minshift_sum(scores: torch.Tensor) -> torch.Tensor:
    """Min-shift sum normalisation ``[K] -> [K]``: non-negative, sums to 1, uniform ``1/K`` on ties.

    Example:
        >>> minshift_sum(torch.tensor([1.0, 2.0, 4.0])).tolist()
        [0.0, 0.25, 0.75]
    """
    shifted = scores - scores.min()  # s_k - min_j s_j  >= 0
    total = shifted.sum()  # sum_i (s_i - min_j s_j)
    if not torch.isfinite(total) or total <= 1e-9 * max(1.0, scores.abs().max().item()):
        return torch.full_like(scores, 1.0 / scores.numel())  # ties: uniform 1/K
    return shifted / total  # n_k = (s_k - min s) / sum (s - min s)


def standardized_softmax(scores: torch.Tensor, temperature: float) -> torch.Tensor:
    """``softmax(z / temperature)`` of the standardised scores ``[K] -> [K]``; uniform on ties.

    Example:
        >>> standardized_softmax(torch.tensor([5.0, 5.0]), 1.0).tolist()
        [0.5, 0.5]
    """
    centred = scores - scores.mean()  # s_k - mean(s)
    spread = centred.pow(2).mean().sqrt()  # population std(s)
    if not torch.isfinite(spread) or spread <= 1e-9 * max(1.0, scores.abs().max().item()):
        return torch.full_like(scores, 1.0 / scores.numel())  # ties: uniform 1/K
    return torch.softmax(centred / spread / temperature, dim=0)  # p = softmax(z / tau)
