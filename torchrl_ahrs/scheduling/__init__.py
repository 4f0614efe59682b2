"""AHRS scheduling: rule repositories, return statistics, selectors and the RuleScheduler hook.

``build_scheduler(cfg, estimator, components, decisions_path, logger, llm_calls_path)`` turns the Hydra config into a
ready :class:`RuleScheduler`:

* ``cfg.method.selector``: ``constant`` | ``fixed`` (with ``cfg.method.rule``) | ``random`` |
  ``bandit`` | ``llm`` | ``direct``. ``llm`` and ``direct`` need ``cfg.llm.model``; with ``llm=offline``
  (no model) the ``bandit`` selector stands in and the run says so at start and in every decision.
* ``cfg.scheduler``: ``interval``, ``history_length``, ``base_weight``, ``rules`` (a repository file,
  null = the shipped one), ``blocking`` (``false`` hides LLM latency: the decision is applied when it
  arrives, training goes on meanwhile).
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
    "RuleScheduler",
    "Selector",
    "Summary",
    "build_scheduler",
    "build_selector",
    "load_repository",
    "normalise_scores",
]

log = logging.getLogger(__name__)
LLM_SELECTORS = ("llm", "direct")


def llm_is_offline(cfg: Any) -> bool:
    """True when no LLM is configured (``llm=offline`` or no ``llm`` section / no ``llm.model``)."""
    return _select(cfg, "llm.name", "offline") == "offline" or not _select(cfg, "llm.model")


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

    Every key has a default (``method.selector=constant``, ``scheduler.interval=100``,
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
        >>> sched.selector.name, sched.interval, sched.weights.tolist()
        ('fixed', 2, [0.5, 0.5])
        >>> build_scheduler({"method": {"selector": "bandit"}}, Estimator(), ["a", "b"]).selector.name
        'bandit'
    """
    components = _components_of(estimator, components)
    rules_path = _select(cfg, "scheduler.rules")
    repository = load_repository(rules_path, validate=rules_path is not None)
    selector, note = build_selector(cfg, repository, list(components), llm_calls_path)
    initial = _select(cfg, "method.initial_weights")
    base_weight = float(_select(cfg, "scheduler.base_weight", 0.5))
    if initial is None:  # the config's documented meaning of null: base_weight for every component
        initial = [base_weight] * len(components)
    scheduler = RuleScheduler(
        estimator,
        list(components),
        repository,
        selector,
        interval=int(_select(cfg, "scheduler.interval", 100)),
        base_weight=base_weight,
        history_length=int(_select(cfg, "scheduler.history_length", 5)),
        initial_weights=list(initial),
        blocking=bool(_select(cfg, "scheduler.blocking", True)),
        logger=logger,
        decisions_path=decisions_path,
        note=note,
    )
    log.info(
        "RuleScheduler: selector=%s, %d rules from %s (digest %s), interval=%d, components=%s",
        selector.name,
        len(repository),
        repository.source_path,
        repository.digest(),
        scheduler.interval,
        list(components),
    )
    return scheduler
