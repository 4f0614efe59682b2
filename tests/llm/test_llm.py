"""LLM selection against a real OpenAI-compatible HTTP server on 127.0.0.1 started by the test.

The server answers from a script: valid, malformed, out-of-range, slow (past the client timeout),
HTTP 500, HTTP 429 and non-JSON bodies. In every case the scheduler goes on and the logs say what
happened. Any socket connection to a host other than 127.0.0.1 fails the test (no network).
"""

import json
import time

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from omegaconf import OmegaConf

from torchrl_ahrs.app.shared.run_dir import DECISIONS, LLM_CALLS
from torchrl_ahrs.app.shared.settings import scheduler_settings
from torchrl_ahrs.llm.answers import parse_rule_answer, parse_weights_answer
from torchrl_ahrs.llm.client import LLMClient, LLMConfig, ReplayMiss
from torchrl_ahrs.scheduling import RuleScheduler, build_scheduler, load_repository
from torchrl_ahrs.scheduling.llm_selectors import DirectWeightSelector, LLMRuleSelector

REPO = load_repository()
COMPONENTS = ["forward", "ctrl", "survive"]
TASK = {"name": "toy", "description": "A toy robot must walk forward.", "components": COMPONENTS}
SECRET = "sk-test-secret-0123456789"


@pytest.fixture(autouse=True)
def no_network(loopback_only, monkeypatch):
    """Only loopback connections are allowed while these tests run (``loopback_only`` in conftest)."""
    monkeypatch.setenv("TEST_LLM_KEY", SECRET)


@pytest.fixture
def server(llm_server):
    """The scripted server of ``tests/llm_server.py``."""
    return llm_server


def llm_config(server, **overrides):
    values = dict(
        name="openai",
        model="openai/test-model",
        api_base=f"http://127.0.0.1:{server.port}/v1",
        api_key_env="TEST_LLM_KEY",
        timeout=0.6,
        max_retries=1,
        backoff=0.0,
    )
    values.update(overrides)
    return LLMConfig(**values)


class Estimator:
    def __init__(self, k=3):
        self.weights = torch.full((k,), 0.5)  # base weight: the scheduler keeps the estimator's weights

    def set_weights(self, weights):
        self.weights = weights.clone()


def feed(scheduler, returns):
    """One iteration with one finished episode whose component returns are ``returns``."""
    scheduler.statistics.add(torch.tensor([returns]), torch.tensor([sum(returns)]))
    scheduler.step()


def llm_scheduler(server, run_dir, **config):
    client = LLMClient(llm_config(server, **config), calls_path=run_dir / LLM_CALLS, sleep=lambda seconds: None)
    selector = LLMRuleSelector(client, REPO, TASK, COMPONENTS, base_weight=0.5, interval=1)
    return RuleScheduler(Estimator(), COMPONENTS, REPO, selector, interval=1, decisions_path=run_dir / DECISIONS)


def calls(run_dir):
    return [json.loads(line) for line in (run_dir / LLM_CALLS).read_text().splitlines()]


def decisions(run_dir):
    return [json.loads(line) for line in (run_dir / DECISIONS).read_text().splitlines()]


def test_valid_answer_selects_rule_and_logs_call_without_secret(server, tmp_path):
    server.script = [("ok", "Forward lags behind, so I choose **~[ 7 ]~**.")]
    scheduler = llm_scheduler(server, tmp_path)
    feed(scheduler, [1.0, 2.0, 4.0])
    assert scheduler.rule_id == 7
    assert scheduler.weights.tolist() == pytest.approx([0.5 + 3 / 5, 0.5 + 2 / 5, 0.5])  # -mu = [-1,-2,-4]
    (entry,) = calls(tmp_path)
    assert entry["parsed"] == 7 and entry["error"] is None and entry["tokens"]["total_tokens"] == 105
    assert entry["model"] == "openai/test-model" and len(entry["prompt_hash"]) == 64 and entry["latency"] > 0
    prompt = entry["prompt"][0]["content"]
    assert "Mean Returns Only" in prompt and "~[1]~" in prompt and "1 to 8" in prompt and "[1, 2, 4]" in prompt
    assert server.requests[0]["auth"] == f"Bearer {SECRET}"  # the key reaches the server ...
    assert SECRET not in (tmp_path / LLM_CALLS).read_text()  # ... and never the log


def test_malformed_then_corrected(server, tmp_path):
    server.script = [("ok", "Rule three looks best."), ("ok", "~[3]~")]
    scheduler = llm_scheduler(server, tmp_path)
    feed(scheduler, [1.0, 2.0, 4.0])
    assert scheduler.rule_id == 3
    first, second = calls(tmp_path)
    assert first["parse_error"] == "no answer of the form ~[N]~ found" and second["purpose"] == "llm-correction"
    assert "could not be used" in server.requests[1]["body"]["messages"][-1]["content"]
    assert "corrective retry" in decisions(tmp_path)[-1]["message"]


def test_out_of_range_twice_keeps_previous_rule(server, tmp_path):
    server.script = [("ok", "~[1]~"), ("ok", "~[42]~")]
    scheduler = llm_scheduler(server, tmp_path)
    feed(scheduler, [1.0, 2.0, 4.0])
    assert scheduler.rule_id == 1
    feed(scheduler, [4.0, 2.0, 1.0])  # both answers out of range: rule 1 stays, recomputed on new stats
    assert scheduler.rule_id == 1 and scheduler.weights.tolist() == pytest.approx([0.5 + 3 / 4, 0.5 + 1 / 4, 0.5])
    assert [entry["parse_error"] for entry in calls(tmp_path)[1:]] == ["rule 42 is out of range 1..8"] * 2
    assert "invalid LLM answer twice" in decisions(tmp_path)[-1]["message"]
    assert "previous rule 1 stays" in decisions(tmp_path)[-1]["message"]


@pytest.mark.parametrize("failure", [("status", 500), ("status", 429), ("garbage", "<html>oops</html>")])
def test_transient_failure_is_retried(server, tmp_path, failure):
    server.script = [failure, ("ok", "~[5]~")]
    scheduler = llm_scheduler(server, tmp_path)
    feed(scheduler, [1.0, 2.0, 4.0])
    assert scheduler.rule_id == 5
    (entry,) = calls(tmp_path)
    assert entry["attempts"] == 2 and entry["error"]  # the failed attempt is on record


def test_persistent_failures_and_timeouts_keep_training_going(server, tmp_path):
    server.script = [("status", 500)]
    scheduler = llm_scheduler(server, tmp_path)
    feed(scheduler, [1.0, 2.0, 4.0])
    assert scheduler.rule_id is None and scheduler.weights.tolist() == [0.5, 0.5, 0.5]
    assert "LLM call failed after 2 attempt(s)" in decisions(tmp_path)[-1]["message"]
    server.script = [("slow", 2.0)]  # past the 0.6 s timeout on both attempts
    started = time.monotonic()
    feed(scheduler, [1.0, 2.0, 4.0])
    assert time.monotonic() - started < 2.0 + 1.0
    assert scheduler.rule_id is None and scheduler.iteration == 2
    assert "Timeout" in calls(tmp_path)[-1]["error"]


def test_direct_weights_validated(server, tmp_path):
    server.script = [("ok", "~[1, 2]~"), ("ok", "~[1, 1, 2]~")]  # wrong count, then valid
    client = LLMClient(llm_config(server), calls_path=tmp_path / LLM_CALLS)
    selector = DirectWeightSelector(client, TASK, COMPONENTS, 0.5, 1)
    scheduler = RuleScheduler(Estimator(), COMPONENTS, REPO, selector, interval=1, decisions_path=tmp_path / DECISIONS)
    feed(scheduler, [1.0, 2.0, 4.0])
    assert scheduler.weights.tolist() == pytest.approx([0.75, 0.75, 1.0]) and scheduler.rule_id is None
    assert calls(tmp_path)[0]["parse_error"] == "expected 3 weights, got 2"


def test_cache_makes_reruns_free(server, tmp_path):
    server.script = [("ok", "~[4]~")]
    messages = [{"role": "user", "content": "pick"}]
    first = LLMClient(llm_config(server, cache_dir=str(tmp_path / "cache")), calls_path=tmp_path / "a" / LLM_CALLS)
    assert first.complete(messages, "t").text == "~[4]~" and len(server.requests) == 1
    second = LLMClient(llm_config(server, cache_dir=str(tmp_path / "cache")), calls_path=tmp_path / "b" / LLM_CALLS)
    reply = second.complete(messages, "t")
    assert reply.text == "~[4]~" and reply.source == "cache" and len(server.requests) == 1


def run_schedule(config, run_dir, rounds=6):
    cfg = OmegaConf.create(
        {
            "seed": 0,
            "task": TASK,
            "method": {"selector": "llm", "initial_weights": None},
            "llm": config,
            "scheduler": {"interval": 1, "history_length": 5, "base_weight": 0.5, "rules": None, "blocking": True},
        }
    )
    scheduler = build_scheduler(
        scheduler_settings(cfg), Estimator(), COMPONENTS, run_dir / DECISIONS, llm_calls_path=run_dir / LLM_CALLS
    )
    schedule = []
    for i in range(rounds):
        feed(scheduler, [float(i), 2.0 - i, (i * 7) % 5])
        schedule.append((scheduler.rule_id, scheduler.weights.tolist()))
    return schedule


def test_replay_reproduces_a_schedule_without_the_server(server, tmp_path):
    server.script = [("ok", f"~[{n}]~") for n in (3, 1, 8, 8, 2)] + [("ok", "no idea"), ("ok", "~[6]~")]
    base = {"name": "openai", "model": "openai/test-model", "api_base": f"http://127.0.0.1:{server.port}/v1"}
    base.update(api_key_env="TEST_LLM_KEY", timeout=0.6, max_retries=0, backoff=0.0)
    recorded = run_schedule(base, tmp_path / "recorded")
    assert [rule for rule, _ in recorded] == [3, 1, 8, 8, 2, 6]
    server.close()
    replayed = run_schedule(
        {"name": "replay", "model": "replay", "replay_from": str(tmp_path / "recorded" / LLM_CALLS)},
        tmp_path / "replay",
    )
    assert replayed == recorded
    assert all(entry["source"] == "replay" for entry in calls(tmp_path / "replay"))
    with pytest.raises(ReplayMiss):  # one more decision than recorded
        run_schedule(
            {"name": "replay", "model": "replay", "replay_from": str(tmp_path / "recorded" / LLM_CALLS)},
            tmp_path / "x",
            rounds=7,
        )


@settings(max_examples=300, deadline=None)
@given(
    st.integers(1, 20),
    st.integers(1, 20),
    st.text(alphabet=st.characters(blacklist_characters="~"), max_size=40),
    st.sampled_from(["{}", "~[{}]~", "**~[{}]~**", "`~[{}]~`", "~ [ {} ] ~", "~{}~", "\n~[\t{} ]~\n"]),
)
def test_rule_parser_properties(rule_id, num_rules, noise, wrapper):
    text = noise + (wrapper.format(rule_id) if wrapper != "{}" else str(rule_id)) + noise
    if wrapper == "{}":
        with pytest.raises(ValueError):
            parse_rule_answer(text, num_rules)
    elif rule_id <= num_rules:
        assert parse_rule_answer(text, num_rules) == rule_id
    else:
        with pytest.raises(ValueError, match="out of range"):
            parse_rule_answer(text, num_rules)


@settings(max_examples=120, deadline=None)
@given(st.text(max_size=80))
def test_parsers_never_crash_on_garbage(text):
    for parse, argument in ((parse_rule_answer, 8), (parse_weights_answer, 3)):
        try:
            parse(text, argument)
        except ValueError:
            pass


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0, 1e3, allow_nan=False), min_size=1, max_size=8))
def test_weights_parser_round_trip(values):
    text = "Here: ~[" + ", ".join(repr(v) for v in values) + "]~"
    if sum(values) > 0:
        assert parse_weights_answer(text, len(values)) == pytest.approx(values)
    else:
        with pytest.raises(ValueError):
            parse_weights_answer(text, len(values))


GENERATED_ANSWER = '''Here are my rules.

```python
import torch

GAIN = 2.0

def doubled_mean(mean_returns, var_returns, history, previous_weights):
    """Doubled Mean

    Twice the mean.

    math: s_k = 2 mu_k
    """
    return GAIN * mean_returns

def sneaky(mean_returns, var_returns, history, previous_weights):
    import os
    return mean_returns

def divides_by_zero(mean_returns, var_returns, history, previous_weights):
    return mean_returns / (var_returns - var_returns)

def helper(x):
    return x
```

```python
def spread(mean_returns, var_returns, history, previous_weights):
    """Spread

    Standard deviation.

    math: s_k = sqrt(sigma2_k)
    """
    return torch.sqrt(var_returns)
```
'''


def test_generate_rules_writes_a_sandboxed_repository(server, tmp_path):
    from torchrl_ahrs.app.generate.rules import generate

    server.script = [("ok", GENERATED_ANSWER)]
    cfg = OmegaConf.create(
        {
            "task": TASK,
            "llm": {
                "name": "openai",
                "model": "openai/test-model",
                "api_base": f"http://127.0.0.1:{server.port}/v1",
                "api_key_env": "TEST_LLM_KEY",
                "timeout": 2.0,
                "max_retries": 0,
            },
        }
    )
    result = generate(cfg, tmp_path)
    assert sorted(result.accepted) == ["doubled_mean", "spread"]
    assert "import of 'os'" in " ".join(result.refused["sneaky"])
    assert "not finite" in " ".join(result.refused["divides_by_zero"])
    assert "takes 1 arguments" in result.refused["helper"][0]
    prompt = server.requests[0]["body"]["messages"][0]["content"]
    assert "def hdpg(" in prompt and "forward" in prompt
    repo = load_repository(result.path)
    assert [rule.name for rule in repo] == ["Doubled Mean", "Spread"]
    assert "provenance: model=openai/test-model" in repo.provenance and "prompt_hash=" in repo.provenance
    assert repo[1].weights(
        torch.tensor([1.0, 2.0, 4.0]), torch.zeros(3), torch.zeros(5, 3), torch.ones(3), 0.5
    ).tolist() == pytest.approx([0.5, 0.5 + 1 / 4, 0.5 + 3 / 4])
