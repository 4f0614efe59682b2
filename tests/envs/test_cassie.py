"""task=cassie: legged_gym reward functions against hand-derived values, the authored model against
Menagerie's Cassie, and the batched env (component sums, partial resets, determinism, Menagerie path)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from torchrl_ahrs.app.shared.settings import load_task_settings
from torchrl_ahrs.envs.common import legged_rewards as lr
from torchrl_ahrs.envs.registry import make_env
from torchrl_ahrs.envs.tasks.cassie import make_cassie
from torchrl_ahrs.envs.tasks.cassie_model import (
    JOINT_NAMES,
    canonical_joint_name,
    default_model_path,
    load_cassie_model,
)
from torchrl_ahrs.evaluation.task_metrics import step_probe

MENAGERIE_SCENE = Path("/work/shared/models/agility_cassie/scene.xml")
needs_menagerie = pytest.mark.skipif(not MENAGERIE_SCENE.exists(), reason="Menagerie's Cassie is not on this machine")


def cassie_cfg(*overrides: str):
    return load_task_settings("cassie", overrides=[f"task.{o}" for o in overrides])


# ----------------------------------------------------------------------------- pure reward functions
def test_tracking_kernels_hand_values():
    # ‖(1, 0) − (0.5, 0.5)‖² = 0.25 + 0.25 = 0.5 → exp(−0.5 / 0.25) = e⁻²
    value = lr.tracking_lin_vel(torch.tensor([[1.0, 0.0]]), torch.tensor([[0.5, 0.5]]), sigma=0.25)
    assert value.item() == pytest.approx(math.exp(-2.0))
    # (0.5 − 0)² / 0.25 = 1 → e⁻¹; a perfect match gives 1
    value = lr.tracking_ang_vel(torch.tensor([0.5, 0.3]), torch.tensor([0.0, 0.3]), sigma=0.25)
    assert value.tolist() == pytest.approx([math.exp(-1.0), 1.0])


def test_penalty_terms_hand_values():
    assert lr.lin_vel_z(torch.tensor([-0.3])).item() == pytest.approx(0.09)
    assert lr.torques(torch.tensor([[3.0, 4.0]])).item() == pytest.approx(25.0)  # 9 + 16
    # (1 − 0)/0.02 = 50, (2 − 0)/0.02 = 100 → 2500 + 10000
    assert lr.dof_acc(torch.tensor([[1.0, 2.0]]), torch.zeros(1, 2), dt=0.02).item() == pytest.approx(12500.0)
    # (0.5 − 0)² + (−0.5 − 0.5)² = 0.25 + 1
    assert lr.action_rate(torch.tensor([[0.5, -0.5]]), torch.tensor([[0.0, 0.5]])).item() == pytest.approx(1.25)


def test_dof_pos_limits_hand_values():
    # range [−1, 1] at 90 % → soft limits [−0.9, 0.9]; range [0, 2] at 90 % → [0.1, 1.9]
    lower, upper = lr.soft_joint_limits(torch.tensor([[-1.0, 1.0], [0.0, 2.0]]), soft_factor=0.9)
    assert lower.tolist() == pytest.approx([-0.9, 0.1]) and upper.tolist() == pytest.approx([0.9, 1.9])
    q = torch.tensor([[0.95, 0.0], [-1.2, 1.0], [0.0, 2.0]])
    # row 0: 0.95 − 0.9 = 0.05 and 0.1 − 0 = 0.1; row 1: −0.9 − (−1.2) = 0.3; row 2: 2.0 − 1.9 = 0.1
    assert lr.dof_pos_limits(q, lower, upper).tolist() == pytest.approx([0.15, 0.3, 0.1])


def test_no_fly_counts_single_support_only():
    contact = torch.tensor([[True, False], [False, True], [True, True], [False, False]])
    assert lr.no_fly(contact).tolist() == [1.0, 1.0, 0.0, 0.0]


def test_feet_air_time_pays_on_touchdown_after_long_swing():
    dt, command = 0.02, torch.tensor([[1.0, 0.0]])
    # left foot: stance, 30 steps in the air, touchdown. The two-step contact filter keeps the first
    # airborne step "in contact", so the timer runs for 29 steps (0.58 s) and the touchdown step adds
    # one more dt: reward = 0.60 − 0.5 = 0.10 at touchdown, 0 elsewhere. The right foot stays down.
    sequence = [True] + [False] * 30 + [True]
    air, last = torch.zeros(1, 2, dtype=torch.float64), torch.zeros(1, 2, dtype=torch.bool)
    rewards = []
    for left in sequence:
        contact = torch.tensor([[left, True]])
        reward, air = lr.feet_air_time(air, contact, last, command, dt)
        last = contact
        rewards.append(reward.item())
    assert rewards[-1] == pytest.approx(0.10)
    assert rewards[:-1] == [0.0] * (len(sequence) - 1)
    assert air.tolist() == [[0.0, 0.0]]


def test_feet_air_time_constructed_state_and_small_command():
    air = torch.tensor([[0.6, 0.3], [0.6, 0.3]])
    contact = torch.tensor([[True, False], [True, False]])
    last = torch.zeros(2, 2, dtype=torch.bool)
    command = torch.tensor([[1.0, 0.0], [0.05, 0.0]])  # second env asks for 0.05 m/s ≤ 0.1: no reward
    reward, new_air = lr.feet_air_time(air, contact, last, command, dt=0.02)
    assert reward.tolist() == pytest.approx([0.62 - 0.5, 0.0])
    torch.testing.assert_close(new_air, torch.tensor([[0.0, 0.32], [0.0, 0.32]]))


def test_scale_terms_multiplies_scale_and_dt():
    scaled = lr.scale_terms(
        {"termination": torch.tensor([1.0]), "no_fly": torch.tensor([1.0])}, lr.CASSIE_REWARD_SCALES, 0.02
    )
    assert scaled["termination"].item() == pytest.approx(-4.0)  # −200 · 0.02
    assert scaled["no_fly"].item() == pytest.approx(0.005)  # 0.25 · 0.02


def test_task_config_scales_are_legged_gym_cassie_and_unknown_terms_fail():
    cfg = cassie_cfg()
    assert dict(cfg.reward_scales) == lr.CASSIE_REWARD_SCALES  # the YAML and the code agree
    assert list(cfg.components) == list(lr.CASSIE_REWARD_SCALES)  # one component per term
    with pytest.raises(ValueError, match="nofly"):
        make_cassie(dataclasses.replace(cfg, reward_scales={"nofly": 1.0}), num_envs=1)


def test_quat_rotate_inverse_matches_mujoco_and_hand_case():
    # a 90° yaw: the world x axis is the body's −y axis
    yaw90 = torch.tensor([[math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]], dtype=torch.float64)
    out = lr.quat_rotate_inverse(yaw90, torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64))
    torch.testing.assert_close(out, torch.tensor([[0.0, -1.0, 0.0]], dtype=torch.float64))
    rng = np.random.default_rng(0)
    quats = rng.normal(size=(5, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    vecs = rng.normal(size=(5, 3))
    expected = np.zeros((5, 3))
    for i in range(5):
        conjugate = quats[i] * np.array([1.0, -1.0, -1.0, -1.0])
        mujoco.mju_rotVecQuat(expected[i], vecs[i], conjugate)
    np.testing.assert_allclose(
        lr.quat_rotate_inverse(torch.from_numpy(quats), torch.from_numpy(vecs)), expected, atol=1e-12
    )
    level = torch.tensor([[1.0, 0.0, 0.0, 0.0]])
    assert lr.projected_gravity(level).tolist() == [[0.0, 0.0, -1.0]]


# ----------------------------------------------------------------------------- the authored model
def _mass_and_leg_length(model: mujoco.MjModel, hip: str, toe: str) -> tuple[float, float]:
    """Total mass and hip-roll-axis to toe-axis distance at the model's ``home`` keyframe."""
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_forward(model, data)
    leg = np.linalg.norm(data.xanchor[model.joint(hip).id] - data.xanchor[model.joint(toe).id])
    return float(model.body_mass.sum()), float(leg)


@needs_menagerie
def test_own_model_mass_and_leg_length_match_menagerie():
    own = _mass_and_leg_length(mujoco.MjModel.from_xml_path(str(default_model_path())), "l_hip_roll", "l_toe")
    ref = _mass_and_leg_length(mujoco.MjModel.from_xml_path(str(MENAGERIE_SCENE)), "left-hip-roll", "left-foot")
    assert own[0] == pytest.approx(ref[0], rel=0.15)
    assert own[1] == pytest.approx(ref[1], rel=0.15)


def test_own_model_stands_on_the_floor_at_home():
    model = mujoco.MjModel.from_xml_path(str(default_model_path()))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_forward(model, data)
    for side in "lr":
        g = model.geom(f"{side}_foot_capsule").id
        bottom = data.geom_xpos[g, 2] - model.geom_size[g, 0]  # the foot capsule lies flat
        assert abs(bottom) < 0.005
    robot = [g for g in range(model.ngeom) if model.geom_bodyid[g] != 0]  # everything but the floor
    primitives = {
        int(t) for t in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_BOX)
    }
    assert all(model.geom_type[g] in primitives for g in robot)


def test_joint_names_of_both_models_map_to_the_ten_actuated_joints():
    assert canonical_joint_name("left-hip-roll") == "l_hip_roll"
    assert canonical_joint_name("right-foot") == "r_toe"  # Menagerie names the toe joint "foot"
    assert canonical_joint_name("left-foot-crank") != "l_toe"
    model, layout = load_cassie_model()
    assert [model.joint(model.actuator_trnid[a, 0]).name for a in layout.actuator_ids] == list(JOINT_NAMES)


# ----------------------------------------------------------------------------- the env
def test_specs_and_components_sum_to_total():
    cfg = cassie_cfg()
    env = make_env(cfg, num_envs=4, seed=0)
    check_env_specs(env)
    rollout = env.rollout(60, break_when_any_done=False)
    reward = rollout["next", "reward"]
    assert rollout["observation"].shape == (4, 60, 42)
    torch.testing.assert_close(sum(reward[c] for c in cfg.components), reward["total"], atol=1e-5, rtol=0)
    for c in cfg.components:
        assert torch.isfinite(reward[c]).all()


def test_action_sets_pd_target_around_home_pose():
    env = make_cassie(cassie_cfg("init_base_vel_noise=0.0", "init_joint_noise=0.0"), num_envs=2, seed=0).base_env
    action = torch.tensor([[1.0] * 10, [-0.5] * 10])
    ctrl = env.apply_action(action)
    _, layout = load_cassie_model()
    home = layout.default_joint_pos  # l/r: 0, 0, 0.49, −1.06, −0.62 in assets/cassie.xml's keyframe
    np.testing.assert_allclose(home[:5], [0.0, 0.0, 0.49, -1.06, -0.62])
    np.testing.assert_allclose(ctrl[0, layout.actuator_ids], home + 0.5)  # q* = q0 + 0.5 · 1
    np.testing.assert_allclose(ctrl[1, layout.actuator_ids], home - 0.25)  # q* = q0 + 0.5 · (−0.5)


def test_observation_at_rest_hand_values():
    env = make_cassie(cassie_cfg("init_base_vel_noise=0.0", "init_joint_noise=0.0"), num_envs=2, seed=3).base_env
    env.commands[:] = torch.tensor([[0.5, -1.0, 0.8], [0.0, 0.0, 0.0]], dtype=torch.float64)
    obs = env.observation()
    torch.testing.assert_close(obs[:, :6], torch.zeros(2, 6, dtype=torch.float64))  # at rest
    torch.testing.assert_close(obs[:, 6:9], torch.tensor([[0.0, 0.0, -1.0]] * 2, dtype=torch.float64))  # level
    torch.testing.assert_close(obs[0, 9:12], torch.tensor([1.0, -2.0, 0.2], dtype=torch.float64))  # × (2, 2, 0.25)
    torch.testing.assert_close(obs[:, 12:], torch.zeros(2, 30, dtype=torch.float64))  # home pose, still, no action


def test_evaluation_probe_at_rest_hand_values():
    """At rest the tracking errors are the commands' own sizes: ‖(0.6, -0.8)‖ = 1.0 m/s and |0.8| rad/s."""
    env = make_cassie(cassie_cfg("init_base_vel_noise=0.0", "init_joint_noise=0.0"), num_envs=2, seed=3).base_env
    env.commands[:] = torch.tensor([[0.6, -0.8, -0.8], [0.0, 0.0, 0.0]], dtype=torch.float64)
    metrics = step_probe("cassie")(env)
    expected = torch.tensor([1.0, 0.0], dtype=torch.float64)
    torch.testing.assert_close(metrics["command_speed"], expected)
    torch.testing.assert_close(metrics["lin_vel_error"], expected, atol=1e-9, rtol=0)
    torch.testing.assert_close(metrics["command_turn"], torch.tensor([0.8, 0.0], dtype=torch.float64))
    torch.testing.assert_close(metrics["ang_vel_error"], metrics["command_turn"], atol=1e-9, rtol=0)


def test_termination_term_is_minus_four_when_below_height():
    # the pelvis starts at 1.0 m, below a 5 m threshold: terminated at once, term = −200 · 0.02
    env = make_env(cassie_cfg("min_base_height=5.0"), num_envs=3, seed=0)
    td = env.rand_step(env.reset())
    assert td["next", "terminated"].all()
    torch.testing.assert_close(td["next", "reward", "termination"], torch.full((3, 1), -4.0))


def test_torques_term_uses_mujoco_actuator_forces():
    env = make_cassie(cassie_cfg(), num_envs=2, seed=0)
    td = env.rand_step(env.reset())
    forces = np.stack([data.actuator_force for data in env.base_env.datas])  # PD torques of the last substep
    expected = -5e-6 * 0.02 * (forces**2).sum(-1)
    np.testing.assert_allclose(td["next", "reward", "torques"].squeeze(-1).numpy(), expected, rtol=1e-5)


def test_partial_reset_leaves_other_envs_untouched():
    env = make_cassie(cassie_cfg(), num_envs=3, seed=0)
    base = env.base_env
    td = env.reset()
    for _ in range(5):
        _, td = env.step_and_maybe_reset(td.set("action", torch.rand(3, 10) * 2 - 1))
    kept = [d.qpos.copy() for d in base.datas], [d.qvel.copy() for d in base.datas], base.commands.clone()
    td.set("_reset", torch.tensor([[False], [True], [False]]))
    env.reset(td)
    for i in (0, 2):
        np.testing.assert_array_equal(base.datas[i].qpos, kept[0][i])
        np.testing.assert_array_equal(base.datas[i].qvel, kept[1][i])
        torch.testing.assert_close(base.commands[i], kept[2][i])
    assert not np.array_equal(base.datas[1].qpos, kept[0][1])
    assert base.episode_steps.tolist() == [5, 0, 5]


def test_same_seed_same_trajectory():
    cfg = cassie_cfg()
    actions = torch.rand(30, 3, 10, generator=torch.Generator().manual_seed(0)) * 2 - 1

    def run(seed):
        env = make_env(cfg, num_envs=3, seed=seed)
        td, observations = env.reset(), []
        for action in actions:
            _, td = env.step_and_maybe_reset(td.set("action", action))
            observations.append(td["observation"].clone())
        return torch.stack(observations)

    first, second, other = run(1), run(1), run(2)
    assert torch.equal(first, second)
    assert not torch.equal(first, other)


@needs_menagerie
def test_menagerie_model_builds_steps_and_rewards_are_finite():
    cfg = cassie_cfg(f"model_path={MENAGERIE_SCENE}", "physics_dt=0.002", "decimation=10")
    env = make_env(cfg, num_envs=2, seed=0)
    assert env.base_env.model.nv == 32  # Menagerie's closed-loop legs, not the 18-DoF authored model
    rollout = env.rollout(25, break_when_any_done=False)
    assert rollout["observation"].shape == (2, 25, 42)
    assert torch.isfinite(rollout["observation"]).all()
    for c in [*cfg.components, "total"]:
        assert torch.isfinite(rollout["next", "reward", c]).all()
