"""Per-head value normalisation: running statistics against numpy, and the denormalised critic in reward units."""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule

from torchrl_ahrs.training.value_norm import denormalized_critic, make_value_norm


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
