"""The policy's initial noise is the configured one (a doubled exp once made it 3x too large)."""

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded

from torchrl_ahrs.training.models import RunningNorm, build_actor


@pytest.mark.parametrize("init_log_std", [-0.5, 0.0, -1.6])
def test_initial_scale_is_exp_of_init_log_std(init_log_std):
    action_spec = Bounded(-torch.ones(8), torch.ones(8), shape=(8,))
    actor = build_actor(RunningNorm(5), 5, action_spec, [16], "tanh", init_log_std)
    out = actor(TensorDict({"observation": torch.randn(3, 5)}, [3]))
    torch.testing.assert_close(out["scale"], torch.full((3, 8), math.exp(init_log_std)))
