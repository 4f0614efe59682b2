"""What a person watching a run sees: one short progress line and, now and then, a per-component table.

Everything else (every component's reward, return and weight, the PPO diagnostics) goes to the
logger (CSV / TensorBoard), not the terminal. The line::

    1.23M/10.0M frames | 8.41k frames/s | ETA 17:32 | return 871.3 | rule 1 hdpg

frames/s is end to end (frames since the start over wall-clock time since the start, collection and
updates together). The table is printed at every decision the scheduler applied, and every
``table_interval`` iterations::

    it 40 | 1.23M frames | rule 1 hdpg
      component     return   weight   share
      forward        812.3    1.500   61.2%
      ctrl           -41.2    0.500   12.1%
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TextIO

import torch
from tensordict import TensorDictBase
from torchrl.trainers import TrainerHookBase

from torchrl_ahrs.rewards.components import TOTAL, finished_episode_returns
from torchrl_ahrs.value.functional import effective_shares

LINE_WIDTH = 80  # a standard terminal


def _si(value: float) -> str:
    for unit, size in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if abs(value) >= size:
            return f"{value / size:.3g}{unit}"
    return f"{value:.3g}"


def _clock(seconds: float) -> str:
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


class ConsoleProgress(TrainerHookBase):
    """Trainer hook (``pre_steps_log``) printing one progress line and a compact per-component table.

    Args:
        total_frames: the run's frame budget (for the ETA).
        components: the K components (the estimator's order).
        estimator: has ``weights [K]`` and ``shares [K]`` (a ``WeightedMultiGAE``: the shares of its last
            call, i.e. of the last update, the numbers logged as ``share/<c>``; after a decision the weight
            column is already the new one); without ``shares`` the table estimates them from the batch's
            reward spreads with the same formula.
        scheduler: optional ``RuleScheduler`` (``rule_id``, ``decision_index``, ``repository``).
        table_interval: iterations between tables besides the decisions (0 = at decisions only).
        stream: where to write (default ``sys.stderr``).
        start_frames: frames already done (a resumed run).
        clock: seconds for the rate and ETA (default ``time.monotonic``; tests pass a fake one).

    Example:
        >>> import io, torch
        >>> from tensordict import TensorDict
        >>> class Gae:
        ...     weights = torch.tensor([1.0, 0.5])  # no shares: estimated from the batch's rewards
        >>> out = io.StringIO()
        >>> console = ConsoleProgress(1000, ["a", "b"], Gae(), table_interval=1, stream=out)
        >>> batch = TensorDict({"next": {"done": torch.ones(4, 1, dtype=torch.bool),
        ...     "reward": {"a": torch.arange(4.0)[:, None], "b": 2 * torch.arange(4.0)[:, None], "total": torch.ones(4, 1)},
        ...     "episode_reward": {"a": torch.ones(4, 1), "b": torch.ones(4, 1), "total": torch.full((4, 1), 9.0)}}}, [4])
        >>> console(batch)
        {}
        >>> line, *table = out.getvalue().splitlines()
        >>> line.split(" | ")[0], line.split(" | ")[3]
        ('4/1k frames', 'return 9')
        >>> table[2].split(), table[3].split()  # b: half the weight, twice the spread: the same share
        (['a', '1', '1.000', '50.0%'], ['b', '1', '0.500', '50.0%'])
    """

    def __init__(
        self,
        total_frames: int,
        components: Sequence[str],
        estimator: Any,
        scheduler: Any = None,
        table_interval: int = 10,
        stream: TextIO | None = None,
        start_frames: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.total_frames = int(total_frames)
        self.components = list(components)
        self.estimator = estimator
        self.scheduler = scheduler
        self.table_interval = int(table_interval)
        self.stream = stream if stream is not None else sys.stderr
        self.frames = int(start_frames)
        self.start_frames = self.frames
        self.clock = clock
        self.started = clock()
        self.iteration = 0
        self.last_return: float | None = None
        self.last_component_returns: list[float] | None = None
        self.seen_decisions = getattr(scheduler, "decision_index", 0)

    def decision_text(self, rule_id: int | None = None, decided: bool | None = None) -> str:
        """``rule 1 hdpg``, ``direct weights`` or ``no rule yet``: the rule in force now, or ``rule_id`` (0 or
        None: no rule) when given."""
        scheduler = self.scheduler
        if rule_id is None and decided is None:
            rule_id = getattr(scheduler, "rule_id", None)
            decided = scheduler is not None and int(getattr(scheduler, "decision_index", 0)) > 0
        if getattr(getattr(scheduler, "selector", None), "name", None) == "constant":
            return "no schedule"  # ppo, mcppo: the weights never change
        if scheduler is None or not rule_id:
            return "direct weights" if decided else "no rule yet"
        rule = scheduler.repository[int(rule_id)]
        return f"rule {rule.id} {rule.key}"

    def line(self) -> str:
        """One line of at most 80 characters: frames, frames/s, ETA, total return, the rule in force."""
        elapsed = max(self.clock() - self.started, 1e-9)
        rate = (self.frames - self.start_frames) / elapsed  # end to end: collection + update
        eta = (self.total_frames - self.frames) / rate if rate > 0 else float("inf")
        parts = [
            f"{_si(self.frames)}/{_si(self.total_frames)} frames",
            f"{_si(rate)} frames/s",
            f"ETA {_clock(eta) if eta != float('inf') else '?'}",
            f"return {'?' if self.last_return is None else f'{self.last_return:.4g}'}",
            self.decision_text(),
        ]
        text = " | ".join(parts)
        return text if len(text) <= LINE_WIDTH else text[: LINE_WIDTH - 1] + "…"  # one terminal line

    def table(self, batch: TensorDictBase, metrics: Mapping[str, float] | None = None) -> str:
        """Per-component last mean return, weight and effective share of one update.

        With the iteration's ``metrics`` (``weight/<c>``: the weights the update used, ``share/<c>``: their
        shares in it, ``scheduler/rule``: the rule they came from) the row's numbers belong to one update, and a
        ``next`` column shows the weights a decision installed after it. Without them, the estimator's
        ``weights`` and ``shares`` (or shares estimated from the batch's reward spreads)."""
        current = self.estimator.weights.detach().float().cpu()
        names = self.components
        header = self.decision_text()
        if metrics is not None and all(f"weight/{c}" in metrics and f"share/{c}" in metrics for c in names):
            weights = torch.tensor([metrics[f"weight/{c}"] for c in names])
            shares = torch.tensor([metrics[f"share/{c}"] for c in names])
            if "scheduler/rule" in metrics:  # the rule of this update; a decision after it is the "next" one
                later = int(not torch.allclose(weights, current))
                decided = int(getattr(self.scheduler, "decision_index", 0)) - later > 0
                header = self.decision_text(int(metrics["scheduler/rule"]), decided)
        else:
            weights = current
            recorded = getattr(self.estimator, "shares", None)
            if recorded is None:  # an estimator that does not record its shares: the reward spreads stand in
                rewards = torch.cat(
                    [batch.get(("next", "reward", c)).float().reshape(-1, 1) for c in names], dim=-1
                ).cpu()  # [N, K], beside the CPU weights
                recorded = effective_shares(rewards, weights)
            shares = recorded.detach().float().cpu()
        changed = not torch.allclose(weights, current)  # a decision after this update: its weights come next
        returns = self.last_component_returns or [float("nan")] * len(names)
        width = max(9, *(len(c) for c in names))
        rows = [
            f"it {self.iteration} | {_si(self.frames)} frames | {header}"
            + (f" -> next {self.decision_text()}" if changed else ""),
            f"  {'component':<{width}} {'return':>9} {'weight':>8} {'share':>7}" + (f" {'next':>8}" if changed else ""),
        ]
        columns = zip(names, returns, weights.tolist(), shares.tolist(), current.tolist(), strict=True)
        for name, ret, weight, share, upcoming in columns:
            row = f"  {name:<{width}} {ret:>9.4g} {weight:>8.3f} {share:>7.1%}"
            rows.append(row + (f" {upcoming:>8.3f}" if changed else ""))
        return "\n".join(rows)

    def __call__(self, batch: TensorDictBase, metrics: Mapping[str, float] | None = None) -> dict[str, float]:
        self.iteration += 1
        self.frames += batch.numel()
        tracked = self.components + ([TOTAL] if TOTAL not in self.components else [])
        returns = finished_episode_returns(batch, tracked)  # [M, K+1]
        if returns.shape[0]:
            means = returns.mean(0).tolist()
            self.last_component_returns, self.last_return = means[: len(self.components)], means[-1]
            if TOTAL in self.components:
                self.last_return = means[self.components.index(TOTAL)]
        print(self.line(), file=self.stream, flush=True)
        decisions = getattr(self.scheduler, "decision_index", 0)
        periodic = self.table_interval > 0 and self.iteration % self.table_interval == 0
        if decisions != self.seen_decisions or periodic:
            self.seen_decisions = decisions
            print(self.table(batch, metrics), file=self.stream, flush=True)
        return {}  # nothing for the logger: ComponentReturnLog logs the numbers

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        pass

    def register(self, trainer, name: str = "console") -> None:
        trainer.register_op("pre_steps_log", self)
