"""Batched MuJoCo base and the ant / quadcopter tasks: hand-derived reward oracles, partial resets,
determinism and TorchRL spec checks."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from torchrl_ahrs.app.shared.settings import load_task_settings
from torchrl_ahrs.envs.backends.mujoco_base import BatchedMujocoEnv
from torchrl_ahrs.envs.registry import make_env
from torchrl_ahrs.envs.tasks.ant import AntEnv
from torchrl_ahrs.envs.tasks.quadcopter import QuadcopterEnv

SLIDER_XML = """
<mujoco>
  <option timestep="0.01"/>
  <worldbody>
    <body><joint name="x" type="slide" axis="1 0 0" damping="0"/><geom type="sphere" size="0.1" mass="1"/></body>
  </worldbody>
  <actuator><motor joint="x" gear="2"/></actuator>
</mujoco>
"""


class Slider(BatchedMujocoEnv):
    """A unit mass on a frictionless rail pushed by a motor (force = 2·a); terminates beyond |x| > 1."""

    reward_term_names = ("position", "effort")

    def reset_state(self, env_ids, rng):
        return rng.uniform(-0.1, 0.1, (len(env_ids), 1)), np.zeros((len(env_ids), 1))

    def observation(self):
        return torch.cat([self.qpos, self.qvel], -1)

    def reward_terms(self):
        return {"position": -self.qpos[:, 0].abs(), "effort": -self.action.square().sum(-1)}

    def terminated(self):
        return self.qpos[:, 0].abs() > 1.0


def make_slider(num_envs=4, seed=0, num_threads=2, max_episode_steps=50):
    return Slider(
        mujoco.MjModel.from_xml_string(SLIDER_XML),
        num_envs=num_envs,
        decimation=5,
        max_episode_steps=max_episode_steps,
        num_threads=num_threads,
        seed=seed,
    )


def test_base_specs_pass():
    check_env_specs(make_slider())


def test_base_physics_matches_constant_force():
    # a = 0.5 → force 1 N on 1 kg; semi-implicit Euler with dt=0.01 over 5 substeps from rest:
    # v_5 = 5·0.01·1 = 0.05; x_5 - x_0 = dt²·(1+2+3+4+5) = 0.0015
    env = make_slider(num_envs=3)
    td = env.reset()
    x0 = td["observation"][:, 0].clone()
    out = env.step(td.set("action", torch.full((3, 1), 0.5)))["next"]
    torch.testing.assert_close(out["observation"][:, 1], torch.full((3,), 0.05))
    torch.testing.assert_close(out["observation"][:, 0] - x0, torch.full((3,), 0.0015))
    torch.testing.assert_close(out["info", "reward_effort"], torch.full((3,), -0.25))
    assert env.control_dt == pytest.approx(0.05)


def test_base_partial_reset_leaves_others_untouched():
    env = make_slider(num_envs=4)
    td = env.reset()
    for _ in range(3):
        td = env.step(td.set("action", torch.ones(4, 1)))
        td = td["next"]
    before = env.qpos.clone(), env.qvel.clone()
    reset_mask = torch.tensor([False, True, False, False]).unsqueeze(-1)
    out = env.reset(td.exclude("reward", "done", "terminated", "truncated").set("_reset", reset_mask))
    keep = torch.tensor([0, 2, 3])
    torch.testing.assert_close(env.qpos[keep], before[0][keep])
    torch.testing.assert_close(env.qvel[keep], before[1][keep])
    torch.testing.assert_close(out["observation"][keep, 0], before[0][keep, 0].float())
    assert env.qvel[1].abs().item() == 0.0 and env.qpos[1].abs().item() <= 0.1
    assert env.episode_steps.tolist() == [3, 0, 3, 3]


def test_base_time_limit_truncates_and_autoresets():
    env = make_slider(num_envs=2, max_episode_steps=4)
    rollout = env.rollout(10, break_when_any_done=False)
    truncated = rollout["next", "truncated"].squeeze(-1)
    assert truncated[:, 3].all() and truncated[:, 7].all() and truncated.sum() == 4


def test_base_threads_do_not_change_results():
    actions = torch.rand(6, 8, 1) * 2 - 1
    results = []
    for threads in (1, 2, 3):
        env = make_slider(num_envs=8, seed=3, num_threads=threads)
        td = env.reset()
        for a in actions:
            td = env.step(td.set("action", a))["next"]
        results.append(td["observation"])
    torch.testing.assert_close(results[0], results[1], rtol=0, atol=0)
    torch.testing.assert_close(results[0], results[2], rtol=0, atol=0)


PD_XML = SLIDER_XML.replace('<motor joint="x" gear="2"/>', '<position joint="x" kp="20" kv="2"/>')


class SliderPDHook(Slider):
    """PD torques recomputed before every substep by the hook: u = 20 (target − x) − 2 ẋ (gear 2 → halve)."""

    per_substep_control = True

    def substep_control(self, env_slice, qpos, qvel):
        return (20.0 * (self.ctrl[env_slice] - qpos) - 2.0 * qvel) / 2.0


def test_per_substep_control_matches_mujoco_position_actuator():
    # MuJoCo's <position kp kv> under the Euler integrator applies the same PD force at each substep
    hook = SliderPDHook(mujoco.MjModel.from_xml_string(SLIDER_XML), num_envs=5, decimation=5, num_threads=2, seed=4)
    native = Slider(mujoco.MjModel.from_xml_string(PD_XML), num_envs=5, decimation=5, num_threads=2, seed=4)
    targets = torch.rand(10, 5, 1, generator=torch.Generator().manual_seed(1)) - 0.5
    td_hook, td_native = hook.reset(), native.reset()
    for target in targets:
        td_hook = hook.step(td_hook.set("action", target))["next"]
        td_native = native.step(td_native.set("action", target))["next"]
        torch.testing.assert_close(td_hook["observation"], td_native["observation"], rtol=1e-6, atol=1e-7)
    assert td_hook["observation"][:, 1].abs().max() > 0.01  # it did move


# ---------------------------------------------------------------------------------------------- ant

COS45 = float(np.cos(np.pi / 4))


def set_state(env, qpos_rows, qvel_rows=None):
    """Writes hand-made states into the stacked arrays that the hooks read."""
    env.state["qpos"][:] = np.asarray(qpos_rows)
    env.state["qvel"][:] = 0.0 if qvel_rows is None else np.asarray(qvel_rows)


def ant_qpos(x, z, quat, joints):
    return [x, 0.0, z, *quat, *joints]


def test_ant_reward_terms_match_hand_derived_values():
    env = AntEnv(num_envs=4, num_threads=1)
    mid = [0.0, np.radians(50)] * 4  # hips centred, ankles mid-range: nothing at a limit
    limits = [np.radians(30), np.radians(70)] + [0.0, np.radians(30)] * 3  # fl hip+ankle at upper; others lower
    upright, yaw45 = [1, 0, 0, 0], [np.cos(np.pi / 8), 0, 0, np.sin(np.pi / 8)]  # half-angle quaternion
    tilt60 = [np.cos(np.pi / 6), np.sin(np.pi / 6), 0, 0]  # 60° about x: up_z = cos 60° = 0.5
    start = [ant_qpos(0.0, 0.5, upright, mid)] * 4
    set_state(env, start)
    env.on_reset(np.arange(4))  # potentials at x = 0
    moved = [
        ant_qpos(0.1, 0.5, upright, mid),
        ant_qpos(0.0, 0.5, yaw45, limits),
        ant_qpos(0.0, 0.5, tilt60, mid),
        ant_qpos(0.0, 0.2, upright, mid),  # fallen: below 0.31
    ]
    qvel = np.zeros((4, 14))
    qvel[0, 6:] = 2.0
    set_state(env, moved, qvel)
    env.action = torch.tensor([[1.0] * 8, [0.5] * 8, [0.0] * 8, [1.0] * 8])
    env.after_physics_step()
    terms = {k: v.tolist() for k, v in env.reward_terms().items()}
    dt = 2 * 0.0083333
    expected = {
        # Δ(−‖target − xy‖)/dt for a 0.1 m step straight at the far target
        "progress": [0.1 / dt, 0.0, 0.0, 0.0],
        "alive": [0.5, 0.5, 0.5, 0.0],
        "up": [0.1, 0.1, 0.0, 0.0],
        # facing: 0.5; yaw 45°: 0.5·cos45/0.8; tilt about x keeps the x axis on the target
        "heading": [0.5, 0.5 * COS45 / 0.8, 0.5, 0.0],
        "actions_cost": [-0.005 * 8, -0.005 * 8 * 0.25, 0.0, 0.0],
        "energy": [-0.05 * 8 * 1.0 * 0.2 * 2.0, 0.0, 0.0, 0.0],
        "joints_at_limit": [0.0, -0.2, 0.0, 0.0],  # two joints at their upper limit; lower limits don't count
        "death": [0.0, 0.0, 0.0, -2.0],
    }
    for name, values in expected.items():
        assert terms[name] == pytest.approx(values, abs=1e-4), name
    assert env.terminated().tolist() == [False, False, False, True]


def test_ant_components_sum_to_total_and_death_replaces_it():
    cfg = load_task_settings("ant")
    env = make_env(cfg, num_envs=4, seed=1)
    rollout = env.rollout(150, break_when_any_done=False)
    reward = rollout["next", "reward"]
    total = sum(reward[c] for c in cfg.components)
    torch.testing.assert_close(total, reward["total"], atol=1e-5, rtol=0)
    died = reward["death"] < 0
    assert torch.all(reward["total"][died] == -2.0)
    assert torch.equal(died, rollout["next", "terminated"])


def test_ant_partial_reset_leaves_other_simulations_untouched():
    env = AntEnv(num_envs=3, num_threads=2)
    td = env.reset()
    for _ in range(5):
        _, td = env.step_and_maybe_reset(td.set("action", torch.rand(3, 8) * 2 - 1))
    kept = [d.qpos.copy() for d in env.datas], [d.qvel.copy() for d in env.datas]
    td.set("_reset", torch.tensor([[False], [False], [True]]))
    env.reset(td)
    for i in (0, 1):
        np.testing.assert_array_equal(env.datas[i].qpos, kept[0][i])
        np.testing.assert_array_equal(env.datas[i].qvel, kept[1][i])
    assert not np.array_equal(env.datas[2].qpos, kept[0][2])
    assert env.episode_steps.tolist() == [5, 5, 0]


@pytest.mark.parametrize("task", ["ant", "quadcopter"])
def test_same_seed_same_trajectory(task):
    cfg = load_task_settings(task)
    actions = torch.rand(40, 3, 8 if task == "ant" else 4, generator=torch.Generator().manual_seed(0)) * 2 - 1

    def run(seed):
        env = make_env(cfg, num_envs=3, seed=seed)
        td, observations = env.reset(), []
        for a in actions:
            out, td = env.step_and_maybe_reset(td.set("action", a))
            observations.append(out["next", "observation"])
        return torch.stack(observations)

    first = run(7)
    torch.testing.assert_close(first, run(7), rtol=0, atol=0)
    assert not torch.equal(first, run(8))


@pytest.mark.parametrize("task", ["ant", "quadcopter"])
def test_task_specs_and_reward_leaves(task):
    cfg = load_task_settings(task)
    env = make_env(cfg, num_envs=3)
    check_env_specs(env)
    leaves = env.rollout(3)["next", "reward"]
    assert sorted(leaves.keys()) == sorted([*cfg.components, "total"])


# ---------------------------------------------------------------------------------------------- quadcopter
def test_quadcopter_reward_terms_match_hand_derived_values():
    env = QuadcopterEnv(num_envs=3, num_threads=1)
    roll90 = [COS45, COS45, 0, 0]  # 90° about x: body y → world z, body z → world −y
    qpos = [[0, 0, 1, 1, 0, 0, 0], [0, 0, 2, *roll90], [0.5, 0, 1, 1, 0, 0, 0]]
    qvel = [[0] * 6, [0, 0, 0, 0, 2, 0], [0, 0, 0, 0, 0, 1]]  # angular velocity is in the body frame
    set_state(env, qpos, qvel)
    terms = {k: v.tolist() for k, v in env.reward_terms().items()}
    # env 0: at target, level, still → 1, 1, 1.
    # env 1: d = 1 → pos = 1/2; up_z = 0 → tilt 1 → up = 1/2; body ω_y = 2 → world ω_z = 2 → spin = 1/5.
    # env 2: d = 0.5 → pos = 1/1.25 = 0.8; level → up = 1; ω_z = 1 → spin = 1/2.
    assert terms["pos"] == pytest.approx([1.0, 0.5, 0.8])
    assert terms["pos_up"] == pytest.approx([1.0, 0.25, 0.8])
    assert terms["pos_spin"] == pytest.approx([1.0, 0.1, 0.4])
    set_state(env, [[0, 0, 4.5, 1, 0, 0, 0], [0, 0, 0.25, 1, 0, 0, 0], [2.9, 0, 1, 1, 0, 0, 0]])
    assert env.terminated().tolist() == [True, True, False]  # d = 3.5 > 3; z < 0.3; d = 2.9


def test_quadcopter_hover_thrust_holds_altitude():
    # total mass 0.7 kg and 4 N per rotor at ctrl 1: hover at ctrl = 0.7·9.81/16, i.e. action = 2·ctrl − 1
    env = QuadcopterEnv(num_envs=2, num_threads=1)
    td = env.reset()
    set_state(env, [[0, 0, 1, 1, 0, 0, 0]] * 2)
    for i, data in enumerate(env.datas):
        data.qpos[:], data.qvel[:] = env.state["qpos"][i], 0.0
    hover = 2 * (0.7 * 9.81 / 16) - 1
    for _ in range(50):
        td = env.step(td.set("action", torch.full((2, 4), hover)))["next"]
    assert env.qpos[:, 2].tolist() == pytest.approx([1.0, 1.0], abs=1e-6)
    assert td["info", "reward_pos"].tolist() == pytest.approx([1.0, 1.0], abs=1e-6)


# ---------------------------------------------------------------------------------------------- Ant-v5 parity
def test_ant_v5_on_the_base_matches_gymnasium_step_for_step():
    # differential oracle: gymnasium's own Ant-v5 from the same state under the same actions
    gym = pytest.importorskip("gymnasium")
    from torchrl_ahrs.envs.tasks.ant_v5_mujoco import AntV5Mujoco

    ours = AntV5Mujoco(num_envs=2, num_threads=2, seed=5)
    td = ours.reset()
    native = gym.make("Ant-v5").unwrapped
    native.reset(seed=0)
    native.set_state(ours.state["qpos"][1].copy(), ours.state["qvel"][1].copy())
    actions = torch.rand(30, 2, 8, generator=torch.Generator().manual_seed(2)) * 2 - 1
    for a in actions:
        td = ours.step(td.set("action", a))["next"]
        obs, reward, terminated, _, info = native.step(a[1].numpy().astype(np.float64))
        np.testing.assert_allclose(td["observation"][1].numpy(), obs, rtol=1e-5, atol=1e-5)
        for term in ("forward", "ctrl", "contact", "survive"):
            assert td["info", f"reward_{term}"][1].item() == pytest.approx(info[f"reward_{term}"], rel=1e-5, abs=1e-6)
        assert td["reward"][1].item() == pytest.approx(reward, rel=1e-5, abs=1e-5)
        assert td["terminated"][1].item() == terminated
    assert td["observation"][1, 27:].abs().sum() > 0  # contact forces are live (mj_rnePostConstraint ran)
