"""The policy: its initial noise is the configured one (a doubled exp once made it 3x too large), and an
unsquashed Gaussian reaches the environment clipped while the rollout keeps the sample."""

import math

import pytest
import torch
from conftest import make_cfg
from tensordict import TensorDict
from torchrl.data import Bounded
from torchrl.envs import ExplorationType, set_exploration_type

from torchrl_ahrs.app.shared.config import validate_config
from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.train.build import build_networks, env_factory
from torchrl_ahrs.training.models import RunningNorm, build_actor


@pytest.mark.parametrize("distribution", ["tanh_normal", "normal"])
@pytest.mark.parametrize("init_log_std", [-0.5, 0.0, -1.6])
def test_initial_scale_is_exp_of_init_log_std(init_log_std, distribution):
    action_spec = Bounded(-torch.ones(8), torch.ones(8), shape=(8,))
    actor = build_actor(RunningNorm(5), 5, action_spec, [16], "tanh", init_log_std, distribution=distribution)
    out = actor(TensorDict({"observation": torch.randn(3, 5)}, [3]))
    torch.testing.assert_close(out["scale"], torch.full((3, 8), math.exp(init_log_std)))


def test_unsquashed_policy_is_clipped_into_the_env_and_kept_in_the_rollout():
    """Oracle: EnvPool's Ant-v5 charges ``ctrl = -0.5 * sum(a^2)`` on the action it receives."""
    cfg = make_cfg("task=ant_v5", "method=ppo", "model.distribution=normal", "model.init_log_std=0.5")
    make_envs = env_factory(cfg)
    actor = build_networks(cfg, make_envs, with_critic=False).actor
    env = make_envs(2, 0)
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):  # as the collector samples
        rollout = env.rollout(20, actor)
    action = rollout["action"]
    assert action.abs().max() > 1.0, "sigma = exp(0.5) should sample outside [-1, 1]"
    expected_ctrl = -0.5 * action.clamp(-1.0, 1.0).pow(2).sum(-1, keepdim=True)  # what the env must have applied
    torch.testing.assert_close(rollout["next", "reward", "ctrl"], expected_ctrl)
    with torch.no_grad():
        sample_log_prob = actor.get_dist(rollout).log_prob(action)  # the rollout's log-prob is the sample's
    torch.testing.assert_close(rollout["action_log_prob"], sample_log_prob)


def test_unknown_distribution_is_one_clear_line():
    with pytest.raises(ConfigError, match="model.distribution must be one of tanh_normal, normal"):
        validate_config(make_cfg("task=point_reach", "model.distribution=beta"))
