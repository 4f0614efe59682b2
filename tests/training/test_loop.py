"""The training loop's bookkeeping on a real run (point_reach, MuJoCo): one owner per piece of state and per
logged name, value-target statistics that absorb each batch once, and a clear refusal to resume a checkpoint
of the layout before the loop."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from conftest import make_cfg

from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.app.train.iteration import train
from torchrl_ahrs.app.train.runs import read_scalar

FRAMES, ITERATIONS, EPOCHS = 64, 3, 3
COMPONENTS = ["distance", "arrival", "ctrl"]


TINY = [
    "task=point_reach",
    "task.max_episode_steps=6",
    "method=hdppo",
    "trainer.num_envs=8",
    f"trainer.frames_per_batch={FRAMES}",
    "trainer.mini_batch_size=32",
    f"trainer.num_epochs={EPOCHS}",
    f"trainer.total_frames={ITERATIONS * FRAMES}",
    "trainer.progress_bar=false",
    "model.hidden_sizes=[16]",
    "scheduler.interval=1",
    "logger.backends=[csv]",
]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    run = RunDirectory(tmp_path_factory.mktemp("run"))
    train(make_cfg(*TINY), run.path)
    return run


def tensor_paths(state, path="checkpoint"):
    """Every (path, tensor) in a nested checkpoint."""
    if isinstance(state, torch.Tensor):
        yield path, state
    elif isinstance(state, dict):
        for key, value in state.items():
            yield from tensor_paths(value, f"{path}/{key}")
    elif isinstance(state, list | tuple):
        for index, value in enumerate(state):
            yield from tensor_paths(value, f"{path}[{index}]")


def test_the_actor_is_checkpointed_once(run):
    checkpoint = torch.load(run.checkpoint, weights_only=False)
    first_layer = next(value for key, value in checkpoint["actor"].items() if key.endswith("weight"))
    holders = [path for path, tensor in tensor_paths(checkpoint) if tensor.shape == first_layer.shape]
    holders = [path for path in holders if torch.equal(dict(tensor_paths(checkpoint))[path], first_layer)]
    assert len(holders) == 1 and holders[0].startswith("checkpoint/actor/"), holders


def test_weights_are_logged_once_under_one_name(run):
    names = sorted(path.relative_to(run.scalars).with_suffix("").as_posix() for path in run.scalars.rglob("*.csv"))
    assert [name for name in names if "weight" in name] == [f"weight/{c}" for c in sorted(COMPONENTS)]
    steps = read_scalar(run.scalar("weight/distance"))[0].astype(int).tolist()
    assert steps == [FRAMES * (i + 1) for i in range(ITERATIONS)]


def test_value_target_statistics_absorb_each_batch_once_whatever_the_epochs(run):
    counts = torch.load(run.checkpoint, weights_only=False)["estimator"]["value_norm.count"]
    assert counts.flatten().tolist() == [float(ITERATIONS * FRAMES)] * counts.numel()  # not EPOCHS times as many


def test_a_checkpoint_of_the_trainer_layout_is_refused_and_the_run_left_alone(run, tmp_path):
    old = RunDirectory(tmp_path)
    train(make_cfg(*TINY, f"trainer.total_frames={2 * ITERATIONS * FRAMES}"), old.path)
    checkpoint = torch.load(old.checkpoint, weights_only=False)
    checkpoint["state"]["collected_frames"] = FRAMES  # as if interrupted, so the resume does not return at once
    checkpoint["loss_module"] = {"actor_network": checkpoint.pop("actor"), "critic_network": checkpoint.pop("critic")}
    torch.save(checkpoint, old.checkpoint)
    (old.path / "finished.json").unlink()
    rows = old.scalar("weight/distance").read_text()
    with pytest.raises(ConfigError, match="no actor, critic entries: it was written by an older version"):
        train(make_cfg(*TINY, f"resume={old.path}"), old.path)
    assert old.scalar("weight/distance").read_text() == rows  # nothing truncated before the refusal


@pytest.mark.parametrize("distribution", ["tanh_normal", "normal"])
def test_a_policy_that_does_not_move_sees_ratio_one_on_every_batch_it_collected(tmp_path, distribution):
    """With lr 1e-12 (Adam moves each weight by ~1e-12; 0 is refused as a typo) the policy the loss scores is the
    one that collected, batch after batch (the observation statistics move between batches): every ratio is 1 and
    nothing is clipped. A mismatch between the log-probabilities stored at collection and those the loss recomputes
    (e.g. the squashed action's inverse, or statistics updated before the update) would show as ratios away from 1,
    and as a KL the adaptive rule could not lower."""
    run = RunDirectory(tmp_path)
    train(
        make_cfg(*TINY, "trainer.lr=1e-12", "trainer.anneal_lr=false", f"model.distribution={distribution}"), run.path
    )
    _, max_ratio = read_scalar(run.scalar("train/max_ratio"))
    _, clip_fraction = read_scalar(run.scalar("train/clip_fraction"))
    assert len(max_ratio) == ITERATIONS
    assert max_ratio.tolist() == pytest.approx([1.0] * ITERATIONS, abs=1e-4)
    assert clip_fraction.tolist() == [0.0] * ITERATIONS


@pytest.mark.parametrize("entropy_coeff", [0.0, 0.01])
def test_the_noise_std_is_logged_whatever_the_entropy_coefficient(tmp_path, entropy_coeff):
    """Oracle: analytic. The first batch is collected by the initial policy, whose σ is exp(init_log_std) in every
    action dimension; later batches follow the update. With entropy_coeff=0 TorchRL's loss computes no entropy, so
    this is the run's only record of its exploration noise."""
    run = RunDirectory(tmp_path)
    train(make_cfg(*TINY, f"ppo.entropy_coeff={entropy_coeff}", "model.init_log_std=-1.0"), run.path)
    _, noise_std = read_scalar(run.scalar("train/noise_std"))
    assert len(noise_std) == ITERATIONS
    assert noise_std[0] == pytest.approx(math.exp(-1.0), rel=1e-6)
    assert noise_std[-1] != pytest.approx(math.exp(-1.0), rel=1e-6)  # the update moved σ
    assert (tmp_path / "metrics" / "scalars" / "train" / "entropy.csv").exists() == (entropy_coeff > 0)


def test_the_total_explained_variance_is_that_of_the_summed_heads_on_the_collected_batch(tmp_path, monkeypatch):
    from torchrl_ahrs.value import WeightedMultiGAE

    calls: list[tuple[np.ndarray, np.ndarray]] = []  # every estimate's (value_target, state_value) [N, T, K]
    forward = WeightedMultiGAE.forward

    def recorded(self, tensordict, **kwargs):
        out = forward(self, tensordict, **kwargs)
        calls.append((out.get("value_target").numpy().copy(), out.get("state_value").numpy().copy()))
        return out

    monkeypatch.setattr(WeightedMultiGAE, "forward", recorded)
    run = RunDirectory(tmp_path / "run")
    train(make_cfg(*TINY), run.path)
    first_estimates = calls[::EPOCHS]  # every_epoch: EPOCHS estimates per batch, the first with the collecting critic
    logged = read_scalar(run.scalar("train/explained_variance_total"))[1]
    assert len(first_estimates) == ITERATIONS == len(logged)
    for (targets, values), value in zip(first_estimates, logged, strict=True):
        total = targets.sum(-1).ravel()  # the three heads' λ-returns summed, by hand in NumPy
        expected = 1.0 - np.var(total - values.sum(-1).ravel(), ddof=1) / np.var(total, ddof=1)
        assert value == pytest.approx(expected, rel=1e-4, abs=1e-5)
    assert not np.allclose(logged, read_scalar(run.scalar("train/explained_variance"))[1])  # not TorchRL's pooled one
