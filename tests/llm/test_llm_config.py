"""LLM selection that cannot surprise: a model under llm=offline is refused, selectors built from a model
string take the scheduler's settings, and one decision is bounded by one total budget."""

import time

import pytest
import torch
from llm_server import free_port
from omegaconf import OmegaConf

from torchrl_ahrs import LLMRuleSelector, RuleScheduler
from torchrl_ahrs.app.shared.settings import scheduler_settings
from torchrl_ahrs.scheduling import build_selector, load_repository
from torchrl_ahrs.scheduling.selectors import DecisionContext, Summary

COMPONENTS = ["forward", "ctrl"]


class Estimator:
    components = COMPONENTS
    weights = torch.full((2,), 0.5)

    def set_weights(self, weights):
        self.weights = weights.clone()


def context():
    summary = Summary(count=1, mean=[1.0, 0.0], var=[0.0, 0.0])
    return DecisionContext(
        components=COMPONENTS,
        mean=torch.tensor([1.0, 0.0]),
        var=torch.zeros(2),
        history=torch.zeros(5, 2),
        previous_weights=torch.full((2,), 0.5),
        summary=summary,
        past=[],
        previous_rule_id=None,
        iteration=1,
        decision_index=0,
    )


def test_a_model_under_llm_offline_fails_at_start_in_one_line():
    cfg = OmegaConf.create({"method": {"selector": "llm"}, "llm": {"name": "offline", "model": "openai/gpt-4o"}})
    with pytest.raises(ValueError, match=r"^llm.model=openai/gpt-4o is set but llm=offline never calls") as error:
        build_selector(scheduler_settings(cfg), load_repository(), COMPONENTS, None)
    assert "\n" not in str(error.value)


def test_selector_from_a_model_string_takes_the_schedulers_settings(llm_server):
    selector = LLMRuleSelector.from_model("openai/test-model", api_base=llm_server.api_base, backoff=0.0)
    assert (selector.components, selector.base_weight, selector.interval) == (None, None, None)
    RuleScheduler(Estimator(), selector=selector, interval=7, base_weight=0.25)
    assert (selector.components, selector.base_weight, selector.interval) == (COMPONENTS, 0.25, 7)
    llm_server.script = [("ok", "~[2]~")]
    assert selector.select(context()).rule_id == 2  # a real HTTP answer through the built client
    with pytest.raises(ValueError, match=r"selector's interval=7 differs from the scheduler's interval=3"):
        RuleScheduler(Estimator(), selector=selector, interval=3, base_weight=0.25)


def test_one_budget_bounds_the_whole_decision(llm_server):
    llm_server.script = [("slow", 3.0)]  # every attempt outlasts the budget
    selector = LLMRuleSelector.from_model(
        "openai/test-model", api_base=llm_server.api_base, timeout=2.0, max_retries=3, backoff=0.0, decision_budget=1.0
    )
    RuleScheduler(Estimator(), selector=selector, interval=1)
    started = time.monotonic()
    decision = selector.select(context())
    elapsed = time.monotonic() - started
    assert elapsed < 1.9, elapsed  # without the budget: 4 attempts x 2 s
    assert decision.keeps_weights and "decision budget spent" in decision.note


def test_server_down_is_bounded_by_the_budget_not_the_backoff():
    selector = LLMRuleSelector.from_model(
        "openai/test-model", api_base=f"http://127.0.0.1:{free_port()}/v1", max_retries=3, decision_budget=0.5
    )  # default backoff 2 s: 2 + 4 + 8 s of sleeping without a budget
    RuleScheduler(Estimator(), selector=selector, interval=1)
    started = time.monotonic()
    decision = selector.select(context())
    assert time.monotonic() - started < 1.5 and "decision budget spent after 1 attempt(s)" in decision.note


def test_build_scheduler_with_an_llm_from_a_plain_dict(llm_server):
    from torchrl_ahrs import build_scheduler

    cfg = {
        "method": {"selector": "llm"},
        "llm": {"name": "openai", "model": "openai/x", "api_base": llm_server.api_base},
    }
    scheduler = build_scheduler(scheduler_settings(cfg), Estimator())
    assert scheduler.selector.name == "llm" and scheduler.selector.client.config.model == "openai/x"
    assert (scheduler.selector.interval, scheduler.selector.base_weight) == (100, 0.5)  # the scheduler's, once


def test_build_scheduler_with_an_llm_from_typed_settings_alone(llm_server, tmp_path):
    from torchrl_ahrs.llm.client import LLMConfig
    from torchrl_ahrs.scheduling import SchedulerSettings, ScheduleSettings, SelectionSettings, build_scheduler

    settings = SchedulerSettings(
        schedule=ScheduleSettings(interval=4, base_weight=0.25),
        selection=SelectionSettings(selector="direct"),
        llm=LLMConfig(name="openai", model="openai/typed", api_base=llm_server.api_base, backoff=0.0),
        task={"name": "toy", "description": "walk", "components": COMPONENTS},
    )
    scheduler = build_scheduler(settings, Estimator(), llm_calls_path=tmp_path / "calls.jsonl")
    assert scheduler.selector.name == "direct" and scheduler.selector.client.config.model == "openai/typed"
    assert (scheduler.selector.interval, scheduler.selector.base_weight) == (4, 0.25)
    assert scheduler.selector.task["description"] == "walk"
