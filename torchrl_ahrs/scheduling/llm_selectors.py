"""Selectors that ask an LLM: ``llm`` (AHRS: pick a rule, ``~[N]~``) and ``direct`` (AHRS-D: K weights).

Failure handling is the same for both: an unreadable or out-of-range answer gets exactly one
corrective retry (the answer and the reason are sent back); if that fails too, or the call itself
fails (timeout, HTTP errors after the client's retries), the previous rule stays in force (its weights
are recomputed on the new statistics; before any rule, the weights stay) and the decision note says
what happened. Every call, including the corrective one, is a line in ``llm_calls.jsonl``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from omegaconf import OmegaConf

from torchrl_ahrs.llm.answers import parse_rule_answer, parse_weights_answer
from torchrl_ahrs.llm.client import LLMClient, LLMConfig
from torchrl_ahrs.llm.prompts import correction_message, direct_weights_prompt, rule_selection_prompt
from torchrl_ahrs.scheduling.rules import RuleRepository
from torchrl_ahrs.scheduling.selectors import Decision, DecisionContext, Selector


class _LLMSelectorBase(Selector):
    expected = ""

    def __init__(
        self, client: LLMClient, task: Mapping[str, Any], components: list[str], base_weight: float, interval: int
    ):
        self.client = client
        self.task = task
        self.components = list(components)
        self.base_weight = base_weight
        self.interval = interval

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
        messages = self.messages(context)
        reply = self.client.complete(messages, purpose=self.name, parser=self.parse)
        if reply.text is None:
            return self.fallback(context, f"LLM call failed after {reply.attempts} attempt(s): {reply.error}")
        if reply.parse_error is None:
            return self.decision(reply.parsed, f"LLM answered ({reply.source})")
        first_error = reply.parse_error
        retry = [
            *messages,
            {"role": "assistant", "content": reply.text},
            correction_message(first_error, self.expected),
        ]
        second = self.client.complete(retry, purpose=f"{self.name}-correction", parser=self.parse)
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

    def __init__(self, client, repository: RuleRepository, task, components, base_weight, interval):
        super().__init__(client, task, components, base_weight, interval)
        self.repository = repository
        self.expected = f"~[N]~ with N one of 1..{len(repository)}"

    def messages(self, context: DecisionContext) -> list[dict[str, str]]:
        return rule_selection_prompt(
            self.task,
            self.components,
            self.repository.describe(),
            len(self.repository),
            context,
            self.base_weight,
            self.interval,
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

    def __init__(self, client, task, components, base_weight, interval):
        super().__init__(client, task, components, base_weight, interval)
        self.expected = f"~[w1, ..., w{len(components)}]~ with {len(components)} non-negative numbers"

    def messages(self, context: DecisionContext) -> list[dict[str, str]]:
        return direct_weights_prompt(self.task, self.components, context, self.base_weight, self.interval)

    def parse(self, text: str) -> list[float]:
        return parse_weights_answer(text, len(self.components))

    def decision(self, parsed: list[float], note: str) -> Decision:
        return Decision(self.name, weights=torch.tensor(parsed, dtype=torch.float32), note=note)

    def fallback(self, context: DecisionContext, why: str) -> Decision:
        return Decision(self.name, note=f"{why}; weights kept")


def build_llm_selector(
    name: str, cfg: Any, repository: RuleRepository, components: list[str], llm_calls_path: Path | None
) -> Selector:
    """``llm`` or ``direct`` from the Hydra config (``cfg.llm``, ``cfg.task``, ``cfg.scheduler``); every call is
    logged to ``llm_calls_path``."""
    llm_cfg = OmegaConf.to_container(cfg.llm, resolve=True)
    client = LLMClient(LLMConfig.from_cfg(llm_cfg), calls_path=llm_calls_path)
    task = OmegaConf.to_container(cfg.task, resolve=True) if "task" in cfg else {}
    base_weight = float(cfg.scheduler.base_weight)
    interval = int(cfg.scheduler.interval)
    if name == "llm":
        return LLMRuleSelector(client, repository, task, components, base_weight, interval)
    return DirectWeightSelector(client, task, components, base_weight, interval)
