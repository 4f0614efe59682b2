"""Selectors: who decides which rule (or which weights) applies for the next period.

A selector gets a :class:`DecisionContext` (this period's statistics, the history, the weights in
force) and returns a :class:`Decision`: a rule id, direct weights (AHRS-D), or neither (keep the
current weights). Selectors without an LLM live here: ``constant`` (PPO), ``fixed`` (HD-PPO),
``random`` (AHRS-R) and ``bandit`` (ours: discounted UCB, stands in when no LLM is configured). The
LLM selectors are in :mod:`torchrl_ahrs.scheduling.llm_selectors`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from torchrl_ahrs.scheduling.rules import RuleRepository
from torchrl_ahrs.scheduling.stats import Summary


@dataclass
class DecisionContext:
    """Everything a selector may look at. Tensors: ``mean``/``var``/``previous_weights`` [K], ``history`` [L, K]."""

    components: list[str]
    mean: torch.Tensor
    var: torch.Tensor
    history: torch.Tensor
    previous_weights: torch.Tensor
    summary: Summary
    past: list[Summary] = field(default_factory=list)
    previous_rule_id: int | None = None
    iteration: int = 0
    decision_index: int = 0


@dataclass
class Decision:
    """A selector's answer. ``rule_id`` xor ``weights`` (normalised shares ``[K]`` summing to 1); neither = keep."""

    selector: str
    rule_id: int | None = None
    weights: torch.Tensor | None = None
    note: str = ""

    @property
    def keeps_weights(self) -> bool:
        return self.rule_id is None and self.weights is None


class Selector:
    """Base class: ``select(context) -> Decision`` plus (optional) checkpoint state."""

    name = "base"

    def select(self, context: DecisionContext) -> Decision:
        raise NotImplementedError

    def state_dict(self) -> dict:
        return {}

    def load_state_dict(self, state: dict) -> None:
        pass

    def close(self) -> None:
        """Releases resources (threads, files); called when training ends."""


class ConstantSelector(Selector):
    """Never changes the weights (PPO: ``initial_weights: [1.0]`` on the total reward).

    Example:
        >>> ConstantSelector().select(None).keeps_weights
        True
    """

    name = "constant"

    def select(self, context: DecisionContext) -> Decision:
        return Decision(self.name, note="constant selector: weights unchanged")


class FixedSelector(Selector):
    """Always the same rule (HD-PPO: ``rule: hdpg``).

    Example:
        >>> from torchrl_ahrs.scheduling.rules import load_repository
        >>> FixedSelector(load_repository(), "hdpg").select(None).rule_id
        9
    """

    name = "fixed"

    def __init__(self, repository: RuleRepository, rule: str | int):
        self.repository = repository  # the scheduler applies this selector's rule ids from it
        self.rule_id = repository.get(rule).id

    def select(self, context: DecisionContext) -> Decision:
        return Decision(self.name, rule_id=self.rule_id)


class RandomSelector(Selector):
    """A uniformly random rule at every decision, from a seeded generator (AHRS-R).

    Example:
        >>> from torchrl_ahrs.scheduling.rules import load_repository
        >>> a, b = RandomSelector(load_repository(), seed=3), RandomSelector(load_repository(), seed=3)
        >>> [a.select(None).rule_id for _ in range(4)] == [b.select(None).rule_id for _ in range(4)]
        True
    """

    name = "random"

    def __init__(self, repository: RuleRepository, seed: int = 0):
        self.repository = repository
        self.rule_ids = repository.ids
        self.generator = torch.Generator().manual_seed(seed)

    def select(self, context: DecisionContext) -> Decision:
        index = int(torch.randint(len(self.rule_ids), (1,), generator=self.generator))
        return Decision(self.name, rule_id=self.rule_ids[index])

    def state_dict(self) -> dict:
        return {"generator": self.generator.get_state()}

    def load_state_dict(self, state: dict) -> None:
        self.generator.set_state(state["generator"])


def total_return_of(summary: Summary) -> float:
    """The period's mean total return (the environment's own reward), else the sum of component means."""
    return summary.total_mean if summary.total_mean is not None else float(sum(summary.mean))


class BanditSelector(Selector):
    """Discounted UCB over the rules, rewarded by the normalised change of the total return (ours, no LLM).

    After each period the rule chosen for it earns ``r = tanh((T_now - T_then) / scale)`` in [-1, 1],
    where ``T`` is the mean total episode return of the period before the choice (``then``) and of
    the period it governed (``now``), and ``scale`` is the discounted mean of earlier ``|T_now - T_then|``
    (so rewards mean the same early, when returns move by tens, and late, when they move by
    thousandths of their size). Statistics are discounted by ``discount`` each update, so old
    evidence fades as the policy changes (Garivier & Moulines' D-UCB):

        N_i <- discount * N_i + [i chosen],   S_i <- discount * S_i + r [i chosen]
        UCB_i = S_i / N_i + exploration * sqrt(log(sum_j N_j) / N_i)

    Untried rules go first, in a seeded random order; ties break by the lowest id.

    Example:
        >>> from torchrl_ahrs.scheduling.rules import load_repository
        >>> from torchrl_ahrs.scheduling.stats import Summary
        >>> bandit = BanditSelector(load_repository(), seed=0)
        >>> context = DecisionContext(["a"], *[torch.zeros(1)] * 2, torch.zeros(5, 1), torch.ones(1), Summary([0.0], [0.0], 1, 1.0))
        >>> 1 <= bandit.select(context).rule_id <= 9
        True
    """

    name = "bandit"

    def __init__(self, repository: RuleRepository, seed: int = 0, discount: float = 0.9, exploration: float = 1.0):
        if not 0.0 < discount <= 1.0:
            raise ValueError(f"discount must be in (0, 1], got {discount}")
        self.repository = repository
        self.rule_ids = repository.ids
        self.discount = discount
        self.exploration = exploration
        generator = torch.Generator().manual_seed(seed)
        self.untried = [self.rule_ids[i] for i in torch.randperm(len(self.rule_ids), generator=generator).tolist()]
        self.counts = torch.zeros(len(self.rule_ids), dtype=torch.float64)
        self.reward_sums = torch.zeros(len(self.rule_ids), dtype=torch.float64)
        self.last_arm: int | None = None
        self.last_total: float | None = None
        self.last_reward: float | None = None
        self.change_scale: float | None = None  # discounted mean |T_now - T_then|

    def update(self, total_now: float) -> None:
        """Credits the rule chosen last time with the normalised change of the total return."""
        if self.last_arm is None or self.last_total is None:
            return
        change = total_now - self.last_total  # T_now - T_then
        if self.change_scale is None:
            self.change_scale = abs(change)
        self.change_scale = self.discount * self.change_scale + (1 - self.discount) * abs(change)  # mean |change|
        reward = math.tanh(change / (self.change_scale + 1e-8))  # r = tanh(change / scale) in [-1, 1]
        index = self.rule_ids.index(self.last_arm)
        self.counts *= self.discount  # N_i <- gamma N_i
        self.reward_sums *= self.discount  # S_i <- gamma S_i
        self.counts[index] += 1.0
        self.reward_sums[index] += reward
        self.last_reward = reward

    def select(self, context: DecisionContext) -> Decision:
        total_now = total_return_of(context.summary)
        self.update(total_now)
        if self.untried:
            arm = self.untried.pop(0)
            note = "bandit: trying an untried rule"
        else:
            mean_reward = self.reward_sums / self.counts.clamp_min(1e-12)  # S_i / N_i
            bonus = self.exploration * torch.sqrt(
                math.log(max(float(self.counts.sum()), 1.0 + 1e-12)) / self.counts.clamp_min(1e-12)
            )  # c sqrt(log(sum N) / N_i)
            arm = self.rule_ids[int(torch.argmax(mean_reward + bonus))]
            note = f"bandit: UCB {float((mean_reward + bonus).max()):.3f}"
        if self.last_reward is not None:
            note += f", last reward {self.last_reward:+.3f}"
        self.last_arm, self.last_total = arm, total_now
        return Decision(self.name, rule_id=arm, note=note)

    def state_dict(self) -> dict:
        return {
            "untried": list(self.untried),
            "counts": self.counts.clone(),
            "reward_sums": self.reward_sums.clone(),
            "last_arm": self.last_arm,
            "last_total": self.last_total,
            "last_reward": self.last_reward,
            "change_scale": self.change_scale,
        }

    def load_state_dict(self, state: dict) -> None:
        self.untried = list(state["untried"])
        self.counts = state["counts"].clone()
        self.reward_sums = state["reward_sums"].clone()
        self.last_arm, self.last_total, self.last_reward = state["last_arm"], state["last_total"], state["last_reward"]
        self.change_scale = state["change_scale"]
