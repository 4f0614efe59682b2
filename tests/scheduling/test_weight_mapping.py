"""Weight mappings, component scaling and effective shares against hand-computed oracles."""

import math

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from torchrl_ahrs.app.shared.settings import schedule_settings, scheduler_settings
from torchrl_ahrs.scheduling import RuleScheduler, load_repository
from torchrl_ahrs.scheduling.mapping import WeightMapping
from torchrl_ahrs.scheduling.selectors import FixedSelector
from torchrl_ahrs.value.functional import effective_shares


def test_minshift_sum_ratio_is_bounded_and_shrinks_with_k():
    mapping = WeightMapping("minshift_sum", 0.5)
    for k, expected_ratio in [(3, (0.5 + 2 / 3) / 0.5), (8, (0.5 + 7 / 28) / 0.5)]:
        weights = mapping(torch.arange(k, dtype=torch.float32))  # shares (k_i) / sum k_i
        assert weights.min().item() == pytest.approx(0.5)
        assert (weights.max() / weights.min()).item() == pytest.approx(expected_ratio, rel=1e-5)


def test_softmax_hand_values_scale_free_and_sharper_with_lower_temperature():
    scores = torch.tensor([0.0, 1.0])  # z = [-1, 1]
    for tau in (1.0, 0.25):
        p = 1 / (1 + math.exp(2 / tau))  # softmax([-1, 1] / tau)[0]
        expected = [0.5 + 2 * p, 0.5 + 2 * (1 - p)]
        assert WeightMapping("softmax", 0.5, temperature=tau)(scores).tolist() == pytest.approx(expected, rel=1e-5)
        # neither the scale nor the offset of the scores matters
        shifted = WeightMapping("softmax", 0.5, temperature=tau)(1000.0 * scores - 7.0)
        assert shifted.tolist() == pytest.approx(expected, rel=1e-5)
    sharp = WeightMapping("softmax", 0.5, temperature=0.25)(torch.arange(11.0))
    assert (sharp.max() / sharp.min()).item() > 10  # unlike minshift_sum at K = 11 (ratio 1.36)


def test_paper_mapping_adds_the_base_and_clamps():
    mapping = WeightMapping("plain_sum", 0.5, clamp_min=0.0, clamp_max=2.0)
    assert mapping(torch.tensor([-3.0, 0.25, 1.0, 40.0])).tolist() == [0.0, 0.75, 1.5, 2.0]
    assert mapping.direct(torch.tensor([1.0, 3.0])).tolist() == [1.0, 2.0]  # 0.5 + 2 * [1/4, 3/4]


def test_bad_mapping_settings_are_one_line_errors():
    with pytest.raises(ValueError, match="unknown weight mapping 'linear'"):
        WeightMapping("linear")
    with pytest.raises(ValueError, match="temperature must be positive"):
        WeightMapping("softmax", temperature=0.0)


def test_scheduler_uses_the_configured_mapping():
    class Estimator:
        weights = torch.ones(2)

        def set_weights(self, w):
            self.weights = w.clone()

    repo = load_repository()
    cfg = OmegaConf.create({"scheduler": {"weight_mapping": "plain_sum", "base_weight": 0.5, "clamp": [0.0, 3.0]}})
    estimator = Estimator()
    scheduler = RuleScheduler(
        estimator,
        ["a", "b"],
        repo,
        FixedSelector(repo, "mean_returns_only"),
        interval=1,
        mapping=schedule_settings(cfg).mapping(),
    )
    scheduler.statistics.add(torch.tensor([[0.25, 9.0]]))
    scheduler.step()
    assert estimator.weights.tolist() == [0.75, 3.0]  # 0.5 + mu, clamped at 3


def test_decision_interval_gives_at_least_the_requested_decisions():
    for frames, per_batch, decisions in [(1_000_000, 2048, 15), (400_000, 4096, 10), (20_000, 2048, 15)]:
        cfg = OmegaConf.create(
            {"trainer": {"total_frames": frames, "frames_per_batch": per_batch},
             "scheduler": {"interval": None, "decisions": decisions}}
        )  # fmt: skip
        iterations = frames // per_batch
        assert iterations // scheduler_settings(cfg).decision_interval() >= min(decisions, iterations)
    fixed = OmegaConf.create({"scheduler": {"interval": 7, "decisions": 15}})
    assert scheduler_settings(fixed).decision_interval() == 7


def test_effective_shares_oracle():
    advantages = torch.tensor([[1.0, 100.0], [-1.0, -100.0], [1.0, 100.0], [-1.0, -100.0]])
    std = advantages.std(0)  # [1.1547, 115.47]
    shares = effective_shares(advantages, torch.tensor([3.0, 0.5]))
    expected = torch.tensor([3.0, 0.5]) * std / (torch.tensor([3.0, 0.5]) * std).sum()
    assert torch.allclose(shares, expected) and shares[1] > 0.9  # the large-scale component dominates raw mixing


def _gae_batch(scale_b: float):
    from tensordict import TensorDict

    torch.manual_seed(0)
    b, t = 8, 16
    return TensorDict(
        {
            "observation": torch.randn(b, t, 3),
            "next": {
                "observation": torch.randn(b, t, 3),
                "reward": {"a": torch.randn(b, t, 1), "b": scale_b * torch.randn(b, t, 1)},
                "done": torch.zeros(b, t, 1, dtype=torch.bool),
                "terminated": torch.zeros(b, t, 1, dtype=torch.bool),
            },
        },
        [b, t],
    )


@pytest.mark.parametrize("scale", ["raw", "standardize", "value_norm"])
def test_weighted_gae_component_scale_and_shares(scale):
    from tensordict.nn import TensorDictModule

    from torchrl_ahrs.training.value_norm import make_value_norm
    from torchrl_ahrs.value import WeightedMultiGAE

    critic = TensorDictModule(lambda obs: torch.zeros(*obs.shape[:-1], 2), ["observation"], ["state_value"])
    value_norm = make_value_norm("running", 2)
    gae = WeightedMultiGAE(
        ["a", "b"], gamma=0.9, lmbda=0.9, value_network=critic, component_scale=scale, value_norm=value_norm
    )
    gae.set_weights(torch.tensor([2.0, 1.0]))
    td = gae(_gae_batch(scale_b=1000.0))
    raw = td["advantage_components"]
    if scale == "raw":
        mixed = raw
    elif scale == "standardize":
        flat = raw.reshape(-1, 2)
        mixed = (raw - flat.mean(0)) / (flat.std(0) + 1e-8)
    else:  # a fresh normaliser: sigma_k = population std of the value target over the batch
        mixed = raw / (td["value_target"].reshape(-1, 2).std(0, unbiased=False) + 1e-8)
    expected = (mixed * torch.tensor([2.0, 1.0])).sum(-1, keepdim=True)
    assert torch.allclose(td["advantage"], expected, rtol=1e-4, atol=1e-4)
    assert torch.allclose(gae.shares, effective_shares(mixed, torch.tensor([2.0, 1.0])), atol=1e-5)
    if scale == "raw":
        assert gae.shares[1] > 0.99  # a 1000x larger reward owns the raw mix whatever the weights
    else:
        assert 0.4 < gae.shares[0] < 0.9  # the weights, not the reward scale, set the shares
    with pytest.raises(ValueError, match="component_scale must be one of"):
        WeightedMultiGAE(["a"], gamma=0.9, lmbda=0.9, value_network=critic, component_scale="minmax")


def test_value_norm_component_scale_reads_the_critics_normaliser():
    """After the normaliser has folded targets in, A_k is divided by its scale (numpy's std of every target seen),
    not by the batch's; without a normaliser the choice is refused."""
    from tensordict.nn import TensorDictModule

    from torchrl_ahrs.training.value_norm import make_value_norm
    from torchrl_ahrs.value import WeightedMultiGAE

    critic = TensorDictModule(lambda obs: torch.zeros(*obs.shape[:-1], 2), ["observation"], ["state_value"])
    value_norm = make_value_norm("running", 2)
    seen = torch.tensor([[0.0, -300.0], [4.0, 500.0], [8.0, 100.0]])
    value_norm.update(seen)
    gae = WeightedMultiGAE(
        ["a", "b"], gamma=0.9, lmbda=0.9, value_network=critic, component_scale="value_norm", value_norm=value_norm
    )
    td = gae(_gae_batch(scale_b=1000.0))
    sigma = torch.from_numpy(np.std(seen.numpy(), axis=0)).float()  # [K] population std of every target seen
    expected = (td["advantage_components"] / (sigma + 1e-8)).sum(-1, keepdim=True)  # weights 1
    assert torch.allclose(td["advantage"], expected, rtol=1e-4, atol=1e-4)
    with pytest.raises(ValueError, match="pass value_norm="):
        WeightedMultiGAE(["a"], gamma=0.9, lmbda=0.9, value_network=critic, component_scale="value_norm")
