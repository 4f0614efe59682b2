"""EnvPool / dm_control tasks with reward components: each is stepped and checked against its native reward.

Oracle: the environment's own reward (EnvPool's ``reward``), never a re-typed formula.
"""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("envpool")

from torchrl_ahrs.envs.registry import load_task_config, make_env  # noqa: E402


def _rollout(task: str, steps: int = 60, num_envs: int = 4):
    cfg = load_task_config(task)
    env = make_env(cfg, num_envs=num_envs, seed=0)
    torch.manual_seed(0)
    rollout = env.rollout(steps, break_when_any_done=False)
    reward = rollout["next", "reward"]
    parts = torch.stack([reward[c] for c in cfg.components], dim=-1).sum(-1)  # [N, T, 1]
    return cfg, rollout, reward, parts


@pytest.mark.parametrize("task", ["humanoid", "leap_cube"])
def test_info_term_components_sum_to_native_reward(task):
    cfg, rollout, reward, parts = _rollout(task)
    assert (parts - reward["total"]).abs().max().item() < 1e-4
    assert rollout["observation"].dtype == torch.float32
    live = [c for c in cfg.components if reward[c].abs().max() > 0]
    assert len(live) >= 3, f"most components of {task} should carry signal, live: {live}"


def test_go1_terrain_components_sum_to_unclipped_native_reward():
    cfg, rollout, reward, parts = _rollout("go1_terrain", steps=80)
    assert len(cfg.components) == 16
    # the env clips the scaled sum to [0, 1e4]; the components sum to the value before the clip
    torch.testing.assert_close(parts.clamp(0.0, 1e4), reward["total"], atol=1e-5, rtol=0)
    assert (parts < 0).any(), "random actions should give some negative unclipped sums"
    assert rollout["observation"].shape[-1] == 48
    assert rollout["privileged_state"].shape[-1] == 123
