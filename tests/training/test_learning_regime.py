"""The pieces of the PPO regime: the adaptive-KL learning rate, minibatches, GAE's bootstrap on truncated
episodes and the Cassie preset's PPO numbers. (The loss: ``test_loss.py``; value normalisation:
``test_value_norm.py``.)

Oracles: hand-made one-step episodes whose advantages are known in closed form (the bootstrap), legged_gym's
published numbers (the preset).
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule

from torchrl_ahrs.envs.common.mirror import MirrorAugmentation, SignedPermutation
from torchrl_ahrs.training.loop import adaptive_kl_lr, epoch_minibatches
from torchrl_ahrs.training.run import LoopSettings
from torchrl_ahrs.value import WeightedMultiGAE


@pytest.mark.parametrize(
    "kl, expected_lr",
    [(0.0, 1.5e-3), (0.01, 1e-3), (1.0, 1e-3 / 1.5)],  # below target / 2, in the band, above 2 x target
)
def test_adaptive_kl_rule(kl, expected_lr):
    assert adaptive_kl_lr(1e-3, kl, target=0.01) == pytest.approx(expected_lr)


def test_adaptive_kl_respects_bounds_and_needs_a_positive_target():
    assert adaptive_kl_lr(9e-3, 0.0, target=0.01) == pytest.approx(1e-2)
    assert adaptive_kl_lr(1.2e-5, 1.0, target=0.01) == pytest.approx(1e-5)  # bounded by min_lr
    with pytest.raises(ValueError, match="KL target must be positive"):
        LoopSettings(total_frames=64, kl_target=0.0)


def test_each_epoch_serves_every_transition_once_in_a_fresh_order():
    batch = TensorDict({"a": torch.arange(10.0)}, [10])
    generator = torch.Generator().manual_seed(0)
    epochs = [torch.cat([mb["a"] for mb in epoch_minibatches(batch, 3, generator)]).tolist() for _ in range(2)]
    assert [len(mb) for mb in epoch_minibatches(batch, 3, generator)] == [2, 4, 4]  # torch.chunk's sizes, last first
    assert all(sorted(order) == list(range(10)) for order in epochs) and epochs[0] != epochs[1]


def test_mirrored_minibatches_are_each_minibatch_then_its_image_bit_for_bit():
    """Oracle: the mirror applied to each minibatch after the gather, as the loop did before it mirrored the
    epoch once; uneven minibatches (10 rows in 3) included."""
    flip = SignedPermutation((1, 0, 2), (1.0, 1.0, -1.0))
    augment = MirrorAugmentation.for_policy(observation=flip, action=flip)
    batch = TensorDict(
        {"observation": torch.randn(2, 5, 3), "action": torch.randn(2, 5, 3), "advantage": torch.randn(2, 5, 1)},
        [2, 5],
    )
    folded = epoch_minibatches(batch, 3, torch.Generator().manual_seed(4), augment)
    each = [augment(mb) for mb in epoch_minibatches(batch, 3, torch.Generator().manual_seed(4))]
    assert [len(mb) for mb in folded] == [4, 8, 8]
    for got, expected in zip(folded, each, strict=True):
        assert all(torch.equal(got[key], expected[key]) for key in ("observation", "action", "advantage"))


def test_gae_bootstraps_on_truncation_but_not_on_termination():
    # one step per env, V = 10 everywhere, reward 1: A = r + gamma V(s') (1 - terminated) - V(s)
    critic = TensorDictModule(
        lambda obs: torch.full((*obs.shape[:-1], 1), 10.0), in_keys=["observation"], out_keys=["state_value"]
    )
    gae = WeightedMultiGAE(["total"], gamma=0.9, lmbda=0.95, value_network=critic)
    ones = torch.ones(2, 1, 1, dtype=torch.bool)
    batch = TensorDict(
        {
            "observation": torch.zeros(2, 1, 3),
            "next": {
                "observation": torch.zeros(2, 1, 3),
                "reward": {"total": torch.ones(2, 1, 1)},
                "done": ones,
                "truncated": torch.tensor([[[True]], [[False]]]),
                "terminated": torch.tensor([[[False]], [[True]]]),
            },
        },
        [2, 1],
    )
    advantage = gae(batch)["advantage"].reshape(-1).tolist()
    assert advantage == pytest.approx([1.0 + 0.9 * 10.0 - 10.0, 1.0 - 10.0])


def test_cassie_preset_carries_legged_gyms_ppo_numbers():
    """The oracle is the preset's cited source, legged_gym's ``CassieRoughCfgPPO`` (with ``LeggedRobotCfgPPO``):
    a config edit once dropped the network and the value normalisation without any test noticing."""
    from conftest import make_cfg

    cfg = make_cfg("task=cassie", "method=ahrs")
    assert cfg.trainer.frames_per_batch == 64 * 24  # our first preset's 64 envs x num_steps_per_env, kept per batch
    assert cfg.trainer.num_epochs == 5  # num_learning_epochs
    assert cfg.trainer.frames_per_batch // cfg.trainer.mini_batch_size == 4  # num_mini_batches
    assert (cfg.trainer.lr, cfg.trainer.anneal_lr) == (1e-3, False)  # adaptive schedule's starting rate
    assert (cfg.ppo.entropy_coeff, cfg.ppo.critic_coeff, cfg.ppo.clip_value) == (0.01, 1.0, 0.2)
    assert (cfg.ppo.gamma, cfg.ppo.lmbda, cfg.trainer.max_grad_norm) == (0.99, 0.95, 1.0)
    assert list(cfg.model.hidden_sizes) == [512, 256, 128] and cfg.model.activation == "elu"
    assert cfg.ppo.value_norm == "running"  # ours: one normalised head per component (K = 10 heads)


def test_cassie_preset_carries_the_measured_2p5m_settings():
    """The settings benchmarks/RESULTS.md measured for Cassie at 2.5M frames ("Cassie in fewer frames"), which the
    preset's comments cite; a config edit that loses one changes the main command's result."""
    from conftest import make_cfg

    cfg = make_cfg("task=cassie", "method=ahrs")
    assert (cfg.trainer.total_frames, cfg.trainer.num_envs, cfg.trainer.frames_per_batch) == (2_500_000, 128, 1536)
    assert (cfg.ppo.kl_target, cfg.ppo.kl_adapts, cfg.ppo.mirror, cfg.ppo.mix) == (0.04, "actor", True, "anchored")
    assert cfg.aux.path is None and cfg.aux.scale == 0.5  # the shipped progress term at half scale
    assert cfg.trainer.task_overrides.commands.resampling_time_s == 5.0  # in training only (round 39)
    assert cfg.task.commands.resampling_time_s == 10.0  # evaluate scores the task as defined
    assert cfg.trainer.torch_threads == 2  # the run alone on 2 cores (session 34)
    assert cfg.trainer.collection_threads == 1  # one of them while the physics steps on its own (session 38)
    assert cfg.model.precision == "auto"  # bfloat16 where the hardware has it (session 35)
