"""AHRS scheduling: rule repositories, return statistics, selectors and the RuleScheduler hook.

``build_scheduler(settings, estimator, components, decisions_path, logger, llm_calls_path)`` turns typed
:class:`SchedulerSettings` (``scheduling/settings.py``; ``torchrl_ahrs.app.shared.settings.scheduler_settings``
translates the Hydra config) into a ready :class:`RuleScheduler`:

* ``settings.selection.selector``: ``constant`` | ``fixed`` (with ``selection.rule``) | ``random`` |
  ``bandit`` | ``llm`` | ``direct``. ``llm`` and ``direct`` need ``settings.llm.model``; with ``llm=offline``
  (no model) the ``bandit`` selector stands in and the run says so at start and in every decision.
* ``settings.schedule``: ``interval`` (None: derived from ``decisions`` and the run's length, see
  :meth:`SchedulerSettings.decision_interval`), ``history_length``, ``base_weight``, ``weight_mapping`` with
  ``temperature`` / ``clamp``, ``rules`` (a repository file; None = the shipped one named by
  ``selection.repository``), ``blocking`` (``False`` hides LLM latency: the decision is applied when it
  arrives, training goes on meanwhile).
* ``settings.llm.model`` set under ``llm=offline`` is refused at start (it would never be called);
  ``settings.llm.decision_budget`` bounds one blocking decision (all attempts and the correction) in seconds.
* ``settings.selection.initial_weights``: weights before the first decision (None = ``base_weight``).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from torchrl_ahrs.scheduling.llm_selectors import DirectWeightSelector, LLMRuleSelector
from torchrl_ahrs.scheduling.mapping import WeightMapping
from torchrl_ahrs.scheduling.rules import Rule, RuleRepository, load_repository, normalise_scores
from torchrl_ahrs.scheduling.scheduler import RuleScheduler, _components_of
from torchrl_ahrs.scheduling.selectors import (
    BanditSelector,
    ConstantSelector,
    Decision,
    DecisionContext,
    FixedSelector,
    RandomSelector,
    Selector,
)
from torchrl_ahrs.scheduling.settings import (
    BanditSettings,
    SchedulerSettings,
    ScheduleSettings,
    SelectionSettings,
    interval_for,
)
from torchrl_ahrs.scheduling.stats import ReturnStatistics, Summary

__all__ = [
    "BanditSelector",
    "BanditSettings",
    "ConstantSelector",
    "Decision",
    "DecisionContext",
    "DirectWeightSelector",
    "FixedSelector",
    "LLMRuleSelector",
    "RandomSelector",
    "ReturnStatistics",
    "Rule",
    "RuleRepository",
    "DEFAULTS",
    "ScheduleSettings",
    "SchedulerSettings",
    "SelectionSettings",
    "RuleScheduler",
    "Selector",
    "Summary",
    "WeightMapping",
    "build_scheduler",
    "build_selector",
    "interval_for",
    "load_repository",
    "normalise_scores",
]

log = logging.getLogger(__name__)
DEFAULTS = ScheduleSettings()
LLM_SELECTORS = ("llm", "direct")


def build_selector(
    settings: SchedulerSettings, repository: RuleRepository, components: list[str], llm_calls_path: Path | None = None
) -> tuple[Selector, str]:
    """The selector named by ``settings.selection.selector`` and a note to attach to every decision ('' if none).

    Example:
        >>> from torchrl_ahrs.llm.client import LLMConfig
        >>> settings = SchedulerSettings(selection=SelectionSettings(selector="llm"))  # llm=offline
        >>> selector, note = build_selector(settings, load_repository(), ["a", "b"])
        >>> selector.name, note.startswith("llm=offline: the bandit selector stands in")
        ('bandit', True)
        >>> build_selector(SchedulerSettings(llm=LLMConfig(model="openai/x")), load_repository(), ["a"])
        Traceback (most recent call last):
        ...
        ValueError: llm.model=openai/x is set but llm=offline never calls a model; choose llm=openai, llm=ollama or llm=replay (each takes llm.model), or drop llm.model
    """
    selection = settings.selection
    name = selection.selector
    model = settings.llm.model
    if model and settings.llm.name == "offline":  # a model that would silently not be called
        raise ValueError(
            f"llm.model={model} is set but llm=offline never calls a model; choose llm=openai, llm=ollama "
            "or llm=replay (each takes llm.model), or drop llm.model"
        )
    note = ""
    if name in LLM_SELECTORS and settings.llm_is_offline():
        note = f"llm=offline: the bandit selector stands in for the '{name}' selector (no LLM is called)"
        name = "bandit"
    if name == "constant":
        return ConstantSelector(), note
    if name == "fixed":
        return FixedSelector(repository, selection.rule if selection.rule is not None else "hdpg"), note
    if name == "random":
        return RandomSelector(repository, seed=selection.seed), note
    if name == "bandit":
        bandit = selection.bandit
        return BanditSelector(
            repository, seed=selection.seed, discount=bandit.discount, exploration=bandit.exploration
        ), note
    if name in LLM_SELECTORS:
        from torchrl_ahrs.scheduling.llm_selectors import build_llm_selector

        return build_llm_selector(name, settings, repository, components, llm_calls_path), note
    raise ValueError(f"unknown selector {name!r}; choose constant, fixed, random, bandit, llm or direct")


def build_scheduler(
    settings: SchedulerSettings,
    estimator: Any,
    components: list[str] | None = None,
    decisions_path: Path | None = None,
    logger: Any = None,
    llm_calls_path: Path | None = None,
) -> RuleScheduler:
    """A :class:`RuleScheduler` configured by ``settings``; it appends its decisions to ``decisions_path``
    and an LLM selector its calls to ``llm_calls_path`` (None: not written).

    Every setting has a default (the constant selector, the interval of
    :meth:`SchedulerSettings.decision_interval`, ``base_weight=0.5``, ``history_length=5``,
    ``blocking=True``, the shipped rules), so ``build_scheduler(SchedulerSettings(), gae)`` works;
    ``components`` default to the estimator's. ``initial_weights=None`` installs ``base_weight`` for every
    component.

    Example:
        >>> import torch
        >>> settings = SchedulerSettings(ScheduleSettings(interval=2), SelectionSettings(selector="fixed", rule="hdpg"))
        >>> class Estimator:
        ...     weights = torch.ones(2)
        ...     def set_weights(self, w): self.weights = w.clone()
        >>> sched = build_scheduler(settings, Estimator(), ["a", "b"])
        >>> sched.selector.name, sched.interval, sched.weights.tolist(), len(sched.repository)
        ('fixed', 2, [0.5, 0.5], 1)
        >>> build_scheduler(SchedulerSettings(selection=SelectionSettings(selector="bandit")), Estimator(), ["a", "b"]).selector.name
        'bandit'
    """
    components = _components_of(estimator, components)
    schedule, selection = settings.schedule, settings.selection
    if schedule.rules is None:  # a shipped repository: the 8 hand-written rules, or HD-PPO's rule for hdppo(_a)
        repository = load_repository(selection.shipped_repository(), num_components=len(components))
    else:
        repository = load_repository(schedule.rules, validate=True, num_components=len(components))
    selector, note = build_selector(settings, repository, list(components), llm_calls_path)
    base_weight = float(schedule.base_weight)
    initial = selection.initial_weights
    if initial is None:  # the documented meaning of null: base_weight for every component
        initial = (base_weight,) * len(components)
    scheduler = RuleScheduler(
        estimator,
        list(components),
        repository,
        selector,
        interval=settings.decision_interval(),
        base_weight=base_weight,
        history_length=int(schedule.history_length),
        initial_weights=list(initial),
        blocking=bool(schedule.blocking),
        logger=logger,
        decisions_path=decisions_path,
        note=note,
        mapping=schedule.mapping(),
    )
    log.info(
        "RuleScheduler: selector=%s, %d rules from %s (digest %s), interval=%d, %s, components=%s",
        selector.name,
        len(repository),
        repository.source_path,
        repository.digest(),
        scheduler.interval,
        scheduler.mapping.describe(),
        list(components),
    )
    return scheduler
