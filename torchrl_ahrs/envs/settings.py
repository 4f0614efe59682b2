"""Typed task settings: what a task builder reads, one frozen dataclass per task family.

``conf/task/<name>.yaml`` (with its base ``_envpool``, ``_mujoco`` or ``_mjx``) is the documented reference of
every value, so a field that every task file of its family sets has **no default** here: the value is written
once, in the YAML a Hydra user reads and overrides. A field with a default is an optional switch that no task
file repeats, and its default means "absent" (``None``: the simulator's own choice).

The application turns a composed task config into these records
(:func:`torchrl_ahrs.app.shared.settings.task_settings`, which refuses a key no field takes); the builders in
:mod:`torchrl_ahrs.envs.tasks` take them. The prompt-only keys (``description``, ``component_descriptions``,
``reward_code``, ``environment_code``) and the trainer's (``critic_observation``,
``components_sum_to_native``) are not simulation settings and stay in the config.

Example:
    >>> from torchrl_ahrs.envs import make_env
    >>> task = PointReachSettings(name="point_reach", backend="cpu", components=("distance", "arrival", "ctrl"),
    ...     max_episode_steps=20, target_range=1.0, arrival_radius=0.1, ctrl_cost=0.05)
    >>> make_env(task, num_envs=2).rollout(3)["next", "reward", "arrival"].shape
    torch.Size([2, 3, 1])
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True, kw_only=True)
class TaskSettings:
    """Every task's keys: the registry name, the backend (``cpu`` or ``mjx``) and the K axis, in order.

    Example:
        >>> TaskSettings(name="point_reach", backend="cpu", components=("distance",)).components
        ('distance',)
    """

    name: str
    backend: str
    components: tuple[str, ...]


# ------------------------------------------------------------------ EnvPool family (conf/task/_envpool.yaml)
@dataclass(frozen=True, kw_only=True)
class EnvPoolSettings(TaskSettings):
    """A task stepped by EnvPool: its task id, time limit (``None``: the env's own) and worker threads (0: EnvPool's)."""

    env_id: str
    max_episode_steps: int | None
    num_threads: int


@dataclass(frozen=True, kw_only=True)
class InfoTermsSettings(EnvPoolSettings):
    """An EnvPool task whose components are its ``info`` reward entries times ``term_scale``
    (``ant_v5``, ``humanoid``, ``go1_terrain``, ``leap_cube``).

    ``terms`` maps a component to its info entry (``None``: ``"reward_<component>"`` for each);
    ``observation_keys`` names the dict observation parts that form ``"observation"`` (``None``: the flat one).
    """

    term_scale: float
    terms: Mapping[str, str] | None = None
    observation_keys: tuple[str, ...] | None = None


@dataclass(frozen=True, kw_only=True)
class AntV5Settings(InfoTermsSettings):
    """``ant_v5``: gymnasium Ant-v5's ``include_cfrc_ext_in_observation`` (false: 27 state entries, no contact forces)."""

    include_cfrc_ext_in_observation: bool


@dataclass(frozen=True, kw_only=True)
class DmcSettings(EnvPoolSettings):
    """A dm_control task (``dmc_*``): the observation parts that form ``"observation"``, in order."""

    observation_keys: tuple[str, ...]


@dataclass(frozen=True, kw_only=True)
class CheetahRunSettings(DmcSettings):
    """``dmc_cheetah_run``: the speed (m/s) where ``jog`` saturates and ``sprint`` starts."""

    jog_speed: float


@dataclass(frozen=True, kw_only=True)
class ShadowHandSettings(EnvPoolSettings):
    """``shadow_hand``: the observation parts and the Isaac Gym-style term parameters
    (:class:`~torchrl_ahrs.envs.tasks.shadow_hand.ShadowHandTerms`)."""

    observation_keys: tuple[str, ...]
    dist_scale: float
    rot_eps: float
    action_scale: float
    success_tolerance: float
    success_bonus: float
    fall_distance: float
    fall_penalty: float


# ------------------------------------------------------- own MuJoCo models (conf/task/_mujoco.yaml, _mjx.yaml)
@dataclass(frozen=True, kw_only=True)
class PointReachSettings(TaskSettings):
    """``point_reach`` (:class:`~torchrl_ahrs.envs.tasks.point_reach.PointReachEnv`'s arguments); ``num_threads``
    is an optional switch (``+task.num_threads=2``; ``None``: the env's single thread, the model is tiny)."""

    max_episode_steps: int
    target_range: float
    arrival_radius: float
    ctrl_cost: float
    num_threads: int | None = None


@dataclass(frozen=True, kw_only=True)
class MujocoSettings(TaskSettings):
    """A task on the batched MuJoCo base: its stepping threads (``None``: ``min(cpu count, num_envs)``)."""

    num_threads: int | None


@dataclass(frozen=True, kw_only=True)
class MjxSettings(MujocoSettings):
    """A MuJoCo task with an MJX variant: ``mjx_x64`` runs MJX in float64 (``backend=mjx`` only)."""

    mjx_x64: bool


@dataclass(frozen=True, kw_only=True)
class AntSettings(MjxSettings):
    """``ant``: control steps per episode, physics substeps per control step and Isaac Gym's reward scales."""

    max_episode_steps: int
    decimation: int
    scales: Mapping[str, float]


@dataclass(frozen=True, kw_only=True)
class QuadcopterSettings(MjxSettings):
    """``quadcopter``: episode length, substeps, the hover point [3] (m) and the termination bounds (m)."""

    max_episode_steps: int
    decimation: int
    target: tuple[float, float, float]
    max_distance: float
    min_height: float


@dataclass(frozen=True, kw_only=True)
class CassieCommands:
    """Cassie's velocity commands: the sampling ranges ``(low, high)`` and how often and how small."""

    lin_vel_x: tuple[float, float]
    lin_vel_y: tuple[float, float]
    ang_vel_yaw: tuple[float, float]
    resampling_time_s: float
    min_planar_command: float


@dataclass(frozen=True, kw_only=True)
class CassieSettings(MjxSettings):
    """``cassie``: model and simulation, PD gains per leg joint, commands, reward and resets (``cassie.yaml``)."""

    model_path: str | None
    physics_dt: float
    decimation: int
    episode_length_s: float
    action_scale: float
    stiffness: Mapping[str, float]
    damping: Mapping[str, float]
    commands: CassieCommands
    reward_scales: Mapping[str, float]
    tracking_sigma: float
    soft_dof_pos_limit: float
    feet_air_time_target: float
    contact_threshold: float
    min_base_height: float
    init_joint_noise: float
    init_base_vel_noise: float


@dataclass(frozen=True, kw_only=True)
class BimanualSettings(MujocoSettings):
    """Two Shadow hands (:class:`~torchrl_ahrs.envs.tasks.bimanual.BimanualShadowEnv`): episode, resets, base
    reach; ``base_kp`` / ``base_rot_kp`` (``None``: the hand's own servo gains) are optional."""

    max_episode_steps: int
    decimation: int
    reset_dof_noise: float
    reset_position_noise: float
    base_range: float
    base_rot_range: float
    base_kp: float | None = None
    base_rot_kp: float | None = None
    gate: float


@dataclass(frozen=True, kw_only=True)
class ScissorsSettings(BimanualSettings):
    """``shadow_hand_scissors``: the opening reward's scale and the success and failure thresholds."""

    open_scale: float
    success_q: float
    fail_up: float
    fail_finger_dist: float


@dataclass(frozen=True, kw_only=True)
class BottleCapSettings(BimanualSettings):
    """``shadow_hand_bottle_cap``: the lift reward's scale and the success and failure thresholds."""

    lift_scale: float
    success_lift: float
    fail_cap_height: float
    fail_right_dist: float
    fail_left_dist: float
