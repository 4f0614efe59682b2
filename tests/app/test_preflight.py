"""Start-up checks (torchrl_ahrs/app/train/preflight.py): every mistake of a user's first hour that used to train, exit 0
or end in a traceback is one line on stderr and exit status 2, through the real command line."""

import os
import subprocess
import sys

import pytest
from conftest import make_cfg

from torchrl_ahrs.app.train.build import env_factory
from torchrl_ahrs.app.train.preflight import PreflightError, check_task_rewards
from torchrl_ahrs.llm.client import LLMClient, LLMConfig

SHORT = [
    "trainer.total_frames=1024",
    "trainer.num_envs=8",
    "trainer.frames_per_batch=512",
    "trainer.mini_batch_size=256",
]


def train_command(tmp_path, *overrides: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "torchrl_ahrs.train", "task=point_reach", *SHORT, *overrides]
    command.append(f"hydra.run.dir={tmp_path / 'run'}")
    return subprocess.run(command, capture_output=True, text=True, timeout=300, env=env)


def train_in_process(tmp_path, capsys, monkeypatch, *overrides: str) -> subprocess.CompletedProcess:
    """The command line in a child process. (It ran in this process once, through ``torchrl_ahrs.train.main``; in
    the full suite, Hydra's first in-process run then broke pytest's own streams, "I/O operation on closed file",
    and ended the whole session: a user's command is its own process, so the test is too.)"""
    return train_command(tmp_path, *overrides)


def assert_one_line_error(result: subprocess.CompletedProcess, expected: str) -> None:
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    assert "Traceback" not in result.stderr and "Warning" not in result.stderr, result.stderr[-2000:]
    errors = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and expected in errors[0], result.stderr[-2000:]
    assert result.stderr.strip().splitlines()[-1] == errors[0]  # nothing after it: the line says it all


@pytest.mark.parametrize(
    "override, expected",
    [
        # Hydra's own hint for the first one is the second, which it accepts and stores in config.yaml
        ("trainer.total_frame=1000", "error: trainer.total_frame is not a key of the shipped config (did you mean "),
        ("+trainer.total_frame=1000", "error: +trainer.total_frame is not a key of the shipped config (did you mean "),
        ("++model.hiden_sizes=[8]", "error: ++model.hiden_sizes is not a key of the shipped config (did you mean "),
        ("seed=1e400", "error: seed must be a finite number, got inf"),
        ("trainer.lr=nan", "error: trainer.lr must be a finite number, got nan"),
        (
            "seed=${oc.env:TORCHRL_AHRS_NOT_SET}",
            "error: seed cannot be resolved: \"Environment variable 'TORCHRL_AHRS_",
        ),
        (
            "trainer.lr=${trainer.nope}",
            "error: trainer.lr cannot be resolved: Interpolation key 'trainer.nope' not found",
        ),
        ("seed=1.5", "error: seed must be an integer, got 1.5"),
        (
            "model.hidden_sizes=[]",
            "error: model.hidden_sizes must list at least one positive width (e.g. [64,64]), got []",
        ),
        ("model.hidden_sizes=[64,0]", "error: model.hidden_sizes must list at least one positive width"),
        ("model.component_hidden_sizes=[]", "error: model.component_hidden_sizes must list at least one positive"),
        # dmc_cheetah_run ships jog_speed, so the shipped-key check passes it; point_reach's task has no such setting
        ("+trainer.task_overrides.jog_speed=3.0", "error: task.jog_speed is not a setting of task 'point_reach'"),
    ],
)
def test_config_mistakes_are_one_line_and_exit_2(tmp_path, capsys, monkeypatch, override, expected):
    result = train_in_process(tmp_path, capsys, monkeypatch, override)
    assert_one_line_error(result, expected)
    assert not (tmp_path / "run" / "config.yaml").exists()  # refused before the run directory got a config


def test_the_real_command_line_refuses_a_plus_key(tmp_path):
    result = train_command(tmp_path, "+trainer.total_frame=1000")
    assert_one_line_error(result, "error: +trainer.total_frame is not a key of the shipped config (did you mean ")


def test_a_key_another_task_ships_is_refused_by_this_tasks_settings(tmp_path, capsys, monkeypatch):
    """``+task.jog_speed`` passes the shipped-key check (dmc_cheetah_run has it) but is no setting of point_reach:
    one line naming the key and the task, before anything is built (it used to be ignored)."""
    result = train_in_process(tmp_path, capsys, monkeypatch, "+task.jog_speed=3.0")
    assert_one_line_error(result, "error: task 'point_reach': unknown key 'jog_speed'; its keys are ")


def test_shipped_optional_keys_stay_accepted():
    """A key one option of a group ships (num_threads: several tasks) is fine with + on any option."""
    from torchrl_ahrs.app.train.preflight import check_command_line

    check_command_line(["task=point_reach", "+task.num_threads=1", "+task.critic_observation=x", "hydra.run.dir=x"])
    check_command_line(["+sweep=smoke", "hydra/launcher=local", "method.rule=a,b", "seed=range(1,3)", "-m"])
    check_command_line(["+trainer.task_overrides.max_episode_steps=40"])  # a task's key, for training only


@pytest.mark.skipif(__import__("importlib").util.find_spec("wandb") is not None, reason="wandb is installed")
def test_missing_logger_package_names_the_extra(tmp_path, capsys, monkeypatch):
    result = train_in_process(tmp_path, capsys, monkeypatch, "logger.backends=[csv,wandb]")
    assert_one_line_error(
        result,
        "error: logger.backends has wandb but the wandb package is not installed: pip install 'torchrl-ahrs[wandb]'",
    )


def without(*names: str) -> dict[str, str]:
    return {key: value for key, value in os.environ.items() if key not in names}


def test_missing_llm_key_is_refused_at_start(tmp_path, loopback_only):
    result = train_command(tmp_path, "method=ahrs", "llm=openai", env=without("OPENAI_API_KEY"))
    assert_one_line_error(
        result, "error: llm.model=openai/gpt-4o needs the OPENAI_API_KEY environment variable, which is not set"
    )
    # the same config with a key (or a local server) passes the check: it is the key that is missing
    from torchrl_ahrs.app.train.preflight import check_config

    check_config(make_cfg("task=point_reach", "method=ahrs", "llm=openai", "llm.api_base=http://127.0.0.1:9/v1"))
    check_config(make_cfg("task=point_reach", "method=ppo", "llm=openai"))  # ppo never asks the LLM


def test_generate_aux_without_a_key_says_so_once(tmp_path):
    command = [sys.executable, "-m", "torchrl_ahrs.generate_aux", "task=point_reach", "llm=openai"]
    command.append(f"hydra.run.dir={tmp_path}")
    result = subprocess.run(command, capture_output=True, text=True, timeout=120, env=without("OPENAI_API_KEY"))
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "needs the OPENAI_API_KEY environment variable" in lines[0], result.stderr[-2000:]
    assert len(result.stderr) < 400  # was 3.8 KB of the same "Missing credentials", retried for ~30 s


def test_a_key_that_never_reaches_the_provider_is_not_retried(tmp_path, loopback_only):
    """litellm reports the SDK's "Missing credentials" as an InternalServerError (a 5xx): one attempt, no backoff."""
    sleeps: list[float] = []
    config = LLMConfig(name="openai", model="openai/gpt-4o", api_key_env="TORCHRL_AHRS_NOT_SET", max_retries=3)
    client = LLMClient(config, calls_path=tmp_path / "calls.jsonl", sleep=sleeps.append)
    reply = client.complete([{"role": "user", "content": "hi"}], purpose="test")
    assert reply.text is None and reply.attempts == 1 and sleeps == []
    assert "Missing credentials" in reply.error
    assert (tmp_path / "calls.jsonl").read_text().count("\n") == 1  # the call is still logged


def test_an_unknown_info_term_names_the_key_and_the_keys_that_exist(tmp_path):
    """Ant-v5's healthy bonus is reward_survive; reward_healthy used to make a component that was zero forever."""
    result = train_command(tmp_path, "task=ant_v5", "method=mcppo", "task.terms.survive=reward_healthy")
    assert_one_line_error(
        result,
        "error: component 'survive' reads info.reward_healthy, which the environment never writes; info has: "
        "elapsed_step, reward_contact, reward_ctrl, reward_forward, reward_survive",
    )


def test_components_that_miss_part_of_the_native_reward_are_refused(tmp_path, capsys, monkeypatch):
    result = train_in_process(tmp_path, capsys, monkeypatch, "method=mcppo", "task.components=[distance,arrival]")
    assert_one_line_error(
        result, "error: the components distance + arrival do not add up to the native reward on the first steps"
    )


def test_the_reward_check_leaves_the_random_streams_alone():
    import random

    import numpy as np
    import torch

    cfg = make_cfg("task=point_reach", "method=mcppo")
    torch.manual_seed(0), np.random.seed(0), random.seed(0)
    check_task_rewards(env_factory(cfg, check_aux=False), seed=0)
    after = (torch.rand(1).item(), np.random.rand(), random.random())
    torch.manual_seed(0), np.random.seed(0), random.seed(0)
    assert after == (torch.rand(1).item(), np.random.rand(), random.random())
    with pytest.raises(PreflightError, match="do not add up"):
        check_task_rewards(env_factory(make_cfg("task=point_reach", "task.components=[distance]"), check_aux=False), 0)
