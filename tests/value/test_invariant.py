"""The invariant every hybrid-reward method rests on: GAE is linear, so with equal weights on raw component
advantages the mixed advantage is PPO's on the summed reward with the summed value heads. The oracle is
TorchRL's own GAE on the environment's native reward; the estimator is built from the shipped config, so the
test fails when the default mix stops being PPO (e.g. ``ppo.component_scale`` back to ``standardize``)."""

import pytest
import torch
from conftest import make_cfg
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.objectives.value import GAE

from torchrl_ahrs.app.shared.settings import scheduler_settings
from torchrl_ahrs.app.train.build import build_estimator_and_loss, build_networks, env_factory
from torchrl_ahrs.scheduling import build_scheduler


def _mixed_and_oracle(*overrides: str, steps: int = 48, num_envs: int = 4):
    cfg = make_cfg("task=quadcopter", *overrides)
    make_envs = env_factory(cfg, check_aux=False)
    torch.manual_seed(0)
    networks = build_networks(cfg, make_envs)
    estimator, _ = build_estimator_and_loss(cfg, networks, make_envs.components)
    build_scheduler(
        scheduler_settings(cfg), estimator, make_envs.components
    )  # installs the method's initial (equal) weights
    env = make_envs(num_envs, 0)
    try:
        with torch.no_grad():
            rollout = env.rollout(steps, networks.actor, break_when_any_done=False, auto_reset=True)  # [N, T]
    finally:
        env.close()
    networks.actor_norm.update(rollout["observation"].reshape(-1, rollout["observation"].shape[-1]))
    if estimator.value_norm is not None:  # non-trivial statistics: per-head mean and scale differ
        heads = len(estimator.columns)  # K, or K + 1 with the anchored mix's column
        estimator.value_norm.update(torch.randn(256, heads) * torch.arange(1.0, 1 + heads) + 3.0)
    mixed = estimator(rollout.clone())["advantage"]  # [N, T, 1] = sum_k w_k A_k
    summed_values = TensorDictSequential(
        estimator.value_network,
        TensorDictModule(lambda v: v.sum(-1, keepdim=True), in_keys=["state_value"], out_keys=["state_value"]),
    )  # V = sum_k V_k
    oracle = GAE(gamma=cfg.ppo.gamma, lmbda=cfg.ppo.lmbda, value_network=summed_values)
    oracle.set_keys(reward=("reward", "total"))  # the native reward (the components add up to it)
    ppo_advantage = oracle(rollout.clone())["advantage"]  # [N, T, 1]
    return cfg, estimator, mixed, ppo_advantage


@pytest.mark.parametrize("method", ["mcppo", "hdppo", "ahrs_wo_a"])  # methods whose components sum to the native reward
def test_equal_weights_on_the_default_mix_are_ppo_on_the_summed_reward(method):
    cfg, estimator, mixed, ppo_advantage = _mixed_and_oracle(f"method={method}")
    weights = estimator.weights
    assert torch.allclose(weights, weights[0].expand_as(weights)), "every method starts from equal weights"
    assert weights[0].item() == cfg.scheduler.base_weight
    torch.testing.assert_close(mixed, weights[0] * ppo_advantage, rtol=1e-4, atol=1e-5)


def test_the_invariant_fails_when_components_are_standardised():
    _, estimator, mixed, ppo_advantage = _mixed_and_oracle("method=mcppo", "ppo.component_scale=standardize")
    assert not torch.allclose(mixed, estimator.weights[0] * ppo_advantage, rtol=1e-2, atol=1e-3)


def test_ppo_is_the_one_head_case_of_the_same_estimator():
    _, estimator, mixed, ppo_advantage = _mixed_and_oracle("method=ppo")
    assert estimator.components == ["total"]
    torch.testing.assert_close(mixed, estimator.weights[0] * ppo_advantage, rtol=1e-4, atol=1e-5)


def test_the_anchored_mix_over_one_component_is_ppo_without_a_second_critic():
    """A preset may set ``ppo.mix=anchored`` for every method of a task; PPO's one head is its own anchor."""
    cfg, estimator, mixed, ppo_advantage = _mixed_and_oracle("method=ppo", "ppo.mix=anchored")
    assert estimator.columns == ["total"] and cfg.ppo.mix == "anchored"
    torch.testing.assert_close(mixed, estimator.weights[0] * ppo_advantage, rtol=1e-4, atol=1e-5)


def column_values(estimator, column: int) -> TensorDictSequential:
    """The estimator's value network (in reward units) reduced to one of its columns, ``[*B, 1]``."""
    pick = TensorDictModule(lambda v: v[..., [column]], in_keys=["state_value"], out_keys=["state_value"])
    return TensorDictSequential(estimator.value_network, pick)


@pytest.mark.parametrize(
    ("method", "heads"),
    [("mcppo", []), ("ahrs_wo_a", []), ("mcppo", ["model.component_hidden_sizes=[8]"])],  # narrower K heads too
)
def test_equal_weights_on_the_anchored_mix_are_ppo_with_the_anchors_own_critic(method, heads):
    """Oracle: TorchRL's GAE on the native reward with the anchor's value alone; the K heads play no part."""
    cfg, estimator, mixed, _ = _mixed_and_oracle(f"method={method}", "ppo.mix=anchored", *heads)
    assert estimator.columns == [*estimator.components, "anchor"]
    rollout = _anchored_rollout(cfg)
    oracle = GAE(gamma=cfg.ppo.gamma, lmbda=cfg.ppo.lmbda, value_network=column_values(estimator, -1))
    oracle.set_keys(reward=("reward", "total"))
    mixed = estimator(rollout.clone())["advantage"]
    torch.testing.assert_close(mixed, estimator.weights[0] * oracle(rollout.clone())["advantage"], rtol=1e-4, atol=1e-5)


def test_unequal_weights_on_the_anchored_mix_add_each_components_deviation_to_the_anchor():
    """Oracle: w̄ GAE(r_total, V_Σ) + Σ_k (w_k - w̄) GAE(r_k, V_k), each term TorchRL's GAE on one column."""
    cfg, estimator, _, _ = _mixed_and_oracle("method=mcppo", "ppo.mix=anchored")
    weights = torch.linspace(0.5, 1.5, len(estimator.components))
    estimator.set_weights(weights)
    rollout = _anchored_rollout(cfg)
    mixed = estimator(rollout.clone())["advantage"]

    def column_gae(reward_key, column):
        oracle = GAE(gamma=cfg.ppo.gamma, lmbda=cfg.ppo.lmbda, value_network=column_values(estimator, column))
        oracle.set_keys(reward=reward_key)
        return oracle(rollout.clone())["advantage"]  # [N, T, 1]

    expected = weights.mean() * column_gae(("reward", "total"), -1)  # w̄ A_Σ
    for k, name in enumerate(estimator.components):
        expected = expected + (weights[k] - weights.mean()) * column_gae(("reward", name), k)  # (w_k - w̄) A_k
    torch.testing.assert_close(mixed, expected, rtol=1e-4, atol=1e-5)
    # and it is not the unanchored mix with these critics: the anchor is a network of its own
    unanchored = (weights * estimator(rollout.clone())["advantage_components"][..., :-1]).sum(-1, keepdim=True)
    assert not torch.allclose(mixed, unanchored, rtol=1e-2, atol=1e-3)


def _anchored_rollout(cfg, steps: int = 48, num_envs: int = 4):
    """A rollout of the task with a fresh policy (the critic's values need only be some fixed function)."""
    make_envs = env_factory(cfg, check_aux=False)
    torch.manual_seed(1)
    networks = build_networks(cfg, make_envs, with_critic=False)
    env = make_envs(num_envs, 0)
    try:
        with torch.no_grad():
            return env.rollout(steps, networks.actor, break_when_any_done=False, auto_reset=True)  # [N, T]
    finally:
        env.close()
