"""Per-component episode-return statistics between two scheduling decisions.

Returns of finished episodes ``[M, K]`` are accumulated (count, sum, sum of squares in float64);
:meth:`ReturnStatistics.summarise` turns them into a :class:`Summary` (mean and variance per
component) and starts a new period. The last ``history_length`` summaries are kept for the rules
(``history [L, K]``) and the prompts (means, variances, weights and rule of each earlier period).

Non-finite returns (a diverged simulation) are dropped row by row and counted, never averaged in.
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass, field

import torch


@dataclass
class Summary:
    """One period's statistics: ``mean [K]``, ``var [K]`` (population variance), episode ``count``,
    the total return's mean (``total_mean``), and the weights and rule that were in force."""

    mean: list[float]
    var: list[float]
    count: int
    total_mean: float | None = None
    weights: list[float] = field(default_factory=list)
    rule_id: int | None = None

    def to_dict(self) -> dict:
        return asdict(self)


class ReturnStatistics:
    """Accumulates finished-episode returns ``[M, K]`` and keeps the last ``history_length`` summaries.

    Args:
        num_components: K.
        history_length: L, the number of earlier summaries kept.

    Example:
        >>> import torch
        >>> stats = ReturnStatistics(2, history_length=5)
        >>> stats.add(torch.tensor([[1.0, 10.0], [3.0, 10.0]]))  # rows kept
        2
        >>> summary = stats.summarise()
        >>> summary.mean, summary.var, summary.count
        ([2.0, 10.0], [1.0, 0.0], 2)
        >>> stats.history_tensor(torch.tensor([5.0, 5.0])).shape  # [L, K]
        torch.Size([5, 2])
    """

    def __init__(self, num_components: int, history_length: int = 5):
        if history_length < 1:
            raise ValueError(f"history_length must be at least 1, got {history_length}")
        self.num_components = num_components
        self.history_length = history_length
        self.history: deque[Summary] = deque(maxlen=history_length)
        self.dropped_non_finite = 0
        self._reset_period()

    def _reset_period(self) -> None:
        self.count = 0
        self.sum = torch.zeros(self.num_components, dtype=torch.float64)
        self.sum_sq = torch.zeros(self.num_components, dtype=torch.float64)
        self.total_count = 0
        self.total_sum = 0.0

    def add(self, returns: torch.Tensor, total_returns: torch.Tensor | None = None) -> int:
        """Adds episode returns ``[M, K]`` (and optionally the total return ``[M]``); returns rows kept."""
        returns = returns.detach().to("cpu", torch.float64).reshape(-1, self.num_components)  # once per batch
        finite = torch.isfinite(returns).all(dim=-1)
        self.dropped_non_finite += int((~finite).sum())
        kept = returns[finite]
        self.count += kept.shape[0]
        self.sum += kept.sum(dim=0)  # sum_m R_mk
        self.sum_sq += (kept * kept).sum(dim=0)  # sum_m R_mk^2
        if total_returns is not None:
            totals = total_returns.detach().to("cpu", torch.float64).reshape(-1)[finite]
            self.total_count += totals.shape[0]
            self.total_sum += float(totals.sum())
        return int(kept.shape[0])

    def summarise(self) -> Summary:
        """This period's :class:`Summary` (count 0 when no episode finished); starts a new period."""
        if self.count == 0:
            summary = Summary([float("nan")] * self.num_components, [float("nan")] * self.num_components, 0)
        else:
            mean = self.sum / self.count  # mu_k = sum R_mk / M
            var = (self.sum_sq / self.count - mean * mean).clamp_min(0.0)  # sigma2_k = E[R^2] - mu^2
            total = self.total_sum / self.total_count if self.total_count else None
            summary = Summary(mean.tolist(), var.tolist(), self.count, total)
        self._reset_period()
        return summary

    def push(self, summary: Summary) -> None:
        """Appends a decided period to the history (oldest dropped beyond L)."""
        self.history.append(summary)

    def history_tensor(self, current_mean: torch.Tensor) -> torch.Tensor:
        """Earlier means ``[L, K]``, oldest first; padded at the front with the oldest summary,
        or with ``current_mean`` when there is none yet (so improvements start at 0)."""
        rows = [torch.tensor(summary.mean, dtype=torch.float32) for summary in self.history]
        pad = rows[0] if rows else current_mean.float()
        rows = [pad] * (self.history_length - len(rows)) + rows
        return torch.stack(rows)

    def state_dict(self) -> dict:
        return {
            "count": self.count,
            "sum": self.sum.clone(),
            "sum_sq": self.sum_sq.clone(),
            "total_count": self.total_count,
            "total_sum": self.total_sum,
            "history": [summary.to_dict() for summary in self.history],
            "dropped_non_finite": self.dropped_non_finite,
        }

    def load_state_dict(self, state: dict) -> None:
        self.count = int(state["count"])
        self.sum = state["sum"].clone().to(torch.float64)
        self.sum_sq = state["sum_sq"].clone().to(torch.float64)
        self.total_count = int(state["total_count"])
        self.total_sum = float(state["total_sum"])
        self.history = deque((Summary(**item) for item in state["history"]), maxlen=self.history_length)
        self.dropped_non_finite = int(state["dropped_non_finite"])
