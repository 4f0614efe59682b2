"""The RuleScheduler: statistics → selector → rule → weights in the advantage estimator.

The training loop (:func:`torchrl_ahrs.training.loop.learn`) calls it at two places, and so does a TorchRL
:class:`~torchrl.trainers.Trainer` it is registered on (it is a ``TrainerHookBase``):

* :meth:`~RuleScheduler.observe_batch` (every collected batch; the Trainer's ``pre_steps_log``): the returns of
  episodes that finished in the batch, ``[M, K]``, go into :class:`~torchrl_ahrs.scheduling.stats.ReturnStatistics`;
  the weights in force (``weight/<c>``, their one logged name) and the rule id are returned for the logger.
* :meth:`~RuleScheduler.step` (every training iteration; ``post_steps``): every ``interval`` iterations a decision
  is made: ``w = mapping(rule(mean [K], var [K], history [L, K], previous_weights [K]))`` is installed with
  ``estimator.set_weights(w)``.

Guards (each one keeps the current weights and says why in the log):
  * no episode finished since the last decision;
  * non-finite statistics (non-finite returns are also dropped row by row when they arrive);
  * the selector raised, or answered nothing usable;
  * the rule raised or returned a wrong shape or non-finite scores.

With ``blocking=False`` the selector runs in a background thread; its decision is applied at the
first iteration after it arrives, computed on the statistics it was asked about. A pending request
is not checkpointed.
"""

from __future__ import annotations

import json
import logging
import math
import time
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from pathlib import Path
from typing import Any, Protocol

import torch
from tensordict import TensorDictBase
from torchrl.trainers import TrainerHookBase

from torchrl_ahrs.common.background import in_daemon_thread
from torchrl_ahrs.common.text import error_line, one_line
from torchrl_ahrs.llm.client import FatalSelectorError
from torchrl_ahrs.rewards.components import EPISODE_REWARD, TOTAL, finished_episode_returns
from torchrl_ahrs.scheduling.mapping import WeightMapping
from torchrl_ahrs.scheduling.rules import RuleRepository, load_repository
from torchrl_ahrs.scheduling.selectors import BanditSelector, ConstantSelector, Decision, DecisionContext, Selector
from torchrl_ahrs.scheduling.settings import ScheduleSettings, interval_for
from torchrl_ahrs.scheduling.stats import ReturnStatistics, Summary

log = logging.getLogger(__name__)
CLOSE_WAIT_SECONDS = 5.0  # how long the end of a run waits for a decision still being made in the background


class WeightedEstimator(Protocol):
    """What the scheduler needs from the advantage estimator (``WeightedMultiGAE``); ``components`` optional."""

    weights: torch.Tensor

    def set_weights(self, weights: torch.Tensor) -> None: ...


class RuleScheduler(TrainerHookBase):
    """Picks weight rules during training and installs the weights in the advantage estimator.

    It reads each finished episode's component returns at ``("next", "episode_reward", c)`` (where
    :class:`~torchrl_ahrs.rewards.ComponentRewardSum` writes them); ``set_keys(episode_reward=...)``
    points it elsewhere (e.g. ``"episode"`` for ``RewardSum(out_keys=[("episode", c), ...])``).

    Args:
        estimator: object with ``weights [K]`` and ``set_weights(weights [K])`` (a ``WeightedMultiGAE``).
        components: the K reward components, in the estimator's order (default: ``estimator.components``).
        repository: the rules a selector may pick (default: the selector's, else the shipped repository).
        selector: decides at every decision point (constant, fixed, random, bandit, llm, direct);
            default a :class:`~torchrl_ahrs.scheduling.BanditSelector` over ``repository``.
        interval: training iterations between decisions; ``None`` (the default, as on the command line)
            derives it when registered on a Trainer: ``decisions`` decisions over the trainer's run.
        decisions: decisions per run when ``interval`` is ``None``.
        base_weight: ``w_base`` (used when ``mapping`` is not given: the default mapping with this base).
        history_length: L, earlier summaries shown to rules and selectors.
        initial_weights: weights ``[K]`` installed at construction (default: keep the estimator's).
        blocking: ``False`` runs the selector in a background thread.
        logger: optional TorchRL logger (``log_scalar``) for decision scalars.
        decisions_path: the JSONL file that gets one line per decision point (None = none written).
        note: text attached to every decision log (e.g. that the bandit stands in for an LLM).
        mapping: rule scores -> weights (:class:`~torchrl_ahrs.scheduling.mapping.WeightMapping`).

    Example:
        >>> import torch
        >>> from torchrl_ahrs.scheduling.rules import load_repository
        >>> from torchrl_ahrs.scheduling.selectors import FixedSelector
        >>> class Estimator:
        ...     weights = torch.ones(2)
        ...     def set_weights(self, w): self.weights = w.clone()
        >>> repo, est = load_repository(), Estimator()
        >>> sched = RuleScheduler(est, ["a", "b"], repo, FixedSelector(repo, "mean_returns_only"), interval=1,
        ...                       initial_weights=[0.5, 0.5])
        >>> est.weights.tolist()
        [0.5, 0.5]
        >>> sched.statistics.add(torch.tensor([[1.0, 3.0]]))
        1
        >>> sched.step()
        >>> est.weights.tolist()
        [0.5, 1.5]
    """

    def __init__(
        self,
        estimator: WeightedEstimator,
        components: list[str] | None = None,
        repository: RuleRepository | None = None,
        selector: Selector | None = None,
        interval: int | None = ScheduleSettings.interval,
        base_weight: float = ScheduleSettings.base_weight,
        history_length: int = ScheduleSettings.history_length,
        initial_weights: list[float] | torch.Tensor | None = None,
        blocking: bool = ScheduleSettings.blocking,
        logger: Any = None,
        decisions_path: str | Path | None = None,
        note: str = "",
        mapping: WeightMapping | None = None,
        decisions: int = ScheduleSettings.decisions,
    ):
        if interval is not None and interval < 1:
            raise ValueError(f"interval must be at least 1, got {interval}")
        self.estimator = estimator
        self.components = _components_of(estimator, components)
        if repository is None:
            repository = getattr(selector, "repository", None) or load_repository()
        self.repository = repository
        self.selector = selector if selector is not None else BanditSelector(repository)
        self.episode_reward_key: Any = EPISODE_REWARD
        self.interval: int | None = None if interval is None else int(interval)
        self.decisions = int(decisions)
        self.mapping = mapping if mapping is not None else WeightMapping(base_weight=float(base_weight))
        self.base_weight = self.mapping.base_weight
        self.blocking = blocking
        self.logger = logger
        self.decisions_path = Path(decisions_path) if decisions_path is not None else None
        self.note = note
        self._share_with_selector()
        self.statistics = ReturnStatistics(len(self.components), history_length)
        self.iteration = 0
        self.frames = 0
        self.decision_index = 0
        self.rule_id: int | None = None
        keep = initial_weights is None  # the estimator's weights stand until the first decision
        initial = torch.as_tensor(estimator.weights if keep else initial_weights, dtype=torch.float32)
        initial = initial.detach().cpu().reshape(-1).clone()
        if initial.shape != (len(self.components),) or not torch.isfinite(initial).all():
            what = "the estimator's weights" if keep else "initial_weights"
            raise ValueError(f"{what} must be {len(self.components)} finite numbers, got {initial.tolist()}")
        if not keep:
            self.estimator.set_weights(initial.float())
        self._pending: tuple[Future, DecisionContext] | None = None
        if note:
            log.warning("RuleScheduler: %s", note)

    def _share_with_selector(self) -> None:
        settings: dict[str, Any] = {
            "components": self.components,
            "base_weight": self.base_weight,
            "mapping_text": self.mapping.describe(),
        }
        if self.interval is not None:
            settings["interval"] = self.interval
        _share_settings(self.selector, **settings)

    def derive_interval(self, total_frames: int, frames_per_batch: int) -> int:
        """Sets an interval left ``None`` to ``decisions`` decisions over ``total_frames``; returns the interval."""
        if self.interval is None:
            self.interval = interval_for(total_frames, frames_per_batch, self.decisions)
            self._share_with_selector()
        return self.interval

    @property
    def weights(self) -> torch.Tensor:
        """The current weights ``[K]``: a CPU copy of the estimator's, the one place they live (and are
        checkpointed, with the estimator; on the learner's device). Read once per iteration and decision."""
        return self.estimator.weights.detach().to("cpu", torch.float32, copy=True)

    def set_keys(self, *, episode_reward: Any = None) -> RuleScheduler:
        """Where the episode returns are read: ``("next", *episode_reward, c)``; returns ``self``."""
        if episode_reward is not None:
            self.episode_reward_key = episode_reward
        return self

    # ---------------------------------------------------------------- trainer hooks
    def register(self, trainer, name: str = "rule_scheduler") -> None:
        """Registers ``observe_batch`` at ``pre_steps_log``, ``step`` at ``post_steps``, and the module; an
        interval left ``None`` is derived from the trainer's ``total_frames`` and its collector's batch size."""
        if self.interval is None:
            collector = getattr(trainer, "collector", None)
            batch = getattr(collector, "requested_frames_per_batch", None) or getattr(
                collector, "frames_per_batch", None
            )
            if not batch or not getattr(trainer, "total_frames", None):
                raise ValueError("RuleScheduler(interval=None) needs a trainer with total_frames and a collector")
            self.derive_interval(int(trainer.total_frames), int(batch))
        trainer.register_op("pre_steps_log", self.observe_batch)
        trainer.register_op("post_steps", self.step)
        trainer.register_op("shutdown", self.close)
        trainer.register_module(name, self)

    def observe_batch(self, batch: TensorDictBase) -> dict[str, float]:
        """Feeds the batch's finished episodes to the statistics; returns the scalars to log (:meth:`scalars`)."""
        self.frames += batch.numel()
        key = self.episode_reward_key
        returns = finished_episode_returns(batch, self.components, key)  # [M, K]; a missing key is named
        totals = None
        root = (key,) if isinstance(key, str) else tuple(key)
        if TOTAL not in self.components and ("next", *root, TOTAL) in batch.keys(True, True):
            totals = finished_episode_returns(batch, [TOTAL], key)
        elif TOTAL in self.components:
            totals = returns[:, self.components.index(TOTAL)]
        self.statistics.add(returns, totals)
        return self.scalars()

    def scalars(self) -> dict[str, float]:
        """``weight/<c>`` for every component (the weights in force) and ``scheduler/rule`` (0 = no rule yet)."""
        values = {f"weight/{c}": float(w) for c, w in zip(self.components, self.weights, strict=True)}
        values["scheduler/rule"] = float(self.rule_id or 0)
        return values

    def step(self) -> None:
        """Counts one training iteration; decides every ``interval`` iterations; applies late answers."""
        if self.interval is None:
            raise ValueError("RuleScheduler has no interval: pass interval=, call derive_interval(), or register it")
        self.iteration += 1
        self._collect_pending()
        if self.iteration % self.interval == 0:
            self.decide()

    # ---------------------------------------------------------------- decisions
    def decide(self) -> None:
        """One decision point: summarise the period, ask the selector, install the weights."""
        if self._pending is not None:
            self._record(None, "previous decision still pending; weights kept, statistics keep accumulating")
            return
        summary = self.statistics.summarise()
        if summary.count == 0:
            self._record(None, "no finished episodes since the last decision; weights kept")
            return
        summary.weights, summary.rule_id = self.weights.tolist(), self.rule_id
        if not all(math.isfinite(x) for x in [*summary.mean, *summary.var]):
            self._record(None, f"non-finite statistics {summary.mean} / {summary.var}; weights kept", summary)
            return
        mean = torch.tensor(summary.mean, dtype=torch.float32)
        context = DecisionContext(
            components=self.components,
            mean=mean,
            var=torch.tensor(summary.var, dtype=torch.float32),
            history=self.statistics.history_tensor(mean),
            previous_weights=self.weights.clone(),
            summary=summary,
            past=list(self.statistics.history),
            previous_rule_id=self.rule_id,
            iteration=self.iteration,
            decision_index=self.decision_index,
        )
        self.statistics.push(summary)
        if self.blocking:
            self._apply(self._run_selector(context), context)
        else:
            self._pending = (in_daemon_thread(self._run_selector, context, name="rule-selector"), context)
            self._record(None, "decision requested in the background; weights kept until it arrives", summary)

    def _run_selector(self, context: DecisionContext) -> Decision:
        try:
            return self.selector.select(context)
        except FatalSelectorError:
            raise  # e.g. a replay miss: continuing would silently diverge from the recorded run
        except Exception as error:  # noqa: BLE001 (a selector failure must not stop training)
            # one capped line; the traceback only when debugging (a huge message would fill every log)
            log.warning("selector %s failed: %s", self.selector.name, error_line(error), exc_info=log.isEnabledFor(10))
            return Decision(self.selector.name, note=f"selector failed: {error_line(error)}")

    def _collect_pending(self) -> None:
        if self._pending is not None and self._pending[0].done():
            future, context = self._pending
            self._pending = None
            self._apply(future.result(), context)

    def _apply(self, decision: Decision, context: DecisionContext) -> None:
        if decision.keeps_weights:
            self._record(decision, decision.note or "selector kept the weights", context.summary)
            return
        try:
            if decision.weights is not None:
                weights = self.mapping.direct(decision.weights)  # e.g. w = base + x / sum x
                rule_id = None
            else:
                rule = self.repository[decision.rule_id]  # type: ignore[index]  # set: keeps_weights returned above
                weights = self.mapping(rule.scores(context.mean, context.var, context.history, self.weights))
                rule_id = rule.id
        except Exception as error:  # noqa: BLE001 (a rule failure must not stop training)
            # one capped line, whatever the rule raised (a 1 MB message would fill every log at every decision)
            self._record(decision, f"{one_line(decision.note)} rule failed ({error_line(error)}); weights kept")
            return
        if weights.shape != self.weights.shape or not torch.isfinite(weights).all():
            self._record(decision, f"invalid weights {weights.tolist()}; weights kept")
            return
        self.estimator.set_weights(weights.float())
        self.rule_id = rule_id
        self.decision_index += 1
        self._record(decision, decision.note, context.summary, applied=True)

    def _record(self, decision: Decision | None, message: str, summary: Summary | None = None, applied: bool = False):
        """Logs one decision point to python logging, the TorchRL logger and the decisions file."""
        selector = decision.selector if decision is not None else self.selector.name
        rule = self.repository[self.rule_id] if (applied and self.rule_id is not None) else None
        if selector != ConstantSelector.name:  # one short line; a method without a schedule has nothing to say
            # the full message, the statistics and the note (said once, at start) go to the decisions file
            short = message if len(message) <= 60 else message[:59] + "…"  # e.g. why an LLM call fell back
            reason = f" ({short})" if short else ""
            if applied:
                what = f"rule {rule.id} {rule.key}" if rule else "direct weights"
                weights_text = " ".join(f"{w:.2f}" for w in self.weights.tolist())
                log.info("decision it %d (%s): %s -> %s%s", self.iteration, selector, what, weights_text, reason)
            else:
                log.info("decision it %d (%s): weights kept%s", self.iteration, selector, reason)
        if self.logger is not None and applied:  # the new weights are logged as weight/<c> from the next batch on
            self.logger.log_scalar("scheduler/decision_rule", float(self.rule_id or 0), step=self.frames)
        if self.decisions_path is not None:
            self.decisions_path.parent.mkdir(parents=True, exist_ok=True)
            entry = {
                "time": time.time(),
                "iteration": self.iteration,
                "frames": self.frames,
                "selector": selector,
                "applied": applied,
                "rule_id": self.rule_id if applied else None,
                "rule": rule.key if rule else None,
                "weights": self.weights.tolist(),
                "episodes": summary.count if summary else None,
                "mean": summary.mean if summary else None,
                "var": summary.var if summary else None,
                "message": message,
                "note": self.note,
            }
            with open(self.decisions_path, "a") as handle:
                handle.write(json.dumps(entry) + "\n")

    # ---------------------------------------------------------------- checkpointing
    def state_dict(self) -> dict[str, Any]:
        return {
            "iteration": self.iteration,
            "frames": self.frames,
            "decision_index": self.decision_index,
            "rule_id": self.rule_id,
            "statistics": self.statistics.state_dict(),
            "selector": self.selector.state_dict(),
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.iteration = int(state_dict["iteration"])
        self.frames = int(state_dict["frames"])
        self.decision_index = int(state_dict["decision_index"])
        self.rule_id = state_dict["rule_id"]
        self.statistics.load_state_dict(state_dict["statistics"])
        self.selector.load_state_dict(state_dict["selector"])

    def close(self, wait_seconds: float = CLOSE_WAIT_SECONDS) -> None:
        """Waits up to ``wait_seconds`` for a pending background decision (applies it), else drops it and says
        so; releases the selector. The selector's thread is a daemon: a silent server cannot hold up the exit."""
        if self._pending is not None:
            try:
                self._pending[0].result(timeout=wait_seconds)
            except FutureTimeout:
                self._pending = None
                self._record(None, f"decision still pending after {wait_seconds:g} s at shutdown; dropped")
            except Exception:  # noqa: BLE001 (_collect_pending re-raises a fatal selector error)
                pass
            self._collect_pending()
        self.selector.close()


def _components_of(estimator: Any, components: list[str] | None) -> list[str]:
    """The K components: given, or the estimator's; both given must agree."""
    own = getattr(estimator, "components", None)
    if components is None:
        if own is None:
            raise ValueError("RuleScheduler needs components=[...] (the estimator has no .components)")
        return list(own)
    if own is not None and list(own) != list(components):
        raise ValueError(f"components {list(components)} differ from the estimator's {list(own)}")
    return list(components)


def _share_settings(selector: Any, **settings: Any) -> None:
    """Gives an LLM selector the scheduler's components/base_weight/interval/mapping text (shown in its prompts);
    values the selector already holds must agree, so the prompt cannot describe another schedule."""
    for name, value in settings.items():
        if not hasattr(selector, name):
            continue
        own = getattr(selector, name)
        if own is None:
            setattr(selector, name, list(value) if isinstance(value, list) else value)
        elif own != value:
            raise ValueError(f"the selector's {name}={own!r} differs from the scheduler's {name}={value!r}")
