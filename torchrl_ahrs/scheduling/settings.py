"""The schedule's settings as typed records whose defaults are written once: the Python API and the shipped
config agree (``tests/app/test_defaults.py`` compares them key by key). The library never reads the Hydra tree;
``torchrl_ahrs.app.shared.settings`` translates a composed config into these records.

* :class:`ScheduleSettings`: the ``scheduler`` section (interval, mapping, history, repository file).
* :class:`BanditSettings`: ``llm.bandit``, the discounted UCB that stands in for an LLM under ``llm=offline``.
* :class:`SelectionSettings`: what picks the rules: ``method.selector`` / ``rule`` / ``repository`` /
  ``initial_weights`` and ``seed``.
* :class:`SchedulerSettings`: the three above with the LLM (``llm``), the task text for the prompts, the
  auxiliary reward file and the run's length: everything :func:`~torchrl_ahrs.scheduling.build_scheduler` reads.

Example:
    >>> s = ScheduleSettings()
    >>> s.weight_mapping, s.base_weight, s.decisions, s.interval
    ('minshift_sum', 0.5, 15, None)
    >>> interval_for(total_frames=1_000_000, frames_per_batch=2048, decisions=15)
    32
    >>> SchedulerSettings(total_frames=1_000_000, frames_per_batch=2048).decision_interval()
    32
    >>> SelectionSettings(selector="fixed", rule="hdpg").shipped_repository()
    'hdpg'
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from torchrl_ahrs.llm.client import LLMConfig
from torchrl_ahrs.scheduling.mapping import DEFAULT_BASE_WEIGHT, DEFAULT_MAPPING, WeightMapping

# the interval when neither scheduler.interval nor the run's length is given: the paper's 100 epochs
UNSIZED_INTERVAL = 100


@dataclass(frozen=True)
class ScheduleSettings:
    """Every ``scheduler.*`` default (see ``conf/config.yaml`` for each field's meaning).

    ``interval=None`` derives the interval from the run's length: ``decisions`` decisions per run, as the
    paper's 1 500 epochs with a decision every 100 (= 15 decisions) on every task length. ``rules=None``
    uses the method's shipped repository (:meth:`SelectionSettings.shipped_repository`).

    Example:
        >>> ScheduleSettings(weight_mapping="plain_sum", clamp=(0.0, 3.0)).mapping().describe()
        "w_k = 0.5 + s_k, clamped into [0, 3], with s_k the rule's output"
    """

    interval: int | None = None
    decisions: int = 15
    history_length: int = 5
    base_weight: float = DEFAULT_BASE_WEIGHT
    weight_mapping: str = DEFAULT_MAPPING
    temperature: float = 1.0
    clamp: tuple[float, float] = (0.0, 10.0)
    rules: str | None = None
    blocking: bool = True

    def mapping(self) -> WeightMapping:
        """The :class:`WeightMapping` these settings name (``weight_mapping``, ``base_weight``,
        ``temperature``, ``clamp``)."""
        return WeightMapping(
            self.weight_mapping,
            float(self.base_weight),
            temperature=float(self.temperature),
            clamp_min=float(self.clamp[0]),
            clamp_max=float(self.clamp[1]),
        )


@dataclass(frozen=True)
class BanditSettings:
    """``llm.bandit``: the discounted UCB over the rules (``conf/llm/offline.yaml``)."""

    discount: float = 0.9
    exploration: float = 1.0


@dataclass(frozen=True)
class SelectionSettings:
    """What picks the rules (the ``method`` group's selector keys and ``seed``).

    ``selector``: ``constant`` | ``fixed`` (with ``rule``) | ``random`` | ``bandit`` | ``llm`` | ``direct``;
    ``repository``: the shipped repository's name (None: ``hdpg`` when ``rule == "hdpg"``, else ``ahrs``);
    ``initial_weights``: the weights before the first decision (None: ``base_weight`` for every component).

    Example:
        >>> SelectionSettings(selector="random", seed=3).shipped_repository()
        'ahrs'
    """

    selector: str = "constant"
    rule: str | int | None = None
    repository: str | None = None
    initial_weights: tuple[float, ...] | None = None
    seed: int = 0
    bandit: BanditSettings = field(default_factory=BanditSettings)

    def shipped_repository(self) -> str:
        """The shipped repository used when ``scheduler.rules`` is null."""
        if self.repository is not None:
            return self.repository
        return "hdpg" if self.rule == "hdpg" else "ahrs"


@dataclass(frozen=True)
class SchedulerSettings:
    """Everything :func:`~torchrl_ahrs.scheduling.build_scheduler` needs, typed.

    ``llm``: the LLM the ``llm`` / ``direct`` selectors ask (the default, ``name="offline"`` without a
    model, lets the bandit stand in); ``task``: the task's settings shown in the prompts (``name``,
    ``description``, ``components``, ...); ``aux_path``: the auxiliary reward file shown as component aux's
    code (None: the task's shipped one); ``total_frames`` / ``frames_per_batch``: the run's length, from
    which a null ``schedule.interval`` is derived.

    Example:
        >>> from torchrl_ahrs.llm.client import LLMConfig
        >>> settings = SchedulerSettings(ScheduleSettings(decisions=10), total_frames=409_600, frames_per_batch=4096)
        >>> settings.decision_interval(), settings.llm_is_offline()
        (10, True)
        >>> SchedulerSettings(llm=LLMConfig(name="openai", model="openai/gpt-4o")).llm_is_offline()
        False
    """

    schedule: ScheduleSettings = field(default_factory=ScheduleSettings)
    selection: SelectionSettings = field(default_factory=SelectionSettings)
    llm: LLMConfig = field(default_factory=LLMConfig)
    task: Mapping[str, Any] = field(default_factory=dict)
    aux_path: str | None = None
    total_frames: int | None = None
    frames_per_batch: int = 1

    def decision_interval(self) -> int:
        """Training iterations between decisions: ``schedule.interval``, or, when it is null,
        :func:`interval_for` the run's length (at least ``decisions`` decisions); ``UNSIZED_INTERVAL`` (the
        paper's 100) when the run's length is unknown."""
        if self.schedule.interval is not None:
            return int(self.schedule.interval)
        if self.total_frames is None:
            return UNSIZED_INTERVAL
        return interval_for(self.total_frames, self.frames_per_batch, self.schedule.decisions)

    def llm_is_offline(self) -> bool:
        """True when no LLM is configured (``llm=offline``, or no model)."""
        return self.llm.name == "offline" or not self.llm.model


def interval_for(total_frames: int, frames_per_batch: int, decisions: int = ScheduleSettings.decisions) -> int:
    """Iterations between decisions so that a run of ``total_frames`` makes ``decisions`` of them:
    ``max(1, (total_frames // frames_per_batch) // decisions)``."""
    iterations = int(total_frames) // max(1, int(frames_per_batch))  # I = total / batch
    return max(1, iterations // max(1, int(decisions)))  # I // D
