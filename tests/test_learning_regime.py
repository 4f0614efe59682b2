"""The pieces of the PPO regime: per-head value normalisation, adaptive-KL learning rate, minibatches,
and GAE's bootstrap on truncated episodes.

Oracles: ``torch.distributions.kl_divergence`` (the KL), numpy's mean/std (the statistics), hand-made
one-step episodes whose advantages are known in closed form (the bootstrap).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch.distributions import Independent, Normal, kl_divergence

from torchrl_ahrs.training.loop import LoopSettings, adaptive_kl_lr, epoch_minibatches
from torchrl_ahrs.training.loss import HybridClipPPOLoss, gaussian_kl
from torchrl_ahrs.training.models import RunningNorm, build_actor, build_critic
from torchrl_ahrs.training.value_norm import denormalized_critic, make_value_norm
from torchrl_ahrs.value import WeightedMultiGAE


def test_gaussian_kl_matches_torch_distributions():
    g = torch.Generator().manual_seed(0)
    loc0, loc1 = torch.randn(16, 8, generator=g), torch.randn(16, 8, generator=g)
    s0, s1 = torch.rand(16, 8, generator=g) + 0.1, torch.rand(16, 8, generator=g) + 0.1
    expected = kl_divergence(Independent(Normal(loc0, s0), 1), Independent(Normal(loc1, s1), 1))
    assert torch.allclose(gaussian_kl(loc0, s0, loc1, s1), expected, atol=1e-5)


@pytest.mark.parametrize("distribution", ["tanh_normal", "normal"])
def test_loss_writes_the_kl_from_the_collecting_to_the_current_policy(distribution):
    from torchrl.data import Bounded

    torch.manual_seed(0)
    spec = Bounded(-torch.ones(2), torch.ones(2), (2,))
    actor = build_actor(RunningNorm(3), 3, spec, [8], distribution=distribution)
    critic = build_critic(RunningNorm(3), 3, 1, [8])
    with torch.no_grad():
        batch = actor(TensorDict({"observation": torch.randn(32, 3)}, [32]))
    current_loc, current_scale = batch["loc"].clone(), batch["scale"].clone()
    # the collecting policy: mean shifted, spread 1.5x the current one's
    batch["loc"], batch["scale"] = current_loc + 0.3, current_scale * 1.5
    batch["advantage"], batch["value_target"] = torch.randn(32, 1), torch.randn(32, 1)
    assert "kl" not in HybridClipPPOLoss(actor, critic, functional=False)(batch).keys()  # only when asked
    loss = HybridClipPPOLoss(actor, critic, functional=False, kl=True)
    expected = kl_divergence(
        Independent(Normal(batch["loc"], batch["scale"]), 1), Independent(Normal(current_loc, current_scale), 1)
    ).mean()
    losses = loss(batch)
    assert losses["kl"].item() == pytest.approx(expected.item(), rel=1e-5)
    assert not losses["kl"].requires_grad
    assert torch.equal(batch["loc"], current_loc + 0.3)  # the caller's minibatch keeps the collecting policy's


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


def test_value_norm_statistics_per_head_match_numpy():
    rng = np.random.default_rng(0)
    chunks = [rng.normal([0.0, 500.0], [1.0, 200.0], size=(100, 2)) for _ in range(3)]
    norm = make_value_norm("running", 2)
    for chunk in chunks:
        norm.update(torch.tensor(chunk, dtype=torch.float32))
    all_values = np.concatenate(chunks)
    assert np.allclose(norm.mean.numpy(), all_values.mean(0), rtol=1e-4)
    assert np.allclose(norm.scale().numpy() ** 2, all_values.var(0), rtol=1e-3)
    normalized = norm.normalize(torch.tensor(all_values, dtype=torch.float32)).numpy()
    assert np.allclose(normalized.mean(0), 0.0, atol=1e-3) and np.allclose(normalized.std(0), 1.0, atol=1e-3)


def test_denormalized_critic_shares_parameters_and_maps_to_reward_units():
    net = TensorDictModule(torch.nn.Linear(3, 2), in_keys=["observation"], out_keys=["state_value"])
    norm = make_value_norm("running", 2)
    norm.update(torch.tensor([[0.0, 100.0], [10.0, 300.0]]))  # mu = (5, 200), sigma = (5, 100)
    critic = denormalized_critic(net, norm)
    td = TensorDict({"observation": torch.randn(4, 3)}, [4])
    raw = net(td.clone())["state_value"]
    out = critic(td.clone())["state_value"]
    assert torch.allclose(out, raw * torch.tensor([5.0, 100.0]) + torch.tensor([5.0, 200.0]), atol=1e-3)
    assert {id(p) for p in critic.parameters()} == {id(p) for p in net.parameters()}
    assert "module.1.value_norm.mean" in critic.state_dict()  # the statistics travel with the checkpointed critic


def test_each_epoch_serves_every_transition_once_in_a_fresh_order():
    batch = TensorDict({"a": torch.arange(10.0)}, [10])
    generator = torch.Generator().manual_seed(0)
    epochs = [torch.cat([mb["a"] for mb in epoch_minibatches(batch, 3, generator)]).tolist() for _ in range(2)]
    assert [len(mb) for mb in epoch_minibatches(batch, 3, generator)] == [2, 4, 4]  # torch.chunk's sizes, last first
    assert all(sorted(order) == list(range(10)) for order in epochs) and epochs[0] != epochs[1]


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
    frames_per_env = cfg.trainer.frames_per_batch // cfg.trainer.num_envs
    assert frames_per_env == 24  # num_steps_per_env
    assert cfg.trainer.num_epochs == 5  # num_learning_epochs
    assert cfg.trainer.frames_per_batch // cfg.trainer.mini_batch_size == 4  # num_mini_batches
    assert (cfg.trainer.lr, cfg.ppo.kl_target, cfg.trainer.anneal_lr) == (1e-3, 0.01, False)  # adaptive schedule
    assert (cfg.ppo.entropy_coeff, cfg.ppo.critic_coeff, cfg.ppo.clip_value) == (0.01, 1.0, 0.2)
    assert (cfg.ppo.gamma, cfg.ppo.lmbda, cfg.trainer.max_grad_norm) == (0.99, 0.95, 1.0)
    assert list(cfg.model.hidden_sizes) == [512, 256, 128] and cfg.model.activation == "elu"
    assert cfg.ppo.value_norm == "running"  # ours: one normalised head per component (K = 10 heads)


def test_critic_loss_is_the_squared_error_averaged_over_batch_and_heads():
    """Oracle: the elementwise mean of (v - G)^2 over [B, K]; the config documents this reduction."""
    from tensordict.nn import NormalParamExtractor
    from torchrl.modules import ProbabilisticActor, TanhNormal

    from torchrl_ahrs.training.loss import HybridClipPPOLoss

    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(3, 4), NormalParamExtractor())
    actor = ProbabilisticActor(
        TensorDictModule(net, ["observation"], ["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
    )
    critic = TensorDictModule(torch.nn.Linear(3, 2), ["observation"], ["state_value"])
    loss = HybridClipPPOLoss(actor, critic, components=["a", "b"], critic_coeff=1.0, loss_critic_type="l2")
    batch = TensorDict(
        {
            "observation": torch.randn(16, 3),
            "action": torch.rand(16, 2) * 1.8 - 0.9,
            "action_log_prob": torch.zeros(16),
            "advantage": torch.randn(16, 1),
            "value_target": torch.randn(16, 2) * 3,
        },
        [16],
    )
    with torch.no_grad():
        squared_error = (critic(batch.clone())["state_value"] - batch["value_target"]).pow(2)  # [B, K]
    assert loss(batch)["loss_critic"].item() == pytest.approx(squared_error.mean().item(), rel=1e-5)
