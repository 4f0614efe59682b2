"""``task=ant``: the Isaac Gym Ant reward on a MuJoCo ant authored for this project (assets/ant.xml).

Reward terms (all [N]) and how Isaac Gym's death rule maps onto components::

    progress        = φ_t − φ_{t−1},  φ = −‖target_xy − torso_xy‖ / dt       (target at x = 1000)
    alive           = 0.5
    up              = 0.1 · [up_proj > 0.93]
    heading         = 0.5 if heading_proj > 0.8 else 0.5 · heading_proj / 0.8
    actions_cost    = −0.005 · Σ a²
    energy          = −0.05 · Σ |a · 0.2 q̇|          (Isaac Gym scales joint velocities by 0.2 first)
    joints_at_limit = −0.1 · #{joints with scaled position > 0.99}   (Isaac Gym counts the upper side only)
    death           = −2 when torso z < 0.31, else 0

Isaac Gym replaces the whole reward by the death cost on a fall. Here, on a fall step every other term
is set to 0 and ``death`` = −2, so Σ components equals Isaac Gym's total on every step.
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib.resources import files

import mujoco
import numpy as np
import torch
from torchrl.envs import EnvBase

from torchrl_ahrs.envs.backends.mujoco_base import BatchedMujocoEnv, with_reward_components
from torchrl_ahrs.envs.common.rotations import body_axis, quat_rotate_inverse
from torchrl_ahrs.envs.settings import AntSettings

ANT_TERMS = ("progress", "alive", "up", "heading", "actions_cost", "energy", "joints_at_limit", "death")

DEFAULT_SCALES = {
    "alive_reward": 0.5,
    "up_weight": 0.1,
    "heading_weight": 0.5,
    "actions_cost_scale": 0.005,
    "energy_cost_scale": 0.05,
    "dof_vel_scale": 0.2,
    "joints_at_limit_cost_scale": 0.1,
    "death_cost": -2.0,
    "termination_height": 0.31,
}


def ant_reward_terms(
    progress: torch.Tensor,
    torso_z: torch.Tensor,
    up_proj: torch.Tensor,
    heading_proj: torch.Tensor,
    actions: torch.Tensor,
    dof_vel: torch.Tensor,
    dof_pos_scaled: torch.Tensor,
    scales: Mapping[str, float] = DEFAULT_SCALES,
) -> dict[str, torch.Tensor]:
    """Isaac Gym Ant reward terms, one tensor [N] per name in ``ANT_TERMS``; Σ terms = Isaac Gym's total.

    Args:
        progress: potential difference φ_t − φ_{t−1} [N].
        torso_z: torso height [N].
        up_proj: world z component of the torso's z axis [N].
        heading_proj: torso x axis · unit direction to the target [N].
        actions: policy actions in [-1, 1], [N, A].
        dof_vel: joint velocities (rad/s) [N, A].
        dof_pos_scaled: joint positions mapped to [-1, 1] by their limits [N, A].

    Example:
        >>> n = 2
        >>> terms = ant_reward_terms(torch.tensor([1.0, 1.0]), torch.tensor([0.5, 0.2]), torch.ones(n),
        ...                          torch.ones(n), torch.zeros(n, 8), torch.zeros(n, 8), torch.zeros(n, 8))
        >>> [round(x, 4) for x in sum(terms.values()).tolist()]  # 1 + 0.5 + 0.1 + 0.5; fallen: death only
        [2.1, -2.0]
    """
    s = {**DEFAULT_SCALES, **scales}
    alive = torch.full_like(torso_z, s["alive_reward"])
    up = torch.where(up_proj > 0.93, s["up_weight"], 0.0)  # bonus when nearly upright
    heading = torch.where(
        heading_proj > 0.8, s["heading_weight"], s["heading_weight"] * heading_proj / 0.8
    )  # full weight when facing the target, linear below 0.8
    actions_cost = -s["actions_cost_scale"] * actions.square().sum(-1)  # −c_a Σ a²
    energy = -s["energy_cost_scale"] * (actions * dof_vel * s["dof_vel_scale"]).abs().sum(-1)  # −c_e Σ|a·0.2q̇|
    at_limit = (dof_pos_scaled > 0.99).sum(-1).to(torso_z.dtype)  # joints pressed to their upper limit
    terms = {
        "progress": progress,
        "alive": alive,
        "up": up,
        "heading": heading,
        "actions_cost": actions_cost,
        "energy": energy,
        "joints_at_limit": -s["joints_at_limit_cost_scale"] * at_limit,
    }
    fallen = torso_z < s["termination_height"]
    terms = {name: torch.where(fallen, 0.0, value) for name, value in terms.items()}  # death replaces the total
    terms["death"] = torch.where(fallen, s["death_cost"], 0.0)
    return terms


class AntEnv(BatchedMujocoEnv):
    """The ant running towards a far target, Isaac Gym's reward split into ``ANT_TERMS``.

    Observation [N, 37]: torso z, torso quaternion (4), linear and angular velocity in the torso frame
    (3 + 3), up_proj, heading_proj, scaled joint positions (8), 0.2 × joint velocities (8), last action (8).

    Example:
        >>> env = AntEnv(num_envs=2)
        >>> env.rollout(2)["next", "info", "reward_progress"].shape
        torch.Size([2, 2])
    """

    reward_term_names = ANT_TERMS
    episode_state = ("potential", "prev_potential")

    def __init__(
        self,
        num_envs: int,
        decimation: int = 2,
        max_episode_steps: int = 1000,
        scales: Mapping[str, float] | None = None,
        target_xy: tuple[float, float] = (1000.0, 0.0),
        num_threads: int | None = None,
        seed: int = 0,
        device: str = "cpu",
    ):
        model = mujoco.MjModel.from_xml_path(str(files("torchrl_ahrs.envs.tasks") / "assets" / "ant.xml"))
        self.scales = {**DEFAULT_SCALES, **(scales or {})}
        self.target_xy = torch.tensor(target_xy, dtype=torch.float64)
        low, high = model.jnt_range[1:, 0], model.jnt_range[1:, 1]  # joint 0 is the free root
        self.dof_low, self.dof_high = torch.from_numpy(low.copy()), torch.from_numpy(high.copy())
        self._dof_range_np = (low.copy(), high.copy())  # reset_state draws on the host, whatever the env's device
        super().__init__(model, num_envs, decimation, max_episode_steps, num_threads, seed, device)

    def init_buffers(self) -> None:
        self.potential = torch.zeros(self.num_envs, dtype=torch.float64)
        self.prev_potential = torch.zeros(self.num_envs, dtype=torch.float64)

    def reset_state(self, env_ids, rng):
        n, model = len(env_ids), self.model
        qpos = np.tile(model.qpos0, (n, 1))
        # joints: zero + U(−0.2, 0.2), clamped into their limits (Isaac Gym's reset)
        qpos[:, 7:] = np.clip(rng.uniform(-0.2, 0.2, (n, model.nu)), *self._dof_range_np)
        qvel = np.zeros((n, model.nv))
        qvel[:, 6:] = rng.uniform(-0.1, 0.1, (n, model.nu))
        return qpos, qvel

    def _potential(self) -> torch.Tensor:
        return -(self.target_xy - self.qpos[:, :2]).norm(dim=-1) / self.control_dt  # φ = −‖target − xy‖ / dt

    def on_reset(self, env_ids) -> None:
        self.potential[env_ids] = self._potential()[env_ids]
        self.prev_potential[env_ids] = self.potential[env_ids]

    def after_physics_step(self) -> None:
        self.prev_potential = self.potential
        self.potential = self._potential()

    def _projections(self) -> tuple[torch.Tensor, torch.Tensor]:
        quat = self.qpos[:, 3:7]
        up_proj = body_axis(quat, 2)[:, 2]  # z of the torso's up axis
        to_target = torch.nn.functional.pad(self.target_xy - self.qpos[:, :2], (0, 1))
        heading_proj = (body_axis(quat, 0) * torch.nn.functional.normalize(to_target, dim=-1)).sum(-1)
        return up_proj, heading_proj

    def _dof_pos_scaled(self) -> torch.Tensor:
        return (2 * self.qpos[:, 7:] - self.dof_high - self.dof_low) / (self.dof_high - self.dof_low)  # → [-1, 1]

    def observation(self) -> torch.Tensor:
        quat = self.qpos[:, 3:7]
        up_proj, heading_proj = self._projections()
        return torch.cat(
            [
                self.qpos[:, 2:7],
                quat_rotate_inverse(quat, self.qvel[:, :3]),  # world linear velocity → torso frame
                self.qvel[:, 3:6],  # MuJoCo's free-joint angular velocity is already in the torso frame
                up_proj[:, None],
                heading_proj[:, None],
                self._dof_pos_scaled(),
                self.scales["dof_vel_scale"] * self.qvel[:, 6:],
                self.action.double(),
            ],
            dim=-1,
        )

    def reward_terms(self) -> dict[str, torch.Tensor]:
        up_proj, heading_proj = self._projections()
        return ant_reward_terms(
            self.potential - self.prev_potential,
            self.qpos[:, 2],
            up_proj,
            heading_proj,
            self.action.double(),
            self.qvel[:, 6:],
            self._dof_pos_scaled(),
            self.scales,
        )

    def terminated(self) -> torch.Tensor:
        return self.qpos[:, 2] < self.scales["termination_height"]


def make_ant(
    task: AntSettings,
    num_envs: int,
    seed: int = 0,
    device: str = "cpu",
    env_class: type[AntEnv] = AntEnv,
) -> EnvBase:
    """Task builder (registry signature): ``AntEnv`` (or ``env_class``, e.g. its MJX variant) + ``RewardComponents``
    over ``task.components``."""
    env = env_class(
        num_envs,
        decimation=int(task.decimation),
        max_episode_steps=int(task.max_episode_steps),
        scales=dict(task.scales),
        num_threads=task.num_threads,
        seed=seed,
        device=device,
    )
    return with_reward_components(env, task.components)
