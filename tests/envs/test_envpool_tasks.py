"""EnvPool / dm_control tasks with reward components: each is stepped and checked against its native reward.

Oracle: the environment's own reward (EnvPool's ``reward``), never a re-typed formula.
"""

from __future__ import annotations

import math

import pytest
import torch

pytest.importorskip("envpool")

from torchrl_ahrs.app.shared.settings import load_task_settings  # noqa: E402
from torchrl_ahrs.envs.registry import make_env  # noqa: E402


def _rollout(task: str, steps: int = 60, num_envs: int = 4):
    cfg = load_task_settings(task)
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


def test_shadow_hand_terms_against_native_reward():
    cfg, rollout, reward, parts = _rollout("shadow_hand", steps=30)
    # the decomposed sum is the training reward
    torch.testing.assert_close(parts, reward["total"], atol=1e-4, rtol=1e-6)
    # oracle: gymnasium-robotics' native dense reward is -(10 ||p - p*|| + theta_g) with
    # theta_g = 2 acos(w) in [0, 2 pi] (signed w: not the shortest angle); Isaac Gym's theta (ours, via rot)
    # is the shortest one, min(theta_g, 2 pi - theta_g)
    theta = 1.0 / reward["rot"] - cfg.rot_eps
    native = rollout["next", "info", "native_reward"].unsqueeze(-1)
    theta_native = reward["dist"] - native
    shortest = torch.minimum(theta_native, 2 * math.pi - theta_native)
    torch.testing.assert_close(theta, shortest, atol=2e-4, rtol=1e-4)
    assert (theta_native > math.pi).any() and (theta_native < math.pi).any()  # both branches exercised
    assert (reward["action"] < 0).all()
    assert rollout["observation"].shape[-1] == 61 + 7


def test_quat_angle_known_rotations():
    from torchrl_ahrs.envs.tasks.shadow_hand import quat_angle

    identity = torch.tensor([1.0, 0.0, 0.0, 0.0])
    half_turn_z = torch.tensor([0.0, 0.0, 0.0, 1.0])
    quarter_turn_x = torch.tensor([math.cos(math.pi / 8), math.sin(math.pi / 8), 0.0, 0.0])  # 45 degrees
    assert quat_angle(identity, identity).item() == pytest.approx(0.0, abs=1e-6)
    assert quat_angle(identity, half_turn_z).item() == pytest.approx(math.pi, abs=1e-6)
    assert quat_angle(quarter_turn_x, identity).item() == pytest.approx(math.pi / 4, abs=1e-6)
    assert quat_angle(-quarter_turn_x, identity).item() == pytest.approx(math.pi / 4, abs=1e-6)  # q ~ -q


@pytest.mark.parametrize("task, obs_dim", [("dmc_walker_walk", 24), ("dmc_quadruped_run", 78), ("dmc_cheetah_run", 17)])
def test_dmc_components_sum_exactly_to_native_reward(task, obs_dim):
    cfg, rollout, reward, parts = _rollout(task, steps=60)
    torch.testing.assert_close(parts, reward["total"], atol=1e-6, rtol=0)
    assert rollout["observation"].shape[-1] == obs_dim


def test_quadruped_run_terms_are_computed_from_observations_not_the_reward():
    # both terms come from torso_upright / torso_velocity; the product must still reproduce the native
    # reward, and move <= 0 <= upright
    _, _, reward, _ = _rollout("dmc_quadruped_run", steps=60)
    assert (reward["upright"] >= 0).all() and (reward["move"] <= 1e-7).all()
    assert reward["move"].abs().max() > 0


def test_walker_stand_terms_match_dm_control_when_move_factor_is_zero():
    # oracle: dm_control's own reward with the walker's COM velocity forced to -100 m/s, so that its move
    # factor is 0 and r = stand / 6: our observation-based standing + upright must equal r, move ~ 0
    np = pytest.importorskip("numpy")
    suite = pytest.importorskip("dm_control.suite")
    from torchrl_ahrs.envs.tasks.dmc_tasks import walker_walk_terms

    env = suite.load("walker", "walk", task_kwargs={"random": 0})
    env.physics.horizontal_velocity = lambda: -100.0
    env.reset()
    rng = np.random.default_rng(0)
    for _ in range(40):
        step = env.step(rng.uniform(-1, 1, 6))
        obs = step.observation
        terms = walker_walk_terms(
            torch.tensor(obs["height"]), torch.tensor(obs["orientations"][0]), torch.tensor(step.reward)
        )
        assert abs(terms["move"].item()) < 1e-9
    # and in EnvPool's walker, the remainder move = 5 stand move / 6 implies a move factor in [0, 1]
    _, _, reward, _ = _rollout("dmc_walker_walk", steps=60)
    stand = 6.0 * (reward["standing"] + reward["upright"])
    move_factor = reward["move"] / (5.0 * stand / 6.0)
    assert (move_factor > -1e-5).all() and (move_factor < 1 + 1e-5).all()


def test_cheetah_split_at_jog_speed():
    _, _, reward, _ = _rollout("dmc_cheetah_run", steps=60)
    assert (reward["jog"] <= 0.5 + 1e-7).all() and (reward["sprint"] >= 0).all()
    assert ((reward["sprint"] > 0) <= (reward["jog"] >= 0.5 - 1e-7)).all()  # sprint only once jog is full
