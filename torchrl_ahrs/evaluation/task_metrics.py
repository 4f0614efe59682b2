"""Task metrics beyond the return: what "doing the task well" means for each robot, per step.

A probe reads the base environment right after a step (before any reset) and returns
``{metric: Tensor [N]}``; :func:`~torchrl_ahrs.evaluation.episodes.run_episodes` averages each metric
over an episode's steps and also keeps its value at the episode's last step (``<metric>_final``).

=============  =====================================================================================
cassie         ``lin_vel_error`` ‖cmd_xy − v_xy‖ (m/s, base frame), ``ang_vel_error`` |cmd_yaw − ω_z| (rad/s);
               ``command_speed`` ‖cmd_xy‖ and ``command_turn`` |cmd_yaw|, whose ``_final`` value per episode
               says what was commanded when an episode ended early
point_reach    ``distance`` ‖p* − p‖ to the target (m)
quadcopter     ``distance`` ‖p* − p‖ to the hover point (m)
bimanual       ``success`` 1 while Bi-DexHands' success test holds (scissors opened by 0.29 rad, cap risen
               0.03 m): its episode mean is the share of steps, ``success_final`` the share of episodes
               ending opened; and ``success_rate`` the share of episodes that succeeded at some step
               (shadow_hand_scissors, shadow_hand_bottle_cap)
hands          ``success_rate``: share of episodes with a positive ``success`` return (any task that
               has a ``success`` component: shadow_hand, leap_cube); see :func:`episode_metrics`
=============  =====================================================================================
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import torch
from torchrl.envs import EnvBase

StepProbe = Callable[[EnvBase], dict[str, torch.Tensor]]


def cassie_tracking_errors(env) -> dict[str, torch.Tensor]:
    """Velocity-command tracking errors ``[N]`` of a :class:`~torchrl_ahrs.envs.tasks.cassie.CassieEnv`, and the
    command's size ``[N]`` (read at a fall, it says which commands the policy falls under)."""
    lin_vel, ang_vel = env._base_velocities()  # base-frame [N, 3] each, the same read-out the reward uses
    return {
        "lin_vel_error": torch.linalg.vector_norm(env.commands[:, :2] - lin_vel[:, :2], dim=-1),  # ‖c_xy − v_xy‖
        "ang_vel_error": (env.commands[:, 2] - ang_vel[:, 2]).abs(),  # |c_yaw − ω_z|
        "command_speed": torch.linalg.vector_norm(env.commands[:, :2], dim=-1),  # ‖c_xy‖
        "command_turn": env.commands[:, 2].abs(),  # |c_yaw|
    }


def point_reach_distance(env) -> dict[str, torch.Tensor]:
    """Distance ``[N]`` of the point mass to its target."""
    return {"distance": torch.linalg.vector_norm(env.target - env.qpos[:, :2], dim=-1)}  # ‖p* − p‖


def quadcopter_distance(env) -> dict[str, torch.Tensor]:
    """Distance ``[N]`` of the quadcopter to its hover point."""
    return {"distance": torch.linalg.vector_norm(env.target - env.qpos[:, :3], dim=-1)}  # ‖p* − p‖


def bimanual_success(env) -> dict[str, torch.Tensor]:
    """Bi-DexHands' success flag ``[N]`` (1.0 / 0.0) of a bimanual Shadow hand task."""
    return {"success": env.success().float()}


STEP_PROBES: dict[str, StepProbe] = {
    "shadow_hand_scissors": bimanual_success,
    "shadow_hand_bottle_cap": bimanual_success,
    "cassie": cassie_tracking_errors,
    "point_reach": point_reach_distance,
    "quadcopter": quadcopter_distance,
}


def step_probe(task_name: str) -> StepProbe | None:
    """The per-step metric probe of ``task_name``, or None when the task has none.

    Example:
        >>> step_probe("cassie").__name__, step_probe("ant_v5")
        ('cassie_tracking_errors', None)
    """
    return STEP_PROBES.get(task_name)


def episode_metrics(
    returns: Mapping[str, torch.Tensor], step_metrics: Mapping[str, torch.Tensor] | None = None
) -> dict[str, float]:
    """Metrics that follow from the per-episode component returns ``{c: [M]}`` and the per-episode means of
    the step probe's metrics ``{m: [M]}`` (a ``success`` step flag there takes precedence).

    Example:
        >>> episode_metrics({"success": torch.tensor([0.0, 250.0, 500.0, 0.0])})
        {'success_rate': 0.5}
        >>> episode_metrics({}, {"success": torch.tensor([0.0, 0.1, 0.0, 0.0])})
        {'success_rate': 0.25}
    """
    metrics = {}
    if step_metrics is not None and "success" in step_metrics:
        metrics["success_rate"] = (step_metrics["success"] > 0).float().mean().item()  # P(a successful step)
    elif "success" in returns:
        metrics["success_rate"] = (returns["success"] > 0).float().mean().item()  # P(at least one success step)
    return metrics
