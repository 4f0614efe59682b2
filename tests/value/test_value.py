"""WeightedMultiGAE against TorchRL's own GAE run per component; critic and mixing checks."""

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.objectives.value import GAE

from torchrl_ahrs.value import MultiHeadCritic, WeightedMultiGAE, mix_advantages
from torchrl_ahrs.value.gae import GEMM_ROW_BLOCK

B, T, K, OBS = 6, 40, 5, 3
NAMES = [f"c{k}" for k in range(K)]


def make_batch(seed=0, done_rate=0.08):
    gen = torch.Generator().manual_seed(seed)
    done = torch.rand(B, T, 1, generator=gen) < done_rate
    terminated = done & (torch.rand(B, T, 1, generator=gen) < 0.5)  # some ends are time limits
    rewards = {name: torch.randn(B, T, 1, generator=gen) * (k + 1) for k, name in enumerate(NAMES)}
    return TensorDict(
        {
            "observation": torch.randn(B, T, OBS, generator=gen),
            "next": {
                "observation": torch.randn(B, T, OBS, generator=gen),
                "reward": rewards,
                "done": done,
                "terminated": terminated,
            },
        },
        [B, T],
    )


def make_critic(heads=K, separate=False):
    torch.manual_seed(1)
    net = MultiHeadCritic(OBS, heads, hidden_sizes=[16], separate_heads=separate)
    return TensorDictModule(net, in_keys=["observation"], out_keys=["state_value"])


@pytest.mark.parametrize("separate", [False, True])
def test_each_component_equals_torchrl_gae_on_that_component_alone(separate):
    critic = make_critic(separate=separate)
    batch = make_batch()
    out = WeightedMultiGAE(NAMES, gamma=0.97, lmbda=0.9, value_network=critic)(batch.clone())
    for k, name in enumerate(NAMES):
        head_k = TensorDictModule(lambda obs, k=k: critic.module(obs)[..., k : k + 1], ["observation"], ["state_value"])
        oracle = GAE(gamma=0.97, lmbda=0.9, value_network=head_k)
        oracle.set_keys(reward=("reward", name))
        expected = oracle(batch.clone())
        assert (expected["advantage"][..., 0] - out["advantage_components"][..., k]).abs().max() <= 1e-5
        assert (expected["value_target"][..., 0] - out["value_target"][..., k]).abs().max() <= 1e-5


def test_mixed_advantage_is_the_weighted_sum_of_component_advantages():
    weights = torch.tensor([0.5, 1.0, 1.5, 0.0, 2.0])
    out = WeightedMultiGAE(NAMES, gamma=0.99, lmbda=0.95, value_network=make_critic(), weights=weights)(make_batch())
    components = out["advantage_components"]
    expected = sum(weights[k] * components[..., k : k + 1] for k in range(K))
    assert out["advantage"].shape == (B, T, 1)
    torch.testing.assert_close(out["advantage"], expected)


def test_component_normalisation_makes_each_column_standard_before_mixing():
    # with one-hot weights the mixed advantage is exactly that component, standardised
    weights = torch.zeros(K)
    weights[4] = 1.0
    estimator = WeightedMultiGAE(
        NAMES, gamma=0.99, lmbda=0.95, value_network=make_critic(), weights=weights, component_scale="standardize"
    )
    mixed = estimator(make_batch())["advantage"]
    assert mixed.mean().abs() < 1e-5
    assert (mixed.std() - 1).abs() < 1e-3


def test_weights_are_replaceable_and_validated():
    estimator = WeightedMultiGAE(NAMES, gamma=0.99, lmbda=0.95, value_network=make_critic())
    before = estimator(make_batch())["advantage"]
    estimator.set_weights([2.0] * K)
    after = estimator(make_batch())["advantage"]
    torch.testing.assert_close(after, 2 * before)
    assert "weights" in estimator.state_dict()
    with pytest.raises(ValueError, match="shape"):
        estimator.set_weights([1.0, 2.0])
    with pytest.raises(ValueError, match="finite"):
        estimator.set_weights([float("nan")] * K)


def test_critic_with_wrong_number_of_heads_fails_loudly():
    estimator = WeightedMultiGAE(NAMES, gamma=0.99, lmbda=0.95, value_network=make_critic(heads=1))
    with pytest.raises(ValueError, match="5 GAE columns .* build the critic with one head per column"):
        estimator(make_batch())


def test_mismatched_component_shapes_are_refused():
    batch = make_batch()
    batch["next", "reward", "c0"] = torch.zeros(B, T, 2)
    with pytest.raises(ValueError, match="different shapes"):
        WeightedMultiGAE(NAMES, gamma=0.99, lmbda=0.95, value_network=make_critic())(batch)


def test_mix_refuses_wrong_weight_shape():
    with pytest.raises(ValueError, match=r"shape \[K\]"):
        mix_advantages(torch.zeros(3, 2), torch.ones(3))


def test_separate_heads_are_independent():
    critic = MultiHeadCritic(OBS, 3, [8], separate_heads=True)
    obs = torch.randn(4, OBS, requires_grad=True)
    critic(obs)[:, 1].sum().backward()
    grads = critic.net[0].weight.grad  # [K, in, out]
    assert grads[1].abs().sum() > 0
    assert grads[0].abs().sum() == 0 and grads[2].abs().sum() == 0


def test_keys_are_configurable():
    batch = make_batch().rename_key_(("next", "reward"), ("next", "parts"))
    estimator = WeightedMultiGAE(NAMES, gamma=0.99, lmbda=0.95, value_network=make_critic())
    estimator.set_keys(reward="parts", advantage="adv", advantage_components="adv_k")
    assert ("next", "parts", "c0") in estimator.in_keys and "reward" not in str(estimator.in_keys)
    assert estimator.out_keys == ["adv", "adv_k", "value_target"]
    out = estimator(batch)
    assert out["adv"].shape == (B, T, 1) and out["adv_k"].shape == (B, T, K)


def test_reward_key_names_the_input_tree_and_the_total_is_left_alone():
    batch = make_batch()
    total = torch.randn(B, T, 1)
    batch["next", "reward", "total"] = total.clone()
    estimator = WeightedMultiGAE(NAMES, gamma=0.99, lmbda=0.95, value_network=make_critic())
    out = estimator(batch)
    torch.testing.assert_close(out["next", "reward", "total"], total)  # never overwritten by a [.., K] stack
    assert set(out["next", "reward"].keys()) == {*NAMES, "total"}
    estimator.set_keys(reward=("reward", "total"))  # TorchRL's env.reward_key: a leaf, not the tree
    with pytest.raises(KeyError, match=r"names the tree's root"):
        estimator(make_batch())


def test_forward_has_its_own_docstring():
    assert "Σ_k w_k A_k" in WeightedMultiGAE.forward.__doc__


@pytest.mark.parametrize("head_sizes", [[16, 16], [4]])  # the K heads as wide as PPO's critic, or narrower
def test_the_anchor_head_is_a_network_of_its_own_that_starts_as_ppos_critic(head_sizes):
    torch.manual_seed(3)
    ppo_critic = MultiHeadCritic(OBS, 1, [16, 16])
    torch.manual_seed(3)
    anchored = MultiHeadCritic(OBS, K, head_sizes, anchor_head=True, anchor_hidden_sizes=[16, 16])
    assert anchored.anchor is not None
    assert [layer.out_features for layer in anchored.net if isinstance(layer, torch.nn.Linear)] == [*head_sizes, K]
    pairs = zip(ppo_critic.net.state_dict().values(), anchored.anchor.state_dict().values(), strict=True)
    for ppo_tensor, anchor_tensor in pairs:
        assert torch.equal(ppo_tensor, anchor_tensor)  # the same draws: an anchored method begins where PPO does
    observation = torch.randn(7, OBS)
    values = anchored(observation)
    assert values.shape == (7, K + 1)
    torch.testing.assert_close(values[:, -1:], ppo_critic(observation))
    values[:, -1].sum().backward()  # the anchor's value reads none of the K heads' parameters
    assert all(param.grad is None or not param.grad.any() for param in anchored.net.parameters())


def test_the_anchored_mix_refuses_a_component_named_like_its_column_and_a_critic_without_the_anchor():
    critic = TensorDictModule(torch.nn.Linear(OBS, K), in_keys=["observation"], out_keys=["state_value"])
    with pytest.raises(ValueError, match="names its extra column 'anchor'"):
        WeightedMultiGAE(["anchor", "b"], gamma=0.9, lmbda=0.9, value_network=critic, anchored=True)
    gae = WeightedMultiGAE(NAMES, gamma=0.9, lmbda=0.9, value_network=critic, anchored=True)  # K values, not K + 1
    with pytest.raises(ValueError, match=r"returned 5 value\(s\) per state but there are 6 GAE columns.*anchor_head"):
        gae(make_batch())


def make_chained_batch(seed=0, end_rate=0.08):
    """A batch laid out as a collector delivers it: the next state of step t is the state of step t + 1
    unless the episode ended at t, where the next state is the final one and step t + 1 starts afresh."""
    batch = make_batch(seed, end_rate)
    ended = batch["next", "done"][..., 0]
    states = batch["observation"].clone()
    next_states = batch["next", "observation"]
    for t in range(T - 1):
        went_on = ~ended[:, t]
        states[went_on, t + 1] = next_states[went_on, t]
    batch["observation"] = states
    assert ended[:, :-1].any() and not torch.equal(states[:, 1:], next_states[:, :-1]), "needs ends inside the window"
    return batch


def count_rows(critic):
    """Rows the critic's network is called on, counted by a forward hook."""
    rows = []
    critic.module.register_forward_hook(lambda module, args, out: rows.append(args[0].reshape(-1, OBS).shape[0]))
    return rows


def test_a_chained_batch_evaluates_each_state_once_with_torchrls_values_bit_for_bit():
    critic = make_critic()
    batch = make_chained_batch()
    rows = count_rows(critic)
    out = WeightedMultiGAE(NAMES, gamma=0.97, lmbda=0.9, value_network=critic)(batch.clone())
    ended = batch["next", "done"][..., 0]
    apart = int(ended[:, :-1].sum()) + B  # the next states no step t + 1 gives: episode ends and each row's last
    padding = -(B * T + apart) % GEMM_ROW_BLOCK  # whole blocks of the matrix kernels' rows
    assert rows == [B * T + apart + padding] and sum(rows) < 2 * B * T
    for k, name in enumerate(NAMES):  # TorchRL's GAE on head k, with its own pass over both halves of the batch
        head_k = TensorDictModule(lambda obs, k=k: critic.module(obs)[..., k : k + 1], ["observation"], ["state_value"])
        oracle = GAE(gamma=0.97, lmbda=0.9, value_network=head_k)
        oracle.set_keys(reward=("reward", name))
        expected = oracle(batch.clone())
        assert torch.equal(out["state_value"][..., k : k + 1], expected["state_value"])
        assert torch.equal(out["next", "state_value"][..., k : k + 1], expected["next", "state_value"])
        torch.testing.assert_close(out["advantage_components"][..., k : k + 1], expected["advantage"])


def test_a_batch_that_does_not_chain_gets_each_next_state_evaluated():
    critic = make_critic()
    batch = make_batch()  # next states unrelated to the following states: V(s_{t+1}) must not stand in for V(s'_t)
    out = WeightedMultiGAE(NAMES, gamma=0.97, lmbda=0.9, value_network=critic)(batch.clone())
    with torch.no_grad():
        torch.testing.assert_close(out["next", "state_value"], critic.module(batch["next", "observation"]))
        assert not torch.allclose(out["next", "state_value"][:, :-1], critic.module(batch["observation"])[:, 1:])
