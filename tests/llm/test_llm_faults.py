"""LLM faults against a real local OpenAI-compatible server: down, reset, 429 + Retry-After, truncated
JSON, a prompt over the context window. The client retries what a retry can fix (bounded), the
selector falls back, and both logs say so; a short training goes on through all of them.
"""

import json
import threading
import time

import pytest
import torch
from conftest import make_cfg
from llm_server import ScriptedServer, context_length_error, free_port

from torchrl_ahrs.app.shared.run_dir import DECISIONS, LLM_CALLS
from torchrl_ahrs.app.train.runs import read_scalar
from torchrl_ahrs.llm.client import LLMClient, LLMConfig, retry_after
from torchrl_ahrs.scheduling import RuleScheduler, load_repository
from torchrl_ahrs.scheduling.llm_selectors import LLMRuleSelector
from torchrl_ahrs.train import train

REPO = load_repository()
COMPONENTS = ["forward", "ctrl", "survive"]
TASK = {"name": "toy", "description": "A toy robot must walk forward.", "components": COMPONENTS}
RATE_LIMITED = b'{"error": {"message": "Rate limit reached", "type": "requests", "code": "rate_limit_exceeded"}}'
TOO_LONG = context_length_error()


def rate_limit(headers):
    return ("http", 429, headers, RATE_LIMITED)


class Estimator:
    def __init__(self, k=3):
        self.weights = torch.full((k,), 0.5)  # base weight: the scheduler keeps the estimator's weights

    def set_weights(self, weights):
        self.weights = weights.clone()


def scheduler_for(api_base, run_dir, **overrides):
    settings = dict(model="openai/test-model", api_base=api_base, timeout=2.0, max_retries=1, backoff=0.0)
    settings.update(overrides)
    client = LLMClient(LLMConfig(**settings), calls_path=run_dir / LLM_CALLS)  # real sleep: Retry-After is timed
    selector = LLMRuleSelector(client, REPO, TASK, COMPONENTS, base_weight=0.5, interval=1)
    return RuleScheduler(Estimator(), COMPONENTS, REPO, selector, interval=1, decisions_path=run_dir / DECISIONS)


def decide(scheduler):
    """One iteration with one finished episode, timed."""
    scheduler.statistics.add(torch.tensor([[1.0, 2.0, 4.0]]), torch.tensor([7.0]))
    started = time.monotonic()
    scheduler.step()
    return time.monotonic() - started


def jsonl(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture(scope="module", autouse=True)
def litellm_imported():
    """litellm's first import takes seconds; do it once so the per-case time bounds measure the case."""
    import litellm  # noqa: F401


@pytest.mark.parametrize(
    "script, error_name",
    [
        ([("reset", "~[2]~")], "Connection reset by peer"),
        ([("truncated", "~[2]~")], "JSONDecodeError"),
        ([rate_limit({"Retry-After": "0"})], "RateLimitError"),
    ],
    ids=["connection-reset", "truncated-json", "429-no-wait"],
)
def test_persistent_fault_is_retried_then_falls_back(llm_server, tmp_path, loopback_only, script, error_name):
    llm_server.script = script
    scheduler = scheduler_for(llm_server.api_base, tmp_path)
    assert decide(scheduler) < 3.0
    assert len(llm_server.requests) == 2  # one retry (max_retries=1), then the selector's fallback
    (call,) = jsonl(tmp_path / LLM_CALLS)
    assert call["response"] is None and call["attempts"] == 2 and error_name in call["error"]
    (decision,) = jsonl(tmp_path / DECISIONS)
    assert "LLM call failed after 2 attempt(s)" in decision["message"] and "weights kept" in decision["message"]
    assert scheduler.rule_id is None and scheduler.weights.tolist() == [0.5, 0.5, 0.5]


@pytest.mark.parametrize("fault", [("reset", "x"), ("truncated", "x")], ids=["connection-reset", "truncated-json"])
def test_one_fault_then_the_retry_answers(llm_server, tmp_path, loopback_only, fault):
    llm_server.script = [fault, ("ok", "~[3]~")]
    scheduler = scheduler_for(llm_server.api_base, tmp_path)
    decide(scheduler)
    assert scheduler.rule_id == 3 and jsonl(tmp_path / LLM_CALLS)[0]["attempts"] == 2


def test_server_down_falls_back_quickly(tmp_path, loopback_only):
    scheduler = scheduler_for(f"http://127.0.0.1:{free_port()}/v1", tmp_path, max_retries=2)
    assert decide(scheduler) < 3.0
    (call,) = jsonl(tmp_path / LLM_CALLS)
    assert call["attempts"] == 3 and call["error"].count("Connection refused") == 3
    assert "LLM call failed after 3 attempt(s)" in jsonl(tmp_path / DECISIONS)[0]["message"]


@pytest.mark.parametrize("header", [{"Retry-After": "1"}, {"retry-after-ms": "1000"}], ids=["seconds", "ms"])
def test_429_retry_after_is_honoured(llm_server, tmp_path, loopback_only, header):
    llm_server.script = [rate_limit(header), ("ok", "~[4]~")]
    scheduler = scheduler_for(llm_server.api_base, tmp_path)  # backoff=0: any wait comes from the header
    decide(scheduler)
    first, second = llm_server.requests
    assert 1.0 <= second["time"] - first["time"] < 2.5
    assert scheduler.rule_id == 4 and "RateLimitError" in jsonl(tmp_path / LLM_CALLS)[0]["error"]


def test_429_retry_after_beyond_the_bound_is_not_waited_for(llm_server, tmp_path, loopback_only):
    llm_server.script = [rate_limit({"Retry-After": "3600"})]
    scheduler = scheduler_for(llm_server.api_base, tmp_path, max_retries=3, max_retry_after=2.0)
    assert decide(scheduler) < 1.5
    assert len(llm_server.requests) == 1
    (call,) = jsonl(tmp_path / LLM_CALLS)
    assert "retry after 3600 s > llm.max_retry_after=2 s" in call["error"]
    assert "LLM call failed after 1 attempt(s)" in jsonl(tmp_path / DECISIONS)[0]["message"]


def test_retry_after_header_forms():
    class Limited(Exception):
        def __init__(self, headers):
            self.litellm_response_headers = headers

    in_ten_seconds = time.strftime("%a, %d %b %Y %H:%M:%S GMT", time.gmtime(time.time() + 10))
    assert retry_after(Limited({"Retry-After": "7"})) == 7.0
    assert retry_after(Limited({"retry-after-ms": "250", "retry-after": "9"})) == 0.25  # the finer one wins
    assert 8.0 < retry_after(Limited({"Retry-After": in_ten_seconds})) <= 10.0
    assert retry_after(Limited({"Retry-After": "soon"})) is None and retry_after(Limited({})) is None


def test_prompt_over_the_context_window_is_not_retried(llm_server, tmp_path, loopback_only):
    llm_server.script = [("ok", "~[5]~"), ("http", 400, {}, TOO_LONG)]
    scheduler = scheduler_for(llm_server.api_base, tmp_path, max_retries=5)
    decide(scheduler)
    assert scheduler.rule_id == 5
    for decisions_so_far in (2, 3):  # every later decision: one request, no retry, the previous rule stays
        assert decide(scheduler) < 1.5
        assert len(llm_server.requests) == decisions_so_far
        assert scheduler.rule_id == 5
    call = jsonl(tmp_path / LLM_CALLS)[-1]
    assert call["attempts"] == 1 and "ContextWindowExceededError" in call["error"]
    assert "maximum context length is 8192 tokens" in call["error"]
    message = jsonl(tmp_path / DECISIONS)[-1]["message"]
    assert "LLM call failed after 1 attempt(s)" in message and "previous rule 5 stays" in message


def rows(path):
    steps, values = read_scalar(path)
    return [(int(step), float(value)) for step, value in zip(steps, values, strict=True)]


@pytest.mark.slow
def test_training_goes_on_through_every_fault(tmp_path, loopback_only):
    """Decision 1: no server; 2: resets; 3: truncated JSON; 4: 429 then rule 4; 5: prompt too long
    (rule 4 stays); 6: rule 6. The server comes up once decision 1 is on record."""
    port = free_port()
    run_dir = tmp_path / "run"
    started: list[ScriptedServer] = []

    def start_server_after_first_call():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not (run_dir / LLM_CALLS).exists():
            time.sleep(0.01)
        server = ScriptedServer(port=port)
        server.script = [("reset", "x")] * 2 + [("truncated", "x")] * 2
        server.script += [
            rate_limit({"Retry-After": "1"}),
            ("ok", "~[4]~"),
            ("http", 400, {}, TOO_LONG),
            ("ok", "~[6]~"),
        ]
        started.append(server)

    watcher = threading.Thread(target=start_server_after_first_call, daemon=True)
    watcher.start()
    overrides = [
        "task=point_reach",
        "method=ahrs_wo_a",
        "llm=openai",
        "llm.model=openai/test-model",
        f"llm.api_base=http://127.0.0.1:{port}/v1",
        "llm.cache_dir=null",
        "llm.timeout=2",
        "llm.max_retries=1",
        "llm.backoff=0",
        "scheduler.interval=1",
        "task.max_episode_steps=20",
        "trainer.total_frames=3072",
        "trainer.num_envs=16",
        "trainer.frames_per_batch=512",
        "trainer.mini_batch_size=128",
        "trainer.num_epochs=1",
        "trainer.progress_bar=false",
        "model.hidden_sizes=[32,32]",
    ]
    cfg = make_cfg(*overrides)
    try:
        train(cfg, run_dir)
    finally:
        watcher.join(timeout=5)
        for server in started:
            server.close()

    decisions = jsonl(run_dir / DECISIONS)
    assert [decision["iteration"] for decision in decisions] == [1, 2, 3, 4, 5, 6]
    assert [decision["rule_id"] for decision in decisions] == [None, None, None, 4, 4, 6]
    messages = [decision["message"] for decision in decisions]
    assert all("LLM call failed after 2 attempt(s)" in message for message in messages[:3])
    assert "ContextWindowExceededError" in messages[4] and "previous rule 4 stays" in messages[4]
    calls = jsonl(run_dir / LLM_CALLS)
    for index, fault in ((0, "Connection refused"), (1, "Connection reset by peer"), (2, "JSONDecodeError")):
        assert fault in calls[index]["error"] and calls[index]["response"] is None
    assert [call["attempts"] for call in calls] == [2, 2, 2, 2, 1, 1]
    assert "RateLimitError" in calls[3]["error"] and calls[3]["parsed"] == 4
    assert len(started[0].requests) == 2 + 2 + 2 + 1 + 1
    steps = [step for step, _ in rows(run_dir / "metrics" / "scalars" / "return" / "total.csv")]
    assert steps == [512 * iteration for iteration in range(1, 7)]  # every iteration trained and logged
    assert (run_dir / "checkpoint.pt").is_file()
