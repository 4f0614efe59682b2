"""End-to-end training: the return goes up, metrics land in the run directory, bad configs fail clearly."""

import re
import subprocess
import sys

import pytest
import torch
from conftest import make_cfg

from torchrl_ahrs.app.shared.config import validate_config
from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.train.runs import read_scalar as read_scalar_file
from torchrl_ahrs.train import train

FAST = [
    "trainer.num_envs=32",
    "trainer.frames_per_batch=1024",
    "trainer.mini_batch_size=256",
    "trainer.num_epochs=10",
    "trainer.lr=1e-3",
    "trainer.progress_bar=false",
    "ppo.gamma=0.95",
    "model.hidden_sizes=[64,64]",
    "ppo.value_norm=running",  # the per-head value normalisation of the presets (K = 3 heads here)
]


def read_scalar(run_dir, name):
    return read_scalar_file(run_dir / "metrics" / "scalars" / f"{name}.csv")[1].tolist()


@pytest.mark.slow
def test_hdppo_learns_point_reach_and_logs_every_component(tmp_path):
    cfg = make_cfg("task=point_reach", "method=hdppo", "trainer.total_frames=49152", "scheduler.interval=5", *FAST)
    train(cfg, tmp_path)
    returns = read_scalar(tmp_path, "return/total")
    first, last = sum(returns[:3]) / 3, sum(returns[-3:]) / 3
    # a random policy scores about -92; the hand-written controller about +33
    assert last > first + 20, f"return did not go up: first {first:.1f}, last {last:.1f}"
    for name in ("distance", "arrival", "ctrl"):
        assert read_scalar(tmp_path, f"return/{name}")
        assert len(read_scalar(tmp_path, f"reward/{name}")) == 49152 // (32 * 32)  # every iteration
        weights = read_scalar(tmp_path, f"weight/{name}")
        assert all(0.5 <= weight <= 0.5 + 3 for weight in weights)  # w = 0.5 + mapping share, K = 3
    assert len(set(read_scalar(tmp_path, "weight/distance"))) > 1, "the HDPG rule never changed the weights"
    assert (tmp_path / "checkpoint.pt").exists()
    assert "point_reach" in (tmp_path / "config.yaml").read_text()


@pytest.mark.slow
def test_ant_v5_preset_regime_learns(tmp_path):
    """The CI learning test on a preset regime (issue 12, item 7): ant_v5's CleanRL-geometry preset."""
    cfg = make_cfg("task=ant_v5", "method=ppo", "trainer.total_frames=61440", "trainer.progress_bar=false")
    assert cfg.trainer.mini_batch_size == 64 and cfg.ppo.value_norm == "running"  # the preset, not the defaults
    assert cfg.ppo.advantage_pass == "once_per_batch"  # CleanRL's order (session 36)
    train(cfg, tmp_path)
    reward_per_step = read_scalar(tmp_path, "reward/total")
    first, last = sum(reward_per_step[:3]) / 3, sum(reward_per_step[-3:]) / 3
    # mean action is ~0 for the untrained tanh-Gaussian: ~+0.07 per step (survive 1, ctrl cost ~0.9); the
    # preset's recorded runs pass +0.3 per step by 60k frames (benchmarks/results/learning/ant_v5_preset_seed1)
    assert last > first + 0.1, f"reward per step did not go up: first {first:.3f}, last {last:.3f}"


def test_ppo_is_the_same_loop_with_one_head_on_total(tmp_path):
    cfg = make_cfg("task=point_reach", "method=ppo", "trainer.total_frames=4096", *FAST)
    metrics = train(cfg, tmp_path)
    assert metrics["weight/total"] == 1.0
    assert "return/distance" not in metrics and "return/total" in metrics


@pytest.mark.parametrize(
    "override, message",
    [
        ("trainer.total_frames=-5", "trainer.total_frames must be a positive integer"),
        ("trainer.num_envs=0", "trainer.num_envs must be a positive integer"),
        ("trainer.lr=0", "trainer.lr must be positive"),
        ("method.initial_weights=[1.0,2.0]", "method.initial_weights has 2 values"),
        ("method.components=[distance,speed]", "does not have"),
        ("trainer.collector=threads", "trainer.collector must be"),
        ("ppo.value_norm=batch", "ppo.value_norm must be running, popart or null"),
        ("ppo.kl_target=0", "ppo.kl_target must be a positive number or null"),
        ("ppo.clip_value=-1", "ppo.clip_value must be a positive number or null"),
        ("trainer.device=gpu", "trainer.device must be null, cpu, cuda or cuda:<index>, got 'gpu'"),
        ("trainer.device=mps", "trainer.device must be null, cpu, cuda or cuda:<index>, got 'mps'"),
    ],
)
def test_impossible_values_name_the_field(override, message):
    cfg = make_cfg("task=point_reach", "method=hdppo", override)
    with pytest.raises(ConfigError, match=message):
        validate_config(cfg)


@pytest.mark.parametrize(
    "override, expected",
    [
        ("task=not_a_robot", "Could not find 'task/not_a_robot'"),
        ("method=not_a_method", "Could not find 'method/not_a_method'"),
        ("trainer.num_envs=0", "error: trainer.num_envs must be a positive integer, got 0"),
        ("device=cuda", "error: device was renamed: use trainer.device (null = the simulation's device)"),
        pytest.param(
            "trainer.device=cuda",  # point_reach is a CPU backend; the learner would go to the GPU
            "error: trainer.device=cuda but torch sees no CUDA device (torch.cuda.is_available() is False)",
            marks=pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA device"),
        ),
    ],
)
def test_command_line_errors_are_one_clear_line(tmp_path, override, expected):
    result = subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.train", "task=point_reach", override, f"hydra.run.dir={tmp_path}"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode != 0
    assert expected in result.stderr
    assert "Traceback" not in result.stderr
    if expected.startswith("error: "):  # ours: one line says it all
        error_lines = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
        assert len(error_lines) == 1 and expected in error_lines[0]


FIXED_FOUR = '''import torch


def four_components(mean_returns, var_returns, history, previous_weights):
    """Four Fixed

    Assumes a task with four components.

    math: s = [1, 2, 3, 4]
    """
    return torch.tensor([1.0, 2.0, 3.0, 4.0])
'''

HOSTILE = '''import os


def leak(mean_returns, var_returns, history, previous_weights):
    """Leak

    Reads the environment.

    math: none
    """
    return os.environ
'''


@pytest.mark.parametrize(
    "source, expected",
    [
        (FIXED_FOUR, "sandbox refused.*shape"),
        (HOSTILE, "sandbox refused"),
        ("def broken(:\n", "scheduler setup failed"),
    ],
)
def test_rule_files_that_cannot_serve_the_task_fail_at_start(tmp_path, source, expected):
    rules = tmp_path / "rules.py"
    rules.write_text(source)
    cfg = make_cfg("task=point_reach", "method=hdppo", f"scheduler.rules={rules}", "trainer.total_frames=1024", *FAST)
    with pytest.raises(ConfigError, match=re.compile(expected, re.S)):
        train(cfg, tmp_path / "run")


def test_unknown_logger_backend_is_named():
    cfg = make_cfg("task=point_reach", "logger.backends=[csv,carrier_pigeon]")
    with pytest.raises(ConfigError, match="carrier_pigeon"):
        validate_config(cfg)


@pytest.mark.slow
@pytest.mark.parametrize("collector", ["multi", "async"])
def test_multi_process_collectors_train_and_log(tmp_path, collector):
    cfg = make_cfg(
        "task=point_reach",
        "task.max_episode_steps=20",
        "method=hdppo",
        f"trainer.collector={collector}",
        "trainer.workers=2",
        "trainer.total_frames=4096",
        "scheduler.interval=2",
        *FAST,
    )
    metrics = train(cfg, tmp_path)
    assert metrics["episodes"] > 0 and "return/distance" in metrics
    weights = read_scalar(tmp_path, "weight/distance")
    assert len(weights) == 4096 // (32 * 32 if collector == "multi" else 16 * 32)


def test_asymmetric_critic_reads_the_privileged_state(tmp_path):
    cfg = make_cfg(
        "task=go1_terrain",
        "task.critic_observation=privileged_state",
        "method=hdppo",
        "trainer.num_envs=4",
        "trainer.frames_per_batch=64",
        "trainer.total_frames=128",
        "trainer.mini_batch_size=32",
        "trainer.progress_bar=false",
        "model.hidden_sizes=[16]",
    )
    train(cfg, tmp_path)
    checkpoint = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    critic_norm_means = [value for key, value in checkpoint["critic"].items() if key.endswith("mean")]
    first_actor_layer = next(value for key, value in checkpoint["actor"].items() if key.endswith("weight"))
    assert critic_norm_means[0].shape == (123,)  # MuJoCo Playground's privileged state
    assert first_actor_layer.shape[-1] == 48  # the policy still sees only the proprioceptive state
    assert critic_norm_means[0].abs().sum() > 0  # its statistics were updated too


def test_unknown_critic_observation_is_named(tmp_path):
    cfg = make_cfg("task=point_reach", "+task.critic_observation=x_ray", "trainer.total_frames=1024", *FAST)
    with pytest.raises(ConfigError, match="x_ray"):
        train(cfg, tmp_path)


def test_value_norm_scale_needs_a_value_normaliser():
    cfg = make_cfg("task=point_reach", "method=hdppo", "ppo.component_scale=value_norm", "ppo.value_norm=null")
    with pytest.raises(ConfigError, match="ppo.component_scale=value_norm divides .* set ppo.value_norm=running"):
        validate_config(cfg)
