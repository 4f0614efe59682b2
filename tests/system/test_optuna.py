"""``hydra/sweeper=optuna`` (docs/optuna.md): each trial is a training run whose return is the objective."""

import subprocess
import sys

import pytest
import yaml

pytest.importorskip("hydra_plugins.hydra_optuna_sweeper", reason="the optuna extra is not installed")


@pytest.mark.slow
def test_optuna_sweeper_maximises_the_runs_return(tmp_path):
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "torchrl_ahrs.train",
            "--multirun",
            "hydra/sweeper=optuna",
            "hydra.sweeper.direction=maximize",
            "hydra.sweeper.n_trials=2",
            "hydra.sweeper.n_jobs=1",
            "hydra.sweeper.sampler.seed=0",
            "trainer.lr=tag(log,interval(0.0001,0.003))",
            "task=point_reach",
            "method=ppo",
            "trainer.total_frames=1024",
            "trainer.num_envs=8",
            "trainer.frames_per_batch=1024",
            "trainer.mini_batch_size=512",
            "trainer.num_epochs=1",
            "trainer.progress_bar=false",
            "logger.backends=[csv]",
            f"hydra.sweep.dir={tmp_path}",
        ],  # fmt: skip
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    result = yaml.safe_load((tmp_path / "optimization_results.yaml").read_text())
    assert 1e-4 <= result["best_params"]["trainer.lr"] <= 3e-3
    # the objective is the best trial's own last logged return/total
    trial_returns = []
    for trial in ("0", "1"):
        rows = (tmp_path / trial / "metrics/scalars/return/total.csv").read_text().splitlines()
        trial_returns.append(float(rows[-1].split(",")[1]))
    assert result["best_value"] == pytest.approx(max(trial_returns))
