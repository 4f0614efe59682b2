"""Cassie velocity tracking on flat ground with legged_gym's reward, as a batched MuJoCo env.

The policy (50 Hz) sets joint-position targets, default + 0.5 · action, for the ten actuated joints;
PD servos inside MuJoCo track them for ``decimation`` physics steps. Observations follow legged_gym:
base linear velocity × 2, base angular velocity × 0.25, projected gravity, commands × (2, 2, 0.25),
joint positions − default, joint velocities × 0.05 and the last action (42 numbers). A velocity
command (v_x, v_y, ω_yaw) is resampled every 10 s; planar commands under 0.2 m/s are zeroed. An
episode lasts 20 s and ends early when the pelvis touches the ground or drops below a height.

The reward is legged_gym's Cassie reward: ten terms (:data:`CASSIE_REWARD_SCALES`), each scale × dt,
summed without clipping; each term is one reward component ``("next", "reward", <term>)``.

Two models load (``task.model_path``):

* the default, ``assets/cassie.xml``, authored in this project: 33.4 kg, 18 DoF (free joint + 6 per leg).
  The achilles-rod four-bar is a rigid joint coupling (tarsus = 0.13 − knee), the shin and heel leaf
  springs are rigid, the toe is driven directly, no self-collision; stable at a 5 ms physics step.
* MuJoCo Menagerie's ``agility_cassie/scene.xml``: 33.3 kg, 32 DoF. Closed loops are four ``connect``
  equality constraints (achilles rod to heel spring, plantar rod to foot) with ball-jointed rods and a
  foot crank; the shin (1500 N m/rad) and heel (1250 N m/rad) springs are joints with stiffness; the two
  legs collide with each other. It is unstable at 5 ms: use ``task.physics_dt=0.002 task.decimation=10``.

Both ship torque motors with gearboxes (gear 25/25/16/16/50); loading turns them into PD servos with
the motor torque limits (:mod:`torchrl_ahrs.envs.tasks.cassie_model`). Joint angle conventions differ, so the
default pose is each model's ``home`` keyframe.

Differences from legged_gym: no observation noise, no heading command (ω_yaw is commanded directly),
additive joint noise at reset instead of scaling, one contact threshold (1 N) for air time and no_fly.

Example:
    >>> from torchrl_ahrs.app.shared.settings import load_task_settings
    >>> env = make_cassie(load_task_settings("cassie"), num_envs=2, seed=0)
    >>> td = env.rollout(3)
    >>> td["next", "reward", "tracking_lin_vel"].shape, td["observation"].shape
    (torch.Size([2, 3, 1]), torch.Size([2, 3, 42]))
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import mujoco
import numpy as np
import torch
from torchrl.envs import EnvBase

from torchrl_ahrs.envs.backends.mujoco_base import BatchedMujocoEnv, with_reward_components
from torchrl_ahrs.envs.common import legged_rewards as lr
from torchrl_ahrs.envs.common.mirror import SignedPermutation
from torchrl_ahrs.envs.settings import CassieSettings
from torchrl_ahrs.envs.tasks.cassie_model import LEG_JOINTS, CassieLayout, load_cassie_model

OBS_SCALES = {"lin_vel": 2.0, "ang_vel": 0.25, "dof_pos": 1.0, "dof_vel": 0.05}
# how each leg joint's angle mirrors about the sagittal (x-z) plane in the shipped model, whose right leg is the
# left one reflected in y (assets/cassie.xml): rotations about x (roll) and z (yaw) change sign, about y do not
MIRROR_JOINT_SIGNS = {"hip_roll": -1.0, "hip_yaw": -1.0, "hip_pitch": 1.0, "knee": 1.0, "toe": 1.0}


class CassieEnv(BatchedMujocoEnv):
    """N Cassies tracking velocity commands; see the module docstring.

    Args:
        model, layout: from :func:`~torchrl_ahrs.envs.tasks.cassie_model.load_cassie_model`.
        num_envs: batch size N.
        decimation: physics steps per policy step (policy dt = decimation · model timestep).
        episode_length_s: time limit (s).
        action_scale: joint target = default + action_scale · action, action in [−1, 1].
        command_ranges: ``{"lin_vel_x": (lo, hi), "lin_vel_y": ..., "ang_vel_yaw": ...}``.
        resampling_time_s: seconds between command resamples.
        min_planar_command: planar commands shorter than this are set to zero.
        reward_scales: ``{term: scale}`` (multiplied by the policy dt).
        tracking_sigma, soft_dof_pos_limit, feet_air_time_target: reward parameters.
        contact_threshold: touch force (N) above which a foot or the pelvis is in contact.
        min_base_height: pelvis height (m) under which an episode terminates.
        init_joint_noise, init_base_vel_noise: uniform reset noise half-widths (rad, m/s and rad/s).

    Example:
        >>> model, layout = load_cassie_model()
        >>> env = CassieEnv(model, layout, num_envs=2)
        >>> env.rollout(2)["next", "info", "reward_no_fly"].shape
        torch.Size([2, 2])
    """

    reward_term_names = tuple(lr.CASSIE_REWARD_SCALES)
    episode_state = ("commands", "last_action", "last_dof_vel", "feet_air_time", "last_contact", "fallen", "terms")
    state_fields = ("sensordata", "actuator_force")

    def __init__(
        self,
        model: mujoco.MjModel,
        layout: CassieLayout,
        num_envs: int,
        decimation: int = 4,
        episode_length_s: float = 20.0,
        action_scale: float = 0.5,
        command_ranges: Mapping[str, tuple[float, float]] | None = None,
        resampling_time_s: float = 10.0,
        min_planar_command: float = 0.2,
        reward_scales: Mapping[str, float] | None = None,
        tracking_sigma: float = 0.25,
        soft_dof_pos_limit: float = 0.95,
        feet_air_time_target: float = 0.5,
        contact_threshold: float = 1.0,
        min_base_height: float = 0.55,
        init_joint_noise: float = 0.1,
        init_base_vel_noise: float = 0.5,
        num_threads: int | None = None,
        seed: int = 0,
        device: str | torch.device = "cpu",
    ):
        dt = decimation * float(model.opt.timestep)
        ranges = dict(command_ranges or {"lin_vel_x": (-1, 1), "lin_vel_y": (-1, 1), "ang_vel_yaw": (-1, 1)})
        self.layout = layout
        self.policy_dt = dt
        self.action_scale = float(action_scale)
        self.command_low = np.array([ranges[k][0] for k in ("lin_vel_x", "lin_vel_y", "ang_vel_yaw")], np.float64)
        self.command_high = np.array([ranges[k][1] for k in ("lin_vel_x", "lin_vel_y", "ang_vel_yaw")], np.float64)
        self.resampling_steps = max(1, round(resampling_time_s / dt))
        self.min_planar_command = float(min_planar_command)
        unknown = set(reward_scales or {}) - set(lr.CASSIE_REWARD_SCALES)
        if unknown:
            raise ValueError(f"unknown Cassie reward terms {sorted(unknown)}; terms: {list(lr.CASSIE_REWARD_SCALES)}")
        self.reward_scales = {**lr.CASSIE_REWARD_SCALES, **(reward_scales or {})}
        self.tracking_sigma = float(tracking_sigma)
        self.feet_air_time_target = float(feet_air_time_target)
        self.contact_threshold = float(contact_threshold)
        self.min_base_height = float(min_base_height)
        self.init_joint_noise = float(init_joint_noise)
        self.init_base_vel_noise = float(init_base_vel_noise)
        self.default_joint_pos = torch.as_tensor(layout.default_joint_pos, dtype=torch.float64)
        # torch copies of the layout's indices: indexing a tensor with a tensor skips numpy conversion
        self._qpos_idx, self._dof_idx = torch.as_tensor(layout.qpos_adr), torch.as_tensor(layout.dof_adr)
        self._act_idx, self._foot_idx = torch.as_tensor(layout.actuator_ids), torch.as_tensor(layout.foot_touch_adr)
        self.soft_lower, self.soft_upper = lr.soft_joint_limits(
            torch.as_tensor(layout.joint_range, dtype=torch.float64), soft_dof_pos_limit
        )
        # observation scale of the commands (v_x, v_y, ω_yaw), legged_gym's (lin_vel, lin_vel, ang_vel)
        self.command_scale = torch.tensor([OBS_SCALES["lin_vel"], OBS_SCALES["lin_vel"], OBS_SCALES["ang_vel"]])
        max_steps = max(1, round(episode_length_s / dt))
        super().__init__(model, num_envs, decimation, max_steps, num_threads, seed, device)

    @property
    def action_dim(self) -> int:
        return len(self.layout.actuator_ids)

    # ---------------------------------------------------------------- buffers and resets
    def init_buffers(self) -> None:
        n, joints, feet = self.num_envs, len(self.layout.qpos_adr), len(self.layout.foot_touch_adr)
        self.commands = torch.zeros(n, 3, dtype=torch.float64)  # (v_x, v_y, ω_yaw), base frame
        self.last_action = torch.zeros(n, joints)
        self.last_dof_vel = torch.zeros(n, joints, dtype=torch.float64)
        self.feet_air_time = torch.zeros(n, feet, dtype=torch.float64)
        self.last_contact = torch.zeros(n, feet, dtype=torch.bool)
        self.fallen = torch.zeros(n, dtype=torch.bool)
        self.terms = {name: torch.zeros(n, dtype=torch.float64) for name in self.reward_term_names}
        # control steps since each env's reset, on the host: which envs resample their command is known
        # without reading episode_steps back from the env's device (a sync per step on an accelerator)
        self.resample_clock = np.zeros(n, np.int64)

    def reset_state(self, env_ids: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        n, layout = len(env_ids), self.layout
        qpos = np.tile(layout.home_qpos, (n, 1))  # nominal stance, passive joints consistent with it
        noise = rng.uniform(-self.init_joint_noise, self.init_joint_noise, (n, len(layout.qpos_adr)))
        qpos[:, layout.qpos_adr] = np.clip(qpos[:, layout.qpos_adr] + noise, *layout.joint_range.T)
        qvel = np.zeros((n, self.model.nv))
        qvel[:, :6] = rng.uniform(-self.init_base_vel_noise, self.init_base_vel_noise, (n, 6))  # base twist
        return qpos, qvel

    def on_reset(self, env_ids: np.ndarray) -> None:
        ids = torch.as_tensor(env_ids, dtype=torch.long, device=self.qpos.device)
        self.resample_clock[env_ids] = 0
        self.last_action[ids] = 0.0
        self.last_dof_vel[ids] = 0.0
        self.feet_air_time[ids] = 0.0
        self.last_contact[ids] = False
        self.fallen[ids] = False
        self._resample_commands(ids)

    def _resample_commands(self, ids: torch.Tensor | np.ndarray) -> None:
        """Draws commands uniformly in their ranges for envs ``ids``; short planar commands become 0."""
        if len(ids) == 0:
            return
        draw = torch.from_numpy(self.rng.uniform(self.command_low, self.command_high, (len(ids), 3)))
        moving = draw[:, :2].norm(dim=-1, keepdim=True) > self.min_planar_command
        draw[:, :2] *= moving  # legged_gym: ‖cmd_xy‖ ≤ 0.2 → stand still
        self.commands[ids] = draw.to(self.commands.device)  # the host generator's draw: O(len(ids)·3) to the device

    # ---------------------------------------------------------------- control
    def apply_action(self, action: torch.Tensor) -> torch.Tensor:
        target = self.default_joint_pos + self.action_scale * action.clamp(-1.0, 1.0).double()  # q* = q0 + s·a
        ctrl = torch.zeros(self.num_envs, self.model.nu, dtype=torch.float64, device=target.device)
        ctrl[:, self._act_idx] = target  # PD servos read ctrl as the target angle
        return ctrl

    # ---------------------------------------------------------------- state read-out
    def _base_velocities(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Base-frame linear [N, 3] and angular [N, 3] velocity of the pelvis."""
        lin_vel = lr.quat_rotate_inverse(self.qpos[:, 3:7], self.qvel[:, 0:3])  # free joint: world-frame v
        return lin_vel, self.qvel[:, 3:6]  # free joint: ω is already in the body frame

    def _dof(self) -> tuple[torch.Tensor, torch.Tensor]:
        return self.qpos[:, self._qpos_idx], self.qvel[:, self._dof_idx]

    def after_physics_step(self) -> None:
        """Computes this step's reward terms and termination, then rolls the history buffers."""
        layout, dt = self.layout, self.policy_dt
        lin_vel, ang_vel = self._base_velocities()
        dof_pos, dof_vel = self._dof()
        sensors = self.state_t["sensordata"]
        contact = sensors[:, self._foot_idx] > self.contact_threshold  # [N, 2]
        pelvis_contact = sensors[:, layout.pelvis_touch_adr] > self.contact_threshold
        self.fallen = pelvis_contact | (self.qpos[:, 2] < self.min_base_height)
        air_reward, self.feet_air_time = lr.feet_air_time(
            self.feet_air_time, contact, self.last_contact, self.commands[:, :2], dt, self.feet_air_time_target
        )
        raw = {
            "termination": self.fallen.double(),
            "tracking_lin_vel": lr.tracking_lin_vel(self.commands[:, :2], lin_vel[:, :2], self.tracking_sigma),
            "tracking_ang_vel": lr.tracking_ang_vel(self.commands[:, 2], ang_vel[:, 2], self.tracking_sigma),
            "lin_vel_z": lr.lin_vel_z(lin_vel[:, 2]),
            "torques": lr.torques(self.state_t["actuator_force"][:, self._act_idx]),
            "dof_acc": lr.dof_acc(dof_vel, self.last_dof_vel, dt),
            "feet_air_time": air_reward,
            "action_rate": lr.action_rate(self.action, self.last_action),
            "dof_pos_limits": lr.dof_pos_limits(dof_pos, self.soft_lower, self.soft_upper),
            "no_fly": lr.no_fly(contact),
        }
        self.terms = lr.scale_terms(raw, self.reward_scales, dt)
        self.last_action = self.action.clone()
        self.last_dof_vel = dof_vel.clone()
        self.last_contact = contact
        self.resample_clock += 1  # = episode_steps, kept on the host
        self._resample_commands(np.flatnonzero(self.resample_clock % self.resampling_steps == 0))

    def reward_terms(self) -> dict[str, torch.Tensor]:
        return self.terms

    def set_extra_state(self, state: dict) -> None:
        super().set_extra_state(state)
        self.resample_clock = self.episode_steps.cpu().numpy().copy()  # the host mirror of the restored counters

    def terminated(self) -> torch.Tensor:
        return self.fallen.clone()

    def observation(self) -> torch.Tensor:
        lin_vel, ang_vel = self._base_velocities()
        dof_pos, dof_vel = self._dof()
        obs = torch.cat(
            [
                lin_vel * OBS_SCALES["lin_vel"],
                ang_vel * OBS_SCALES["ang_vel"],
                lr.projected_gravity(self.qpos[:, 3:7]),
                self.commands * self.command_scale,
                (dof_pos - self.default_joint_pos) * OBS_SCALES["dof_pos"],
                dof_vel * OBS_SCALES["dof_vel"],
                self.action.double(),
            ],
            dim=-1,
        )
        return obs.clamp(-100.0, 100.0)  # legged_gym's clip_observations


def cassie_mirror(task: CassieSettings) -> dict[str, SignedPermutation]:
    """The left-right mirror of Cassie's observation [42] and action [10] (``ppo.mirror``; the task, its reward
    and the shipped model are symmetric about the pelvis's x-z plane). Reflecting y: a velocity's y, an angular
    velocity's x and z, the yaw command flip; the legs swap, their roll and yaw angles flip.

    Raises ``ValueError`` for another model (``task.model_path``): its joint conventions are not this map's."""
    if task.model_path:
        raise ValueError(f"the Cassie mirror map is derived for the shipped model, not {task.model_path}")
    legs = len(LEG_JOINTS)
    joint_signs = tuple(MIRROR_JOINT_SIGNS[name] for name in LEG_JOINTS) * 2
    joints = SignedPermutation((*range(legs, 2 * legs), *range(legs)), joint_signs)  # l <-> r, in JOINT_NAMES order
    polar = SignedPermutation((0, 1, 2), (1.0, -1.0, 1.0))  # a vector: (x, -y, z)
    axial = SignedPermutation((0, 1, 2), (-1.0, 1.0, -1.0))  # an angular velocity (pseudovector): (-x, y, -z)
    command = SignedPermutation((0, 1, 2), (1.0, -1.0, -1.0))  # (v_x, -v_y, -ω_yaw)
    # the blocks of CassieEnv.observation, in order: v, ω, gravity, command, q - q0, q̇, last action
    observation = SignedPermutation.concat([polar, axial, polar, command, joints, joints, joints])
    return {"observation": observation, "action": joints}


def _per_joint(values: Mapping[str, float] | Any) -> list[float]:
    """Gains given as ``{hip_roll: .., ..., toe: ..}`` → [5] in ``LEG_JOINTS`` order."""
    return [float(values[name]) for name in LEG_JOINTS]


def make_cassie(
    task: CassieSettings,
    num_envs: int,
    seed: int = 0,
    device: str = "cpu",
    env_class: type[CassieEnv] = CassieEnv,
) -> EnvBase:
    """Task builder (registry signature): ``CassieEnv`` (or ``env_class``, e.g. its MJX variant) + ``RewardComponents``
    over ``task.components``."""
    model, layout = load_cassie_model(
        task.model_path or None,  # "" from a command line override means the shipped model too
        physics_dt=float(task.physics_dt),
        stiffness=_per_joint(task.stiffness),
        damping=_per_joint(task.damping),
    )
    if model.neq and any(model.eq_type == mujoco.mjtEq.mjEQ_CONNECT) and model.opt.timestep > 0.002:
        warnings.warn(
            f"this Cassie model has closed-loop connect constraints and stiff springs (Menagerie's); a physics_dt "
            f"of {model.opt.timestep} s is likely unstable, use task.physics_dt=0.002 task.decimation=10",
            stacklevel=2,
        )
    commands = task.commands
    env = env_class(
        model,
        layout,
        num_envs,
        decimation=int(task.decimation),
        episode_length_s=float(task.episode_length_s),
        action_scale=float(task.action_scale),
        command_ranges={k: tuple(getattr(commands, k)) for k in ("lin_vel_x", "lin_vel_y", "ang_vel_yaw")},
        resampling_time_s=float(commands.resampling_time_s),
        min_planar_command=float(commands.min_planar_command),
        reward_scales=dict(task.reward_scales),
        tracking_sigma=float(task.tracking_sigma),
        soft_dof_pos_limit=float(task.soft_dof_pos_limit),
        feet_air_time_target=float(task.feet_air_time_target),
        contact_threshold=float(task.contact_threshold),
        min_base_height=float(task.min_base_height),
        init_joint_noise=float(task.init_joint_noise),
        init_base_vel_noise=float(task.init_base_vel_noise),
        num_threads=task.num_threads,
        seed=seed,
        device=device,
    )
    return with_reward_components(env, task.components)
