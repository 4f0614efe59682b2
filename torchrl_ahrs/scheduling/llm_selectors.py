"""Selectors that ask an LLM: ``llm`` (AHRS: pick a rule, ``~[N]~``) and ``direct`` (AHRS-D: K weights).

Failure handling is the same for both: an unreadable or out-of-range answer gets exactly one
corrective retry (the answer and the reason are sent back); if that fails too, or the call itself
fails (timeout, HTTP errors after the client's retries), the previous rule stays in force (its weights
are recomputed on the new statistics; before any rule, the weights stay) and the decision note says
what happened. Every call, including the corrective one, is a line in ``llm_calls.jsonl``.

One decision, corrective retry included, is bounded by ``llm.decision_budget`` seconds in total (the
client's attempts and backoff stop when it is spent). To keep training while the LLM thinks, run the
scheduler with ``blocking=False`` (``scheduler.blocking=false``).

Without settings, build a selector from a model string; the scheduler supplies the components,
``base_weight`` and ``interval`` (given twice they could disagree)::

    selector = LLMRuleSelector.from_model("openai/gpt-4o")          # or api_base="http://host:port/v1"
    scheduler = RuleScheduler(gae, selector=selector, interval=10)  # fills base_weight/interval/components
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from torchrl_ahrs.common.text import ANSWER_CHARS, cap_text
from torchrl_ahrs.llm.answers import parse_rule_answer, parse_weights_answer
from torchrl_ahrs.llm.client import LLMClient, LLMConfig
from torchrl_ahrs.llm.prompts import correction_message, direct_weights_prompt, rule_selection_prompt
from torchrl_ahrs.llm.task_text import AUX
from torchrl_ahrs.rewards.auxiliary import shipped_aux_path
from torchrl_ahrs.scheduling.rules import RuleRepository, load_repository
from torchrl_ahrs.scheduling.selectors import Decision, DecisionContext, Selector

if TYPE_CHECKING:
    from torchrl_ahrs.scheduling.settings import SchedulerSettings


class _LLMSelectorBase(Selector):
    expected = ""
    mapping_text: str | None = None  # how scores become weights, for the prompt (WeightMapping.describe())
    aux_path: Path | None = None  # the auxiliary reward file shown as component aux's code

    def __init__(
        self,
        client: LLMClient,
        task: Mapping[str, Any] | None = None,
        components: list[str] | None = None,
        base_weight: float | None = None,
        interval: int | None = None,
    ):
        # components, base_weight and interval left None are filled in by the RuleScheduler
        self.client = client
        self.task = dict(task or {})
        self.components = list(components) if components is not None else None
        self.base_weight = base_weight
        self.interval = interval

    @staticmethod
    def client_for(
        model: str, api_base: str | None = None, calls_path: str | Path | None = None, **options: Any
    ) -> LLMClient:
        """An :class:`LLMClient` for ``model`` (a litellm string) logging its calls to ``calls_path``;
        ``options`` are :class:`LLMConfig` fields."""
        if not model:
            raise ValueError("an LLM selector needs a model string, e.g. 'openai/gpt-4o'")
        return LLMClient(LLMConfig(name="python", model=model, api_base=api_base, **options), calls_path=calls_path)

    def settings(self) -> tuple[list[str], float, int]:
        """``(components, base_weight, interval)``; unset ones are an error naming the fix."""
        if self.components is None or self.base_weight is None or self.interval is None:
            raise ValueError(
                f"{type(self).__name__} has no components/base_weight/interval yet: hand it to a RuleScheduler "
                "(which fills them in) or pass them to the constructor"
            )
        return self.components, self.base_weight, self.interval

    def messages(self, context: DecisionContext) -> list[dict[str, str]]:
        raise NotImplementedError

    def parse(self, text: str) -> Any:
        raise NotImplementedError

    def decision(self, parsed: Any, note: str) -> Decision:
        raise NotImplementedError

    def fallback(self, context: DecisionContext, why: str) -> Decision:
        """The previous rule stays (or, before the first rule, the weights stay)."""
        if context.previous_rule_id is not None:
            return Decision(
                self.name,
                rule_id=context.previous_rule_id,
                note=f"{why}; previous rule {context.previous_rule_id} stays",
            )
        return Decision(self.name, note=f"{why}; no rule yet, weights kept")

    def select(self, context: DecisionContext) -> Decision:
        budget = self.client.config.decision_budget
        deadline = time.monotonic() + budget if budget is not None else None  # one budget per decision
        messages = self.messages(context)
        reply = self.client.complete(messages, purpose=self.name, parser=self.parse, deadline=deadline)
        if reply.text is None:
            return self.fallback(context, f"LLM call failed after {reply.attempts} attempt(s): {reply.error}")
        if reply.parse_error is None:
            return self.decision(reply.parsed, f"LLM answered ({reply.source})")
        first_error = reply.parse_error
        retry = [
            *messages,
            {"role": "assistant", "content": cap_text(reply.text, ANSWER_CHARS)},  # a 2 MB answer is not sent back
            correction_message(first_error, self.expected),
        ]
        second = self.client.complete(retry, purpose=f"{self.name}-correction", parser=self.parse, deadline=deadline)
        if second.text is not None and second.parse_error is None:
            return self.decision(second.parsed, f"LLM answered after a corrective retry (first answer: {first_error})")
        why = second.parse_error if second.text is not None else f"call failed: {second.error}"
        return self.fallback(context, f"invalid LLM answer twice ({first_error}; then {why})")


class LLMRuleSelector(_LLMSelectorBase):
    """AHRS: the LLM picks a rule from the repository with the "Rules' selection" prompt (answer ``~[N]~``).

    Example:
        >>> from torchrl_ahrs.scheduling.rules import load_repository
        >>> client = LLMClient(LLMConfig(model="openai/none", api_base="http://127.0.0.1:9/v1"))
        >>> selector = LLMRuleSelector(client, load_repository(), {"description": "walk"}, ["a", "b"], 0.5, 100)
        >>> selector.parse("**~[ 2 ]~**")
        2
    """

    name = "llm"

    def __init__(self, client, repository: RuleRepository, task=None, components=None, base_weight=None, interval=None):
        super().__init__(client, task, components, base_weight, interval)
        self.repository = repository
        self.expected = f"~[N]~ with N one of 1..{len(repository)}"

    @classmethod
    def from_model(
        cls,
        model: str,
        api_base: str | None = None,
        *,
        repository: RuleRepository | None = None,
        task: Mapping[str, Any] | None = None,
        calls_path: str | Path | None = None,
        **options: Any,
    ) -> LLMRuleSelector:
        """The AHRS selector on ``model`` over ``repository`` (default: the shipped rules), no Hydra.

        Example:
            >>> selector = LLMRuleSelector.from_model("openai/gpt-4o", api_base="http://127.0.0.1:9/v1")
            >>> selector.client.config.model, len(selector.repository) == len(load_repository()), selector.interval
            ('openai/gpt-4o', True, None)
        """
        client = cls.client_for(model, api_base, calls_path, **options)
        return cls(client, repository if repository is not None else load_repository(), task)

    def messages(self, context: DecisionContext) -> list[dict[str, str]]:
        components, base_weight, interval = self.settings()
        return rule_selection_prompt(
            self.task,
            components,
            self.repository.describe(),
            len(self.repository),
            context,
            base_weight,
            interval,
            mapping_text=self.mapping_text,
            aux_path=self.aux_path,
        )

    def parse(self, text: str) -> int:
        return parse_rule_answer(text, len(self.repository))

    def decision(self, parsed: int, note: str) -> Decision:
        return Decision(self.name, rule_id=parsed, note=note)


class DirectWeightSelector(_LLMSelectorBase):
    """AHRS-D: the LLM answers K non-negative numbers ``~[w1, ..., wK]~``; w = base + x / sum(x).

    Example:
        >>> client = LLMClient(LLMConfig(model="openai/none", api_base="http://127.0.0.1:9/v1"))
        >>> DirectWeightSelector(client, {"description": "walk"}, ["a", "b"], 0.5, 100).parse("~[1, 3]~")
        [1.0, 3.0]
    """

    name = "direct"

    @classmethod
    def from_model(
        cls,
        model: str,
        api_base: str | None = None,
        *,
        task: Mapping[str, Any] | None = None,
        calls_path: str | Path | None = None,
        **options: Any,
    ) -> DirectWeightSelector:
        """The AHRS-D selector on ``model``, no Hydra (see :meth:`LLMRuleSelector.from_model`)."""
        return cls(cls.client_for(model, api_base, calls_path, **options), task)

    @property
    def expected(self) -> str:  # type: ignore[override]
        k = len(self.components or [])
        return f"~[w1, ..., w{k}]~ with {k} non-negative numbers"

    def messages(self, context: DecisionContext) -> list[dict[str, str]]:
        components, base_weight, interval = self.settings()
        return direct_weights_prompt(self.task, components, context, base_weight, interval, aux_path=self.aux_path)

    def parse(self, text: str) -> list[float]:
        return parse_weights_answer(text, len(self.components or []))

    def decision(self, parsed: list[float], note: str) -> Decision:
        return Decision(self.name, weights=torch.tensor(parsed, dtype=torch.float32), note=note)

    def fallback(self, context: DecisionContext, why: str) -> Decision:
        return Decision(self.name, note=f"{why}; weights kept")


def build_llm_selector(
    name: str,
    settings: SchedulerSettings,
    repository: RuleRepository,
    components: list[str],
    llm_calls_path: Path | None,
) -> Selector:
    """``llm`` or ``direct`` from ``settings.llm``, ``settings.task`` and ``settings.aux_path``;
    ``base_weight``, ``interval`` and the weight mapping's text come from the scheduler that receives the
    selector; every call is logged to ``llm_calls_path``. With an ``aux`` component its code
    (``aux_path``, else the task's shipped auxiliary reward) is shown in the prompts."""
    client = LLMClient(settings.llm, calls_path=llm_calls_path)
    task = dict(settings.task)
    selector: _LLMSelectorBase
    if name == "llm":
        selector = LLMRuleSelector(client, repository, task, components)
    else:
        selector = DirectWeightSelector(client, task, components)
    if AUX in components:
        try:
            selector.aux_path = (
                Path(settings.aux_path) if settings.aux_path else shipped_aux_path(str(task.get("name") or ""))
            )
        except FileNotFoundError:
            selector.aux_path = None  # the prompt then gives aux's meaning without its code
    return selector
