"""``task=quadcopter``: Isaac Gym's Quadcopter reward on a MuJoCo quadcopter authored here (assets/quadcopter.xml).

Terms [N] with d = ‖target − p‖ (target (0, 0, 1)), tilt = |1 − up_z|, ω_z the world yaw rate::

    pos      = 1 / (1 + d²)
    pos_up   = pos · 1 / (1 + tilt²)
    pos_spin = pos · 1 / (1 + ω_z²)
    reward   = pos + pos · (up + spin) = pos + pos_up + pos_spin

An env terminates when d > 3 or z < 0.3, and is truncated at the time limit.
"""

from __future__ import annotations

from importlib.resources import files

import mujoco
import numpy as np
import torch
from torchrl.envs import EnvBase

from torchrl_ahrs.envs.backends.mujoco_base import BatchedMujocoEnv, with_reward_components
from torchrl_ahrs.envs.common.rotations import body_axis, quat_rotate
from torchrl_ahrs.envs.settings import QuadcopterSettings

QUADCOPTER_TERMS = ("pos", "pos_up", "pos_spin")


def quadcopter_reward_terms(
    position: torch.Tensor, quat: torch.Tensor, angvel_world: torch.Tensor, target: torch.Tensor
) -> dict[str, torch.Tensor]:
    """Isaac Gym Quadcopter terms ``{pos, pos_up, pos_spin}`` [N] from position [N, 3], quaternion [N, 4]
    (w, x, y, z), world angular velocity [N, 3] and target [3].

    Example:
        >>> hover = quadcopter_reward_terms(torch.tensor([[0.0, 0.0, 1.0]]), torch.tensor([[1.0, 0, 0, 0]]),
        ...                                 torch.zeros(1, 3), torch.tensor([0.0, 0.0, 1.0]))
        >>> {k: v.item() for k, v in hover.items()}  # at the target, level, not spinning: 1 + 1 + 1
        {'pos': 1.0, 'pos_up': 1.0, 'pos_spin': 1.0}
    """
    distance = (target - position).norm(dim=-1)  # d = ‖target − p‖
    pos = 1.0 / (1.0 + distance.square())  # 1 / (1 + d²)
    tilt = (1.0 - body_axis(quat, 2)[:, 2]).abs()  # |1 − up_z|
    up = 1.0 / (1.0 + tilt.square())
    spin = 1.0 / (1.0 + angvel_world[:, 2].square())  # 1 / (1 + ω_z²)
    return {"pos": pos, "pos_up": pos * up, "pos_spin": pos * spin}


class QuadcopterEnv(BatchedMujocoEnv):
    """Fly to and hover at a target with four rotors; actions [N, 4] in [-1, 1] → thrust fraction (a+1)/2.

    Observation [N, 13]: target − position (3), quaternion (4), world linear velocity / 2 (3),
    world angular velocity / π (3).

    Example:
        >>> env = QuadcopterEnv(num_envs=2)
        >>> env.rollout(2)["next", "info", "reward_pos_up"].shape
        torch.Size([2, 2])
    """

    reward_term_names = QUADCOPTER_TERMS

    def __init__(
        self,
        num_envs: int,
        decimation: int = 2,
        max_episode_steps: int = 500,
        target: tuple[float, float, float] = (0.0, 0.0, 1.0),
        max_distance: float = 3.0,
        min_height: float = 0.3,
        num_threads: int | None = None,
        seed: int = 0,
        device: str = "cpu",
    ):
        model = mujoco.MjModel.from_xml_path(str(files("torchrl_ahrs.envs.tasks") / "assets" / "quadcopter.xml"))
        self.target = torch.tensor(target, dtype=torch.float64)
        self.max_distance, self.min_height = float(max_distance), float(min_height)
        super().__init__(model, num_envs, decimation, max_episode_steps, num_threads, seed, device)

    def reset_state(self, env_ids, rng):
        n = len(env_ids)
        qpos = np.tile(self.model.qpos0, (n, 1))  # at (0, 0, 1), level
        qpos[:, :2] += rng.uniform(-1.5, 1.5, (n, 2))  # Isaac Gym's start: xy ± 1.5, z − 0.2 … + 1.5
        qpos[:, 2] += rng.uniform(-0.2, 1.5, n)
        qvel = rng.uniform(-0.2, 0.2, (n, self.model.nv))
        return qpos, qvel

    def apply_action(self, action: torch.Tensor) -> torch.Tensor:
        return ((action.clamp(-1.0, 1.0) + 1.0) / 2.0).double()  # [-1, 1] → thrust fraction [0, 1]

    def _angvel_world(self) -> torch.Tensor:
        return quat_rotate(self.qpos[:, 3:7], self.qvel[:, 3:6])  # MuJoCo stores it in the body frame

    def observation(self) -> torch.Tensor:
        return torch.cat(
            [
                self.target - self.qpos[:, :3],
                self.qpos[:, 3:7],
                self.qvel[:, :3] / 2.0,
                self._angvel_world() / torch.pi,
            ],
            dim=-1,
        )

    def reward_terms(self) -> dict[str, torch.Tensor]:
        return quadcopter_reward_terms(self.qpos[:, :3], self.qpos[:, 3:7], self._angvel_world(), self.target)

    def terminated(self) -> torch.Tensor:
        distance = (self.target - self.qpos[:, :3]).norm(dim=-1)
        return (distance > self.max_distance) | (self.qpos[:, 2] < self.min_height)


def make_quadcopter(
    task: QuadcopterSettings,
    num_envs: int,
    seed: int = 0,
    device: str = "cpu",
    env_class: type[QuadcopterEnv] = QuadcopterEnv,
) -> EnvBase:
    """Task builder (registry signature): ``QuadcopterEnv`` (or ``env_class``, e.g. its MJX variant) + ``RewardComponents``
    over ``task.components``."""
    env = env_class(
        num_envs,
        decimation=int(task.decimation),
        max_episode_steps=int(task.max_episode_steps),
        target=task.target,
        max_distance=float(task.max_distance),
        min_height=float(task.min_height),
        num_threads=task.num_threads,
        seed=seed,
        device=device,
    )
    return with_reward_components(env, task.components)
