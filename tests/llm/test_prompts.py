"""The paper's prompts carry the task description, each component's meaning and its reward code,
read from our implementation: checked on the request a real HTTP server on 127.0.0.1 receives."""

import inspect
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from torchrl_ahrs.app.shared.settings import load_task_config, scheduler_settings
from torchrl_ahrs.envs.tasks.ant import AntEnv, ant_reward_terms
from torchrl_ahrs.llm.task_text import AUX_MEANING, reward_code_blocks, source_of
from torchrl_ahrs.rewards.auxiliary import shipped_aux_path
from torchrl_ahrs.scheduling import build_scheduler

CONF = Path(__file__).resolve().parents[2] / "conf"  # packaged as torchrl_ahrs.conf


class Estimator:
    def __init__(self, k):
        self.weights = torch.ones(k)

    def set_weights(self, weights):
        self.weights = weights.clone()


def ant_cfg(server, selector="llm"):
    task = load_task_config("ant")
    return OmegaConf.create(
        {
            "seed": 0,
            "task": task,
            "method": {"name": "ahrs", "selector": selector, "rule": None, "initial_weights": None},
            "scheduler": {"interval": 1, "history_length": 5, "base_weight": 0.5, "rules": None, "blocking": True,
                          "weight_mapping": "softmax", "temperature": 1.0},
            "aux": {"path": None},
            "llm": {"name": "openai", "model": "openai/test-model", "api_base": f"http://127.0.0.1:{server.port}/v1",
                    "api_key_env": None, "timeout": 2.0, "max_retries": 0},
        }
    )  # fmt: skip


@pytest.mark.parametrize("selector, answer", [("llm", "~[2]~"), ("direct", "~[1, 1, 1, 1, 1, 1, 1, 1, 2]~")])
def test_selection_prompt_sent_holds_description_meanings_and_reward_code(
    llm_server, loopback_only, tmp_path, selector, answer
):
    llm_server.script = [("ok", answer)]
    cfg = ant_cfg(llm_server, selector)
    components = [*cfg.task.components, "aux"]
    scheduler = build_scheduler(
        scheduler_settings(cfg),
        Estimator(len(components)),
        components,
        tmp_path / "decisions.jsonl",
        llm_calls_path=tmp_path / "calls.jsonl",
    )
    scheduler.statistics.add(torch.arange(len(components), dtype=torch.float32)[None], torch.tensor([3.0]))
    scheduler.step()
    prompt = llm_server.requests[0]["body"]["messages"][0]["content"]
    assert " ".join(cfg.task.description.split()) in " ".join(prompt.split())
    for index, name in enumerate(cfg.task.components, start=1):
        assert f"{index}. {name}: {cfg.task.component_descriptions[name]}" in prompt
    assert f"9. aux: {AUX_MEANING}" in prompt  # the auxiliary component is explained, not just named
    assert inspect.getsource(ant_reward_terms).strip() in prompt  # our code, as it runs
    assert shipped_aux_path("ant").read_text().strip() in prompt  # aux's code: the file the run uses
    assert inspect.getsource(AntEnv.observation).strip() in prompt  # environment description
    if selector == "llm":
        assert "softmax(z / 1)" in prompt and "1. Mean Returns Only" in prompt
        assert scheduler.rule_id == 2
    else:
        assert scheduler.rule_id is None and scheduler.weights[-1] > scheduler.weights[0]


def test_every_shipped_task_documents_each_component():
    for path in sorted(p for p in (CONF / "task").glob("*.yaml") if not p.name.startswith("_")):  # _: bases
        task = OmegaConf.to_container(load_task_config(path.stem), resolve=True)
        meanings = task.get("component_descriptions") or {}
        assert set(meanings) == set(task["components"]), path.name
        assert all(meanings.values()), path.name
        for names, source in reward_code_blocks(task, task["components"]):
            assert source.strip() and set(names) <= set(task["components"])
        if task.get("reward_code"):
            assert reward_code_blocks(task, task["components"]), f"{path.name}: a reward_code reference is stale"


def test_code_references_outside_the_package_are_refused():
    with pytest.raises(ValueError, match="inside torchrl_ahrs"):
        source_of("os:system")
