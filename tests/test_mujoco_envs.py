"""Batched MuJoCo base and the ant / quadcopter tasks: hand-derived reward oracles, partial resets,
determinism and TorchRL spec checks."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from torchrl_ahrs.envs.mujoco_base import BatchedMujocoEnv

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
