"""``task=point_reach``: a planar point mass driven to a random target — the smallest real MuJoCo task.

It exists so that a full learning run (collection, K-head GAE, PPO, scheduling) fits in a minute of
CI time and still shows the return clearly going up. Three components, each with a known meaning::

    distance   −‖p − p*‖                         (m)  dominant, shaped
    arrival    1 if ‖p − p*‖ < arrival_radius         sparse bonus
    ctrl       −ctrl_cost · Σ a²                      effort

The native reward is their sum.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from torchrl_ahrs.envs.backends.mujoco_base import BatchedMujocoEnv, with_reward_components
from torchrl_ahrs.envs.settings import PointReachSettings

POINT_XML = """
<mujoco model="point_reach">
  <option timestep="0.02"/>
  <asset>  <!-- visual only: a sky for the tracking camera (MuJoCo draws none without a skybox texture) -->
    <texture type="skybox" builtin="gradient" rgb1="0.6 0.75 0.9" rgb2="0.2 0.25 0.35" width="64" height="64"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1" rgba="0.8 0.8 0.8 1"/>
    <body name="point" pos="0 0 0.05">
      <joint name="x" type="slide" axis="1 0 0" damping="2"/>
      <joint name="y" type="slide" axis="0 1 0" damping="2"/>
      <geom type="sphere" size="0.05" mass="1" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <actuator>
    <motor joint="x" gear="4" ctrlrange="-1 1" ctrllimited="true"/>
    <motor joint="y" gear="4" ctrlrange="-1 1" ctrllimited="true"/>
  </actuator>
</mujoco>
"""


class PointReachEnv(BatchedMujocoEnv):
    """A point mass on two slide joints; the target is resampled at every reset.

    Observation ``[N, 6]``: position, velocity, target − position.

    Example:
        >>> env = PointReachEnv(num_envs=3)
        >>> sorted(env.rollout(2)["next", "info"].keys())
        ['reward_arrival', 'reward_ctrl', 'reward_distance']
    """

    reward_term_names = ("distance", "arrival", "ctrl")
    episode_state = ("target",)

    def __init__(
        self,
        num_envs: int,
        max_episode_steps: int = 100,
        target_range: float = 1.0,
        arrival_radius: float = 0.1,
        ctrl_cost: float = 0.05,
        seed: int = 0,
        device: str = "cpu",
        num_threads: int | None = 1,
    ):
        self.target_range = target_range
        self.arrival_radius = arrival_radius
        self.ctrl_cost = ctrl_cost
        model = mujoco.MjModel.from_xml_string(POINT_XML)
        super().__init__(model, num_envs, 1, max_episode_steps, num_threads, seed, device)

    def init_buffers(self) -> None:
        self.target = torch.zeros(self.num_envs, 2, dtype=torch.float64)

    def reset_state(self, env_ids: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        count = len(env_ids)
        self.target[torch.as_tensor(env_ids)] = torch.from_numpy(
            rng.uniform(-self.target_range, self.target_range, (count, 2))
        )
        return np.zeros((count, 2)), np.zeros((count, 2))

    def _distance(self) -> torch.Tensor:
        return torch.linalg.vector_norm(self.target - self.qpos, dim=-1)  # d = ‖p* − p‖

    def observation(self) -> torch.Tensor:
        return torch.cat([self.qpos, self.qvel, self.target - self.qpos], dim=-1)

    def reward_terms(self) -> dict[str, torch.Tensor]:
        distance = self._distance()
        return {
            "distance": -distance,  # r_dist = −d
            "arrival": (distance < self.arrival_radius).to(torch.float64),  # r_arr = 1[d < radius]
            "ctrl": -self.ctrl_cost * self.action.pow(2).sum(-1),  # r_ctrl = −c Σ a²
        }


def make_point_reach(task: PointReachSettings, num_envs: int, seed: int, device: str = "cpu"):
    """Builder for the registry: :class:`PointReachEnv` with its components as reward leaves."""
    env = PointReachEnv(
        num_envs,
        max_episode_steps=task.max_episode_steps,
        target_range=task.target_range,
        arrival_radius=task.arrival_radius,
        ctrl_cost=task.ctrl_cost,
        seed=seed,
        device=device,
        **({"num_threads": task.num_threads} if task.num_threads is not None else {}),
    )
    return with_reward_components(env, task.components)
