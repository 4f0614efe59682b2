"""python -m torchrl_ahrs.generate_aux against a local scripted LLM server (127.0.0.1): refusals fed back, provenance
saved, the attempt budget, and candidates trained and compared on their training statistics."""

import json
from pathlib import Path

import pytest
from conftest import FAST, make_cfg
from omegaconf import OmegaConf

from torchrl_ahrs.app.shared.auxiliary import validate_aux_file
from torchrl_ahrs.app.shared.settings import load_task_config


def task_dict(name, **extra):
    return {**OmegaConf.to_container(load_task_config(name), resolve=True), **extra}


GOOD_ANSWER = """Here is the function.
```python
import torch

def compute_aux_reward(obs):
    # Thoughts: reward speed towards the target.
    observation = obs["observation"]
    to_target = observation[:, 4:6]
    direction = to_target / (to_target.norm(dim=-1, keepdim=True) + 1e-6)
    return 0.1 * (observation[:, 2:4] * direction).sum(-1)
```"""


HOSTILE_ANSWER = "```python\nimport os\n\ndef compute_aux_reward(obs):\n    return obs['reward.total']\n```"


NAN_ANSWER = "```python\nimport torch\n\ndef compute_aux_reward(obs):\n    return obs['reward.total'] / 0.0\n```"


def _generator_cfg(server, attempts=3):
    cfg = make_cfg(
        "task=point_reach", f"aux.generate.attempts={attempts}", "aux.generate.num_envs=4", "aux.generate.steps=4"
    )
    llm = {
        "name": "openai",
        "model": "openai/test-model",
        "api_base": f"http://127.0.0.1:{server.port}/v1",
        "api_key_env": "TEST_LLM_KEY",
        "timeout": 5.0,
        "max_retries": 0,
    }
    return OmegaConf.merge(cfg, {"llm": llm})


@pytest.mark.slow
def test_generator_feeds_refusals_back_and_saves_with_provenance(llm_server, loopback_only, tmp_path, monkeypatch):
    from torchrl_ahrs.app.generate.aux import generate

    monkeypatch.setenv("TEST_LLM_KEY", "sk-test")
    llm_server.script = [("ok", HOSTILE_ANSWER), ("ok", NAN_ANSWER), ("ok", GOOD_ANSWER)]
    result = generate(_generator_cfg(llm_server), tmp_path)
    assert result.path is not None and result.attempts == 3, result.refusals
    assert "import of 'os'" in " ".join(result.refusals[0]) and "not finite" in " ".join(result.refusals[1])
    first = llm_server.requests[0]["body"]["messages"]
    assert "def reward_terms(" in first[0]["content"] and 'obs["observation"]: shape [N, 6]' in first[0]["content"]
    retry = llm_server.requests[1]["body"]["messages"]
    assert retry[1]["role"] == "assistant" and "import of 'os'" in retry[2]["content"]
    text = result.path.read_text()
    assert "provenance: model=openai/test-model" in text and "prompt_hash=" in text and "attempt 3" in text
    assert validate_aux_file(result.path, task_dict("point_reach"), num_envs=2, steps=2).ok
    assert (tmp_path / "llm_calls.jsonl").read_text().count("\n") == 3


def test_generator_gives_up_after_the_configured_attempts(llm_server, loopback_only, tmp_path, monkeypatch):
    from torchrl_ahrs.app.generate.aux import generate

    monkeypatch.setenv("TEST_LLM_KEY", "sk-test")
    llm_server.script = [("ok", HOSTILE_ANSWER)]
    result = generate(_generator_cfg(llm_server, attempts=2), tmp_path)
    assert result.path is None and result.attempts == 2 and len(llm_server.requests) == 2
    assert not list(Path(tmp_path).glob("*.py"))


SMALLER_ANSWER = GOOD_ANSWER.replace("0.1 * (", "0.01 * (")


def test_generator_trains_candidates_feeds_statistics_back_and_keeps_every_candidate(
    llm_server, loopback_only, tmp_path, monkeypatch
):
    from torchrl_ahrs.app.train.runs import read_scalar as read_csv
    from torchrl_ahrs.generate_aux import generate
    from torchrl_ahrs.reporting.stats import final_return

    monkeypatch.setenv("TEST_LLM_KEY", "sk-test")
    llm_server.script = [("ok", GOOD_ANSWER), ("ok", HOSTILE_ANSWER), ("ok", SMALLER_ANSWER)]
    cfg = OmegaConf.merge(
        _generator_cfg(llm_server, attempts=3),
        make_cfg(*FAST, "method=ahrs", "aux.generate.train_rounds=2", "aux.generate.train_frames=2048"),
        {"llm": _generator_cfg(llm_server).llm},
    )
    result = generate(cfg, tmp_path)
    second = llm_server.requests[1]["body"]["messages"]
    feedback = second[-1]["content"]
    assert second[-2]["content"] == GOOD_ANSWER and "I trained an agent" in feedback
    for name in ["distance", "arrival", "ctrl", "aux", "total (the task's own reward)"]:
        assert f"- {name}: " in feedback, name  # every component's statistics go back
    index = json.loads((tmp_path / "candidates.json").read_text())
    attempts = {c["attempt"]: c for c in index["candidates"]}
    assert (
        sorted(attempts) == [1, 2, 3] and attempts[2]["path"] is None and "import of 'os'" in attempts[2]["reasons"][0]
    )
    finals = {}
    for attempt in (1, 3):  # oracle: the final return/total read from each round's own metrics
        steps, values = read_csv(
            tmp_path / "candidates" / f"attempt_{attempt}" / "run" / "metrics" / "scalars" / "return" / "total.csv"
        )
        finals[attempt] = final_return(steps, values, 2048, 0.25)
        assert attempts[attempt]["scores"]["final return/total"] == pytest.approx(finals[attempt])
        assert (tmp_path / "candidates" / f"attempt_{attempt}" / "aux_reward.py").is_file()
    best = max(finals, key=finals.get)
    assert index["chosen_attempt"] == best == result.chosen_attempt
    chosen_code = (tmp_path / "candidates" / f"attempt_{best}" / "aux_reward.py").read_text()
    assert result.path == tmp_path / "aux_reward.py" and result.path.read_text() == chosen_code
