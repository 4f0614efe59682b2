"""HybridClipPPOLoss: the KL it writes and the critic loss's reduction, against torch.distributions and a hand-computed mean."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch.distributions import Independent, Normal, kl_divergence

from torchrl_ahrs.training.loss import HybridClipPPOLoss, gaussian_kl
from torchrl_ahrs.training.models import RunningNorm, build_actor, build_critic


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
