"""Ant-v5 (gymnasium / EnvPool) on :class:`BatchedMujocoEnv`: the same XML, frame skip, terms and observation.

The throughput benchmark races this against EnvPool's Ant-v5, and a test checks it step for step
against gymnasium's Ant-v5, so "the same work" is verified rather than claimed. The XML is the one
EnvPool ships (``envpool_assets``), identical to gymnasium's.
"""

from __future__ import annotations

import os

import mujoco
import torch

from torchrl_ahrs.envs.backends.mujoco_base import BatchedMujocoEnv


def envpool_ant_xml() -> str:
    """Path of the ant model that EnvPool's Ant-v5 loads (from the ``envpool_assets`` package)."""
    from envpool.registration import asset_base_path

    return os.path.join(asset_base_path("envpool_assets", "mujoco/assets_gym"), "mujoco/assets_gym/ant.xml")


class AntV5Mujoco(BatchedMujocoEnv):
    """Gymnasium/EnvPool Ant-v5 on the batched base: same XML, frame skip, terms and observation [N, 105].

    Terms [N]: forward = Δx_torso / dt, ctrl = −0.5·Σa², contact = −5e-4·Σ clip(cfrc_ext[1:], −1, 1)²,
    survive = 1 while 0.2 ≤ z ≤ 1.0. Terminates when z leaves [0.2, 1.0]; truncates after 1000 steps.

    Example:
        >>> env = AntV5Mujoco(num_envs=2)
        >>> env.rollout(3)["next", "observation"].shape
        torch.Size([2, 3, 105])
    """

    reward_term_names = ("forward", "ctrl", "contact", "survive")
    episode_state = ("prev_x",)
    state_fields = ("xpos", "cfrc_ext")

    def __init__(self, num_envs: int, num_threads: int | None = None, seed: int = 0):
        model = mujoco.MjModel.from_xml_path(envpool_ant_xml())
        self.torso = model.body("torso").id
        super().__init__(model, num_envs, decimation=5, max_episode_steps=1000, num_threads=num_threads, seed=seed)

    def init_buffers(self):
        self.prev_x = torch.zeros(self.num_envs, dtype=torch.float64)

    def reset_state(self, env_ids, rng):
        n = len(env_ids)
        qpos = self.model.qpos0 + rng.uniform(-0.1, 0.1, (n, self.model.nq))  # gymnasium reset noise
        qvel = 0.1 * rng.standard_normal((n, self.model.nv))
        return qpos, qvel

    def on_reset(self, env_ids):
        self.prev_x[env_ids] = self.state_t["xpos"][env_ids, self.torso, 0]

    def after_physics_step(self):
        x = self.state_t["xpos"][:, self.torso, 0]
        self.x_velocity = (x - self.prev_x) / self.control_dt  # v_x = Δx / dt
        self.prev_x = x.clone()

    def _contact_forces(self):
        return self.state_t["cfrc_ext"][:, 1:].clamp(-1.0, 1.0)  # excludes the world body

    def observation(self):
        return torch.cat([self.qpos[:, 2:], self.qvel, self._contact_forces().flatten(1)], -1)

    def reward_terms(self):
        z = self.qpos[:, 2]
        return {
            "forward": getattr(self, "x_velocity", torch.zeros(self.num_envs)),
            "ctrl": -0.5 * self.action.square().sum(-1),  # −0.5·Σa²
            "contact": -5e-4 * self._contact_forces().square().sum((-1, -2)),  # −5e-4·Σ f²
            "survive": ((z >= 0.2) & (z <= 1.0)).double(),
        }

    def terminated(self):
        z = self.qpos[:, 2]
        return (z < 0.2) | (z > 1.0)
