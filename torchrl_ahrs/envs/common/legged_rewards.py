"""legged_gym's locomotion reward terms as pure, vectorised tensor functions.

Every function takes batched tensors (leading dims ``*B``, usually ``[N]``) and returns the raw term
``[*B]``; the task multiplies it by its scale and by the policy step ``dt`` (legged_gym's convention,
see :func:`scale_terms`). Velocities are in the base (body) frame. Nothing here holds state: the
air-time term returns its updated timers for the caller to keep.

Example:
    >>> import torch
    >>> cmd, vel = torch.tensor([[0.5, 0.0]]), torch.tensor([[0.0, 0.0]])
    >>> round(tracking_lin_vel(cmd, vel, sigma=0.25).item(), 4)  # exp(-0.25 / 0.25)
    0.3679
    >>> scale_terms({"tracking_lin_vel": torch.tensor([1.0])}, {"tracking_lin_vel": 1.0}, dt=0.02)
    {'tracking_lin_vel': tensor([0.0200])}
"""

from __future__ import annotations

from collections.abc import Mapping

import torch

from torchrl_ahrs.envs.common.rotations import quat_rotate_inverse  # also used by the tasks as lr.quat_rotate_inverse

# legged_gym's Cassie reward scales (before × dt); only_positive_rewards is False for Cassie
CASSIE_REWARD_SCALES: dict[str, float] = {
    "termination": -200.0,
    "tracking_lin_vel": 1.0,
    "tracking_ang_vel": 1.0,
    "lin_vel_z": -0.5,
    "torques": -5.0e-6,
    "dof_acc": -2.0e-7,
    "feet_air_time": 5.0,
    "action_rate": -0.01,
    "dof_pos_limits": -1.0,
    "no_fly": 0.25,
}


def projected_gravity(quat: torch.Tensor) -> torch.Tensor:
    """Unit gravity direction (0, 0, −1) in the body frame, [*B, 3]."""
    down = torch.zeros(*quat.shape[:-1], 3, dtype=quat.dtype, device=quat.device)
    down[..., 2] = -1.0
    return quat_rotate_inverse(quat, down)


def tracking_lin_vel(command_xy: torch.Tensor, lin_vel_xy: torch.Tensor, sigma: float) -> torch.Tensor:
    """exp(−‖cmd_xy − v_xy‖² / σ), [*B]; command_xy, lin_vel_xy [*B, 2] (base frame)."""
    return torch.exp(-(command_xy - lin_vel_xy).square().sum(-1) / sigma)  # exp(-||c - v||^2 / sigma)


def tracking_ang_vel(command_yaw: torch.Tensor, ang_vel_z: torch.Tensor, sigma: float) -> torch.Tensor:
    """exp(−(cmd_yaw − ω_z)² / σ), [*B]; both [*B] (base frame)."""
    return torch.exp(-(command_yaw - ang_vel_z).square() / sigma)  # exp(-(c - w)^2 / sigma)


def lin_vel_z(lin_vel_z: torch.Tensor) -> torch.Tensor:
    """v_z², [*B] (base-frame vertical velocity)."""
    return lin_vel_z.square()


def torques(torque: torch.Tensor) -> torch.Tensor:
    """Σ_j τ_j², [*B]; torque [*B, J]."""
    return torque.square().sum(-1)


def dof_acc(dof_vel: torch.Tensor, last_dof_vel: torch.Tensor, dt: float) -> torch.Tensor:
    """Σ_j ((q̇_j − q̇_j,prev) / dt)², [*B]; velocities [*B, J], dt the policy step."""
    return ((dof_vel - last_dof_vel) / dt).square().sum(-1)  # finite-difference joint acceleration


def action_rate(action: torch.Tensor, last_action: torch.Tensor) -> torch.Tensor:
    """Σ_j (a_j − a_j,prev)², [*B]; actions [*B, A]."""
    return (action - last_action).square().sum(-1)


def soft_joint_limits(joint_range: torch.Tensor, soft_factor: float) -> tuple[torch.Tensor, torch.Tensor]:
    """legged_gym's soft limits: the range [J, 2] shrunk about its middle to ``soft_factor`` of its width."""
    middle = joint_range.mean(-1)  # m = (lo + hi) / 2
    half = 0.5 * (joint_range[..., 1] - joint_range[..., 0]) * soft_factor  # r/2 · soft
    return middle - half, middle + half


def dof_pos_limits(dof_pos: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor) -> torch.Tensor:
    """Σ_j (max(lo_j − q_j, 0) + max(q_j − hi_j, 0)), [*B]; dof_pos [*B, J], limits [J]."""
    below = (lower - dof_pos).clamp(min=0.0)  # how far under the soft lower limit
    above = (dof_pos - upper).clamp(min=0.0)  # how far over the soft upper limit
    return (below + above).sum(-1)


def no_fly(contact: torch.Tensor) -> torch.Tensor:
    """1 when exactly one foot touches the ground, else 0, [*B]; contact [*B, F] bool."""
    return (contact.sum(-1) == 1).to(torch.float32)


def feet_air_time(
    air_time: torch.Tensor,
    contact: torch.Tensor,
    last_contact: torch.Tensor,
    command_xy: torch.Tensor,
    dt: float,
    target: float = 0.5,
    min_command: float = 0.1,
) -> tuple[torch.Tensor, torch.Tensor]:
    """legged_gym's first-contact air-time reward and the updated air timers.

    A foot's contact is filtered over two steps (contact now or at the previous step). On the first
    filtered contact after a swing the foot earns (air time − target); nothing is paid while the
    commanded planar speed is at most ``min_command``.

    Args:
        air_time: [*B, F] seconds each foot has been in the air before this step.
        contact: [*B, F] bool, contact now.
        last_contact: [*B, F] bool, contact at the previous step.
        command_xy: [*B, 2] commanded planar velocity.
        dt: policy step (s).

    Returns:
        reward [*B] and the new air_time [*B, F] (zero for feet in filtered contact).
    """
    contact_filt = contact | last_contact  # debounce: contact now or one step ago
    first_contact = (air_time > 0.0) & contact_filt  # touchdown after a swing
    air_time = air_time + dt  # the swing lasted one more step
    reward = ((air_time - target) * first_contact).sum(-1)  # Σ_f (t_air,f − target) · first_f
    reward = reward * (command_xy.norm(dim=-1) > min_command)  # only while asked to move
    return reward, air_time * ~contact_filt  # timers restart at contact


def scale_terms(raw: Mapping[str, torch.Tensor], scales: Mapping[str, float], dt: float) -> dict[str, torch.Tensor]:
    """``{name: scale · dt · raw}`` for each raw term (legged_gym multiplies every scale by dt)."""
    return {name: raw[name] * (scales[name] * dt) for name in raw}
