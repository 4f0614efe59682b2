"""AHRS scheduling: rule repositories, return statistics, selectors and the RuleScheduler hook.

``build_scheduler(cfg, estimator, components, decisions_path, logger, llm_calls_path)`` turns the Hydra config into a
ready :class:`RuleScheduler`:

* ``cfg.method.selector``: ``constant`` | ``fixed`` (with ``cfg.method.rule``) | ``random`` |
  ``bandit`` | ``llm`` | ``direct``. ``llm`` and ``direct`` need ``cfg.llm.model``; with ``llm=offline``
  (no model) the ``bandit`` selector stands in and the run says so at start and in every decision.
* ``cfg.scheduler``: ``interval`` (null: derived from ``decisions``, see :func:`decision_interval`),
  ``history_length``, ``base_weight``, ``weight_mapping`` with ``temperature`` / ``clamp``, ``rules``
  (a repository file; null = the shipped one named by ``cfg.method.repository``), ``blocking``
  (``false`` hides LLM latency: the decision is applied when it arrives, training goes on meanwhile).
* ``cfg.llm.model`` set under ``llm=offline`` is refused at start (it would never be called);
  ``cfg.llm.decision_budget`` bounds one blocking decision (all attempts and the correction) in seconds.
* ``cfg.method.initial_weights``: weights before the first decision (null = ``base_weight``).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from torchrl_ahrs.common.config_access import select as _select
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
from torchrl_ahrs.scheduling.settings import ScheduleSettings, interval_for
from torchrl_ahrs.scheduling.stats import ReturnStatistics, Summary

__all__ = [
    "BanditSelector",
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
    "RuleScheduler",
    "Selector",
    "Summary",
    "WeightMapping",
    "build_scheduler",
    "decision_interval",
    "weight_mapping",
    "build_selector",
    "load_repository",
    "normalise_scores",
]

log = logging.getLogger(__name__)
DEFAULTS = ScheduleSettings()
LLM_SELECTORS = ("llm", "direct")


def llm_is_offline(cfg: Any) -> bool:
    """True when no LLM is configured (``llm=offline`` or no ``llm`` section / no ``llm.model``)."""
    return _select(cfg, "llm.name", "offline") == "offline" or not _select(cfg, "llm.model")


def decision_interval(cfg: Any) -> int:
    """Training iterations between decisions: ``scheduler.interval``, or, when it is null,
    ``max(1, iterations // scheduler.decisions)`` with ``iterations = total_frames // frames_per_batch``,
    so a run of any length makes at least ``decisions`` decisions; the paper's 100 when neither the interval
    nor ``trainer.total_frames`` is given (a plain dict without a run length).

    Example:
        >>> from omegaconf import OmegaConf
        >>> cfg = OmegaConf.create({"trainer": {"total_frames": 1_000_000, "frames_per_batch": 2048},
        ...                         "scheduler": {"interval": None, "decisions": 15}})
        >>> decision_interval(cfg), 1_000_000 // 2048 // decision_interval(cfg)
        (32, 15)
    """
    interval = _select(cfg, "scheduler.interval")
    if interval is not None:
        return int(interval)
    total_frames = _select(cfg, "trainer.total_frames")
    if total_frames is None:
        return 100
    batch = int(_select(cfg, "trainer.frames_per_batch", 1))
    return interval_for(int(total_frames), batch, int(_select(cfg, "scheduler.decisions", DEFAULTS.decisions)))


def weight_mapping(cfg: Any) -> WeightMapping:
    """The :class:`WeightMapping` of ``cfg.scheduler`` (``weight_mapping``, ``base_weight``,
    ``temperature``, ``clamp: [min, max]``)."""
    clamp = _select(cfg, "scheduler.clamp", list(DEFAULTS.clamp))
    return WeightMapping(
        str(_select(cfg, "scheduler.weight_mapping", DEFAULTS.weight_mapping)),
        float(_select(cfg, "scheduler.base_weight", DEFAULTS.base_weight)),
        temperature=float(_select(cfg, "scheduler.temperature", DEFAULTS.temperature)),
        clamp_min=float(clamp[0]),
        clamp_max=float(clamp[1]),
    )


def build_selector(
    cfg: Any, repository: RuleRepository, components: list[str], llm_calls_path: Path | None = None
) -> tuple[Selector, str]:
    """The selector named by ``cfg.method.selector`` and a note to attach to every decision ('' if none)."""
    name = _select(cfg, "method.selector", "constant")
    seed = int(_select(cfg, "seed", 0))
    model, llm_name = _select(cfg, "llm.model"), _select(cfg, "llm.name", "offline")
    if model and llm_name == "offline":  # a model that would silently not be called
        raise ValueError(
            f"llm.model={model} is set but llm=offline never calls a model; choose llm=openai, llm=ollama "
            "or llm=replay (each takes llm.model), or drop llm.model"
        )
    note = ""
    if name in LLM_SELECTORS and llm_is_offline(cfg):
        note = f"llm=offline: the bandit selector stands in for the '{name}' selector (no LLM is called)"
        name = "bandit"
    if name == "constant":
        return ConstantSelector(), note
    if name == "fixed":
        return FixedSelector(repository, _select(cfg, "method.rule", "hdpg")), note
    if name == "random":
        return RandomSelector(repository, seed=seed), note
    if name == "bandit":
        return (
            BanditSelector(
                repository,
                seed=seed,
                discount=float(_select(cfg, "llm.bandit.discount", 0.9)),
                exploration=float(_select(cfg, "llm.bandit.exploration", 1.0)),
            ),
            note,
        )
    if name in LLM_SELECTORS:
        from torchrl_ahrs.scheduling.llm_selectors import build_llm_selector

        return build_llm_selector(name, cfg, repository, components, llm_calls_path), note
    raise ValueError(f"unknown selector {name!r}; choose constant, fixed, random, bandit, llm or direct")


def build_scheduler(
    cfg: Any,
    estimator: Any,
    components: list[str] | None = None,
    decisions_path: Path | None = None,
    logger: Any = None,
    llm_calls_path: Path | None = None,
) -> RuleScheduler:
    """A :class:`RuleScheduler` configured from the whole Hydra config (or a plain dict); it appends its
    decisions to ``decisions_path`` and an LLM selector its calls to ``llm_calls_path`` (None: not written).

    Every key has a default (``method.selector=constant``, the interval of :func:`decision_interval`,
    ``scheduler.base_weight=0.5``, ``scheduler.history_length=5``, ``scheduler.blocking=true``,
    the shipped rules), so ``build_scheduler({}, gae)`` works; ``components`` default to the
    estimator's. ``method.initial_weights: null`` installs ``base_weight`` for every component.

    Example:
        >>> import torch
        >>> from omegaconf import OmegaConf
        >>> cfg = OmegaConf.create({"seed": 0, "method": {"selector": "fixed", "rule": "hdpg", "initial_weights": None},
        ...                         "scheduler": {"interval": 2, "history_length": 5, "base_weight": 0.5}})
        >>> class Estimator:
        ...     weights = torch.ones(2)
        ...     def set_weights(self, w): self.weights = w.clone()
        >>> sched = build_scheduler(cfg, Estimator(), ["a", "b"])
        >>> sched.selector.name, sched.interval, sched.weights.tolist(), len(sched.repository)
        ('fixed', 2, [0.5, 0.5], 1)
        >>> build_scheduler({"method": {"selector": "bandit"}}, Estimator(), ["a", "b"]).selector.name
        'bandit'
    """
    components = _components_of(estimator, components)
    rules_path = _select(cfg, "scheduler.rules")
    if rules_path is None:  # a shipped repository: the 8 hand-written rules, or HD-PPO's rule for hdppo(_a)
        shipped = _select(cfg, "method.repository", "hdpg" if _select(cfg, "method.rule") == "hdpg" else "ahrs")
        repository = load_repository(shipped, num_components=len(components))
    else:
        repository = load_repository(rules_path, validate=True, num_components=len(components))
    selector, note = build_selector(cfg, repository, list(components), llm_calls_path)
    initial = _select(cfg, "method.initial_weights")
    base_weight = float(_select(cfg, "scheduler.base_weight", DEFAULTS.base_weight))
    if initial is None:  # the config's documented meaning of null: base_weight for every component
        initial = [base_weight] * len(components)
    scheduler = RuleScheduler(
        estimator,
        list(components),
        repository,
        selector,
        interval=decision_interval(cfg),
        base_weight=base_weight,
        history_length=int(_select(cfg, "scheduler.history_length", DEFAULTS.history_length)),
        initial_weights=list(initial),
        blocking=bool(_select(cfg, "scheduler.blocking", DEFAULTS.blocking)),
        logger=logger,
        decisions_path=decisions_path,
        note=note,
        mapping=weight_mapping(cfg),
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
