"""A sweep rerun in place skips finished jobs (by checkpoint or by the committed ``finished.json``) and the
report reads a finished run without its checkpoint (as committed results have none)."""

import subprocess
import sys

import pytest

from torchrl_ahrs.app.train.runs import load_sweep

SWEEP = [sys.executable, "-m", "torchrl_ahrs.sweep", "task=quadcopter", "method=ppo,mcppo", "seed=0",
         "trainer.total_frames=8192", "trainer.num_envs=16", "trainer.frames_per_batch=512",
         "trainer.mini_batch_size=128", "trainer.progress_bar=false", "logger.backends=[csv]"]  # fmt: skip


@pytest.mark.slow
def test_a_rerun_sweep_skips_finished_runs_and_the_report_needs_no_checkpoint(tmp_path):
    args = [*SWEEP, f"hydra.sweep.dir={tmp_path}", "hydra.sweep.subdir=${method.name}/seed_${seed}"]
    subprocess.run(args, check=True, capture_output=True, text=True, timeout=300)
    runs = {run.method: run for run in load_sweep(tmp_path)}
    assert {m: r.status for m, r in runs.items()} == {"ppo": "ok", "mcppo": "ok"}
    rows = (tmp_path / "ppo/seed_0/metrics/scalars/return/total.csv").read_text()
    for name in ("ppo", "mcppo"):
        assert (tmp_path / name / "seed_0" / "finished.json").is_file()
    (tmp_path / "mcppo/seed_0/checkpoint.pt").unlink()  # committed results carry no checkpoint
    again = subprocess.run(args, check=True, capture_output=True, text=True, timeout=300)
    assert again.stdout.count("is finished (8192 of 8192 frames), nothing to do") == 2, again.stdout[-2000:]
    assert (tmp_path / "ppo/seed_0/metrics/scalars/return/total.csv").read_text() == rows
    assert {run.method: run.status for run in load_sweep(tmp_path)} == {"ppo": "ok", "mcppo": "ok"}
