"""Resuming is exact: a run interrupted after a checkpoint and resumed equals the uninterrupted run —
every tensor of the checkpoint (networks, optimiser, environments, carried episodes, scheduler, random
generators), every metric row except timing, every scheduler decision — for every method and for
``trainer.anneal_lr`` true and false. A run killed with SIGKILL resumes too (subprocess, as a user runs it)."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import torch
from conftest import differences
from hydra import compose, initialize_config_module

from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.app.train import checkpoint as checkpoint_module
from torchrl_ahrs.app.train.iteration import train
from torchrl_ahrs.app.train.runs import read_scalar

TIMING = {"frames_per_second"}  # metrics that measure the machine, not the run


def make_cfg(*overrides):
    with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def metric_rows(run):
    """{scalar name: its CSV rows} for every scalar except timing ones."""
    return {
        str(path.relative_to(run.scalars)): path.read_text()
        for path in sorted(run.scalars.rglob("*.csv"))
        if path.relative_to(run.scalars).with_suffix("").as_posix() not in TIMING
    }


def decisions(run):
    entries = [json.loads(line) for line in run.decisions.read_text().splitlines()] if run.decisions.is_file() else []
    return [{key: value for key, value in entry.items() if key != "time"} for entry in entries]


class Interrupted(Exception):
    pass


def train_until(cfg, run_dir, iterations, monkeypatch):
    """Trains as ``cfg`` says but stops dead right after the checkpoint of iteration ``iterations``."""
    save = checkpoint_module.CheckpointHook.__call__

    def save_then_stop(hook, *arguments):  # (batch, metrics): what the loop hands every after-iteration callable
        save(hook, *arguments)
        if hook.iteration == iterations:
            raise Interrupted

    with monkeypatch.context() as patch:
        patch.setattr(checkpoint_module.CheckpointHook, "__call__", save_then_stop)
        with pytest.raises(Interrupted):
            train(cfg, run_dir)


def assert_same_run(first, second):
    a = torch.load(first.checkpoint, weights_only=False)
    b = torch.load(second.checkpoint, weights_only=False)
    assert differences(a, b) == []
    assert metric_rows(first) == metric_rows(second)
    assert decisions(first) == decisions(second)


FRAMES = 64  # per iteration: 8 envs x 8 steps
ITERATIONS = 4
TINY = [
    "task=point_reach",
    "task.max_episode_steps=6",  # episodes end and restart across the interruption
    "trainer.num_envs=8",
    f"trainer.frames_per_batch={FRAMES}",
    "trainer.mini_batch_size=32",
    "trainer.num_epochs=2",
    f"trainer.total_frames={ITERATIONS * FRAMES}",
    "trainer.progress_bar=false",
    "model.hidden_sizes=[16]",
    "scheduler.interval=1",
    "checkpoint.interval=1",
    "logger.backends=[csv]",
]
METHODS = [
    "ppo",
    "hdppo",
    "ahrs_wo_a",
    "ahrs",
    "ppo_a",
    "hdppo_a",
    "ahrs_r",
    "ahrs_d",
]  # ahrs_d: the bandit (llm=offline)


@pytest.mark.slow
@pytest.mark.parametrize("anneal_lr", [True, False])
@pytest.mark.parametrize("method", METHODS)
def test_interrupted_and_resumed_run_equals_the_uninterrupted_one(tmp_path, monkeypatch, method, anneal_lr):
    overrides = [*TINY, f"method={method}", f"trainer.anneal_lr={anneal_lr}"]
    whole, cut = RunDirectory(tmp_path / "whole"), RunDirectory(tmp_path / "cut")
    train(make_cfg(*overrides), whole.path)
    train_until(make_cfg(*overrides), cut.path, 2, monkeypatch)
    train(make_cfg(*overrides, f"resume={cut.path}"), cut.path)
    assert torch.load(cut.checkpoint, weights_only=False)["state"]["collected_frames"] == ITERATIONS * FRAMES
    assert_same_run(whole, cut)


@pytest.mark.slow
def test_resume_is_exact_on_a_batched_mujoco_task(tmp_path, monkeypatch):
    # with the presets' regime: per-head value normalisation (its running statistics) and value clipping
    overrides = [*TINY[2:], "task=quadcopter", "method=ahrs_wo_a", "ppo.value_norm=running", "ppo.clip_value=0.2"]
    whole, cut = RunDirectory(tmp_path / "whole"), RunDirectory(tmp_path / "cut")
    train(make_cfg(*overrides), whole.path)
    train_until(make_cfg(*overrides), cut.path, 1, monkeypatch)
    train(make_cfg(*overrides, f"resume={cut.path}"), cut.path)
    assert_same_run(whole, cut)


def test_a_resumed_run_that_had_already_finished_changes_nothing(tmp_path):
    run = RunDirectory(tmp_path)
    overrides = [*TINY, "method=ppo", f"trainer.total_frames={FRAMES}"]
    train(make_cfg(*overrides), run.path)
    before = torch.load(run.checkpoint, weights_only=False)
    train(make_cfg(*overrides, f"resume={run.path}"), run.path)
    assert differences(before, torch.load(run.checkpoint, weights_only=False)) == []


KILL_FRAMES = 16 * 32
KILL_ITERATIONS = 14
KILL_ARGS = [
    "task=point_reach",
    "task.max_episode_steps=20",
    "method=hdppo",
    f"trainer.total_frames={KILL_ITERATIONS * KILL_FRAMES}",
    "trainer.num_envs=16",
    "trainer.frames_per_batch=512",
    "trainer.mini_batch_size=128",
    "trainer.num_epochs=2",
    "trainer.progress_bar=false",
    "model.hidden_sizes=[32]",
    "scheduler.interval=2",
    "checkpoint.interval=3",
]


def checkpoint_iteration(run):
    try:
        return torch.load(run.checkpoint, weights_only=False)["checkpoint"]["iteration"]
    except (FileNotFoundError, EOFError, RuntimeError):
        return 0


def csv_steps(path):
    return read_scalar(path)[0].astype(int).tolist()


@pytest.mark.slow
def test_sigkill_then_resume_continues_exactly(tmp_path):
    run = RunDirectory(tmp_path / "run")
    first = subprocess.Popen(
        [sys.executable, "-m", "torchrl_ahrs.train", *KILL_ARGS, f"hydra.run.dir={run.path}"],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 600
    while checkpoint_iteration(run) < 6 and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    assert first.poll() is None, "the run ended before it could be killed"
    os.kill(first.pid, signal.SIGKILL)
    first.wait()
    killed_at = torch.load(run.checkpoint, weights_only=False)
    assert 6 <= killed_at["checkpoint"]["iteration"] < KILL_ITERATIONS

    resumed = subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.train", f"resume={run.path}", f"hydra.run.dir={tmp_path / 'resume'}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    final = torch.load(run.checkpoint, weights_only=False)
    assert final["state"]["collected_frames"] == KILL_ITERATIONS * KILL_FRAMES
    assert final["checkpoint"]["iteration"] == KILL_ITERATIONS
    assert final["rule_scheduler"]["iteration"] == KILL_ITERATIONS

    # every iteration logged its weights exactly once, in order, before and after the kill
    expected_steps = [KILL_FRAMES * (i + 1) for i in range(KILL_ITERATIONS)]
    for name in ("distance", "arrival", "ctrl"):
        assert csv_steps(run.scalar(f"weight/{name}")) == expected_steps
    returns = csv_steps(run.scalar("return/total"))
    assert returns == sorted(set(returns))
    # the rule history: one decision every 2 iterations, no duplicate and none missing
    assert [decision["iteration"] for decision in decisions(run)] == list(range(2, KILL_ITERATIONS + 1, 2))

    # and the killed-and-resumed run is the uninterrupted one
    whole = RunDirectory(tmp_path / "whole")
    train(make_cfg(*KILL_ARGS), whole.path)
    assert_same_run(whole, run)


@pytest.mark.slow
def test_the_anchored_mix_resumes_exactly_and_logs_the_anchors_share(tmp_path, monkeypatch):
    # the anchor's network, its value-norm column and its share are checkpointed state like the K heads'
    overrides = [*TINY, "method=ahrs_wo_a", "ppo.mix=anchored"]
    whole, cut = RunDirectory(tmp_path / "whole"), RunDirectory(tmp_path / "cut")
    train(make_cfg(*overrides), whole.path)
    train_until(make_cfg(*overrides), cut.path, 2, monkeypatch)
    train(make_cfg(*overrides, f"resume={cut.path}"), cut.path)
    assert_same_run(whole, cut)
    shares = {path.stem: read_scalar(path)[1] for path in (whole.scalars / "share").glob("*.csv")}
    assert "anchor" in shares and len(shares) == 4  # point_reach's three components and the anchor
    assert shares["anchor"][0] == 1.0  # the first update's weights are equal: the anchor alone
    total = sum(values for values in shares.values())
    assert all(abs(value - 1.0) < 1e-5 for value in total)  # every iteration's shares add up to one
