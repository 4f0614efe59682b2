"""The schedule's defaults, written once: the Python API and ``conf/config.yaml``'s ``scheduler`` section agree
(``tests/test_defaults.py`` compares them key by key).

Example:
    >>> s = ScheduleSettings()
    >>> s.weight_mapping, s.base_weight, s.decisions, s.interval
    ('minshift_sum', 0.5, 15, None)
    >>> interval_for(total_frames=1_000_000, frames_per_batch=2048, decisions=15)
    32
"""

from __future__ import annotations

from dataclasses import dataclass

from torchrl_ahrs.scheduling.mapping import DEFAULT_BASE_WEIGHT, DEFAULT_MAPPING


@dataclass(frozen=True)
class ScheduleSettings:
    """Every ``scheduler.*`` default (see ``conf/config.yaml`` for each field's meaning).

    ``interval=None`` derives the interval from the run's length: ``decisions`` decisions per run, as the
    paper's 1 500 epochs with a decision every 100 (= 15 decisions) on every task length.
    """

    interval: int | None = None
    decisions: int = 15
    history_length: int = 5
    base_weight: float = DEFAULT_BASE_WEIGHT
    weight_mapping: str = DEFAULT_MAPPING
    temperature: float = 1.0
    clamp: tuple[float, float] = (0.0, 10.0)
    blocking: bool = True


def interval_for(total_frames: int, frames_per_batch: int, decisions: int = ScheduleSettings.decisions) -> int:
    """Iterations between decisions so that a run of ``total_frames`` makes ``decisions`` of them:
    ``max(1, (total_frames // frames_per_batch) // decisions)``."""
    iterations = int(total_frames) // max(1, int(frames_per_batch))  # I = total / batch
    return max(1, iterations // max(1, int(decisions)))  # I // D
