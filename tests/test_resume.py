"""A run killed with SIGKILL mid-training resumes exactly: counters, metrics rows and rule history."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import torch

from torchrl_ahrs.app.checkpoint import CHECKPOINT_FILE

FRAMES_PER_BATCH = 16 * 32
ITERATIONS = 14
ARGS = [
    "task=point_reach",
    "task.max_episode_steps=20",
    "method=hdppo",
    f"trainer.total_frames={ITERATIONS * FRAMES_PER_BATCH}",
    "trainer.num_envs=16",
    "trainer.frames_per_batch=512",
    "trainer.mini_batch_size=128",
    "trainer.num_epochs=2",
    "trainer.progress_bar=false",
    "model.hidden_sizes=[32]",
    "scheduler.interval=2",
    "checkpoint.interval=3",
]


def checkpoint_iteration(run_dir):
    try:
        return torch.load(run_dir / CHECKPOINT_FILE, weights_only=False)["checkpoint"]["iteration"]
    except (FileNotFoundError, EOFError, RuntimeError):
        return 0


def csv_steps(path):
    return [int(line.split(",")[0]) for line in path.read_text().splitlines()]


@pytest.mark.slow
def test_sigkill_then_resume_continues_exactly(tmp_path):
    run_dir = tmp_path / "run"
    first = subprocess.Popen(
        [sys.executable, "-m", "torchrl_ahrs.train", *ARGS, f"hydra.run.dir={run_dir}"],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 600
    while checkpoint_iteration(run_dir) < 6 and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    assert first.poll() is None, "the run ended before it could be killed"
    os.kill(first.pid, signal.SIGKILL)
    first.wait()
    killed_at = torch.load(run_dir / CHECKPOINT_FILE, weights_only=False)
    assert 6 <= killed_at["checkpoint"]["iteration"] < ITERATIONS

    resumed = subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.train", f"resume={run_dir}", f"hydra.run.dir={tmp_path / 'resume'}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    final = torch.load(run_dir / CHECKPOINT_FILE, weights_only=False)
    assert final["state"]["collected_frames"] == ITERATIONS * FRAMES_PER_BATCH
    assert final["checkpoint"]["iteration"] == ITERATIONS
    assert final["rule_scheduler"]["iteration"] == ITERATIONS
    assert final["rule_scheduler"]["decision_index"] >= killed_at["rule_scheduler"]["decision_index"]

    # every iteration logged its weights exactly once, in order, before and after the kill
    expected_steps = [FRAMES_PER_BATCH * (i + 1) for i in range(ITERATIONS)]
    for name in ("distance", "arrival", "ctrl"):
        assert csv_steps(run_dir / "metrics" / "scalars" / "weight" / f"{name}.csv") == expected_steps
    returns = csv_steps(run_dir / "metrics" / "scalars" / "return" / "total.csv")
    assert returns == sorted(set(returns))

    # the rule history: one decision every 2 iterations, no duplicate and none missing
    decisions = [json.loads(line) for line in (run_dir / "scheduler_decisions.jsonl").read_text().splitlines()]
    assert [decision["iteration"] for decision in decisions] == list(range(2, ITERATIONS + 1, 2))
