"""``model.precision``: the hidden layers in bfloat16 follow the float32 network within bfloat16's rounding, with
float32 parameters, gradients and outputs; float32 is the plain network, bit for bit."""

import pytest
import torch
from conftest import make_cfg

from torchrl_ahrs.app.shared.config import validate_config
from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.train.build import build_networks, env_factory
from torchrl_ahrs.training.models import AutocastMLP, compute_dtype, native_bfloat16, set_compute_dtype
from torchrl_ahrs.value import MultiHeadCritic, make_mlp

BFLOAT16_STEP = 2.0**-8  # bfloat16 keeps 8 significant bits: a relative rounding step of 2^-8


def test_a_float32_mlp_is_the_plain_sequential_bit_for_bit():
    torch.manual_seed(0)
    plain = make_mlp(6, [32, 16], 3, "elu")
    mlp = AutocastMLP(*plain)
    x = torch.randn(50, 6)
    assert torch.equal(mlp(x), plain(x))
    assert list(mlp.state_dict()) == list(plain.state_dict())  # checkpoints load into either


def test_bfloat16_hidden_layers_follow_float32_within_rounding_and_train_float32_parameters():
    torch.manual_seed(0)
    mlp = AutocastMLP(*make_mlp(12, [64, 64], 4, "elu"))
    x = torch.randn(256, 12)
    exact = mlp(x)
    exact_grads = torch.autograd.grad(exact.square().sum(), list(mlp.parameters()))
    dtypes = {}
    for index, layer in enumerate(mlp):
        layer.register_forward_hook(lambda module, inputs, output, index=index: dtypes.update({index: output.dtype}))
    mlp.compute_dtype = torch.bfloat16
    approximate = mlp(x)
    assert [dtypes[index] for index in range(len(mlp))] == [torch.bfloat16] * (len(mlp) - 1) + [torch.float32]
    assert approximate.dtype == torch.float32
    # a few roundings of 2^-8 each, relative to the output's scale, not float32's 2^-24
    error = (approximate - exact).abs().max() / exact.abs().max()
    assert 0 < error < 8 * BFLOAT16_STEP
    grads = torch.autograd.grad(approximate.square().sum(), list(mlp.parameters()))
    for grad, exact_grad, parameter in zip(grads, exact_grads, mlp.parameters(), strict=True):
        assert grad.dtype == parameter.dtype == torch.float32
        cosine = torch.nn.functional.cosine_similarity(grad.flatten(), exact_grad.flatten(), dim=0)
        assert cosine > 0.999


def test_set_compute_dtype_reaches_every_mlp_of_a_critic_with_separate_heads_and_an_anchor():
    critic = MultiHeadCritic(8, 3, [16, 16], "elu", separate_heads=True, anchor_head=True)
    x = torch.randn(20, 8)
    exact = critic(x)
    parameters = list(critic.parameters())
    set_compute_dtype(critic, torch.bfloat16)
    assert all(a is b for a, b in zip(critic.parameters(), parameters, strict=True))  # the optimiser's, untouched
    mlps = [module for module in critic.modules() if isinstance(module, AutocastMLP)]
    assert len(mlps) == 2 and all(mlp.compute_dtype == torch.bfloat16 for mlp in mlps)
    approximate = critic(x)
    assert approximate.dtype == torch.float32 and approximate.shape == exact.shape == (20, 4)
    assert 0 < (approximate - exact).abs().max() < 8 * BFLOAT16_STEP * exact.abs().max()
    set_compute_dtype(critic, None)
    assert torch.equal(critic(x), exact)  # back to float32: the same numbers as before


def test_auto_is_bfloat16_exactly_where_the_cpu_computes_it_in_hardware():
    assert compute_dtype("auto") == (torch.bfloat16 if native_bfloat16() else None)
    assert compute_dtype("bfloat16") == torch.bfloat16
    assert compute_dtype("float32") is None


@pytest.mark.parametrize("precision, expected", [("bfloat16", torch.bfloat16), ("float32", None)])
def test_the_run_builds_actor_and_both_critics_in_the_configured_precision(precision, expected):
    cfg = make_cfg("task=point_reach", "method=ahrs", "ppo.mix=anchored", f"model.precision={precision}")
    networks = build_networks(cfg, env_factory(cfg))
    mlps = [
        module
        for net in (networks.actor, networks.critic)
        for module in net.modules()
        if isinstance(module, AutocastMLP)
    ]
    assert len(mlps) == 3  # the actor's mean, the K-head critic, the anchor; not the Sequentials around them
    assert networks.actor_dtype == networks.critic_dtype == expected
    assert all(mlp.compute_dtype == expected for mlp in mlps)


@pytest.mark.parametrize("actor, critic", [("float32", "bfloat16"), ("bfloat16", "float32")])
def test_actor_and_critic_precisions_override_model_precision_each_for_its_own_network(actor, critic):
    cfg = make_cfg(
        "task=point_reach",
        "method=ahrs",
        "ppo.mix=anchored",
        "model.precision=auto",
        f"model.actor_precision={actor}",
        f"model.critic_precision={critic}",
    )
    validate_config(cfg)
    networks = build_networks(cfg, env_factory(cfg))
    expected = {"float32": None, "bfloat16": torch.bfloat16}
    assert (networks.actor_dtype, networks.critic_dtype) == (expected[actor], expected[critic])
    actor_mlps = [m.compute_dtype for m in networks.actor.modules() if isinstance(m, AutocastMLP)]
    critic_mlps = [m.compute_dtype for m in networks.critic.modules() if isinstance(m, AutocastMLP)]
    assert actor_mlps == [expected[actor]] and critic_mlps == [expected[critic]] * 2  # K heads and the anchor


def test_an_unknown_precision_is_one_clear_line():
    with pytest.raises(ConfigError, match=r"^model.precision must be one of float32, bfloat16, auto, got 'half'$"):
        validate_config(make_cfg("task=point_reach", "model.precision=half"))
    with pytest.raises(
        ConfigError, match=r"^model.critic_precision must be one of float32, bfloat16, auto or null, got 'fp16'$"
    ):
        validate_config(make_cfg("task=point_reach", "model.critic_precision=fp16"))
