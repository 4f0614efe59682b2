"""Quaternion helpers for batched states, MuJoCo convention (w, x, y, z), shapes [*B, 4] and [*B, 3].

Example:
    >>> import math, torch
    >>> yaw90 = torch.tensor([[math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]])
    >>> quat_rotate(yaw90, torch.tensor([[1.0, 0.0, 0.0]])).round(decimals=6).abs().tolist()
    [[0.0, 1.0, 0.0]]
"""

from __future__ import annotations

import torch


def quat_rotate(quat: torch.Tensor, vec: torch.Tensor) -> torch.Tensor:
    """Rotates ``vec`` [*B, 3] from the body frame to the world frame by unit ``quat`` [*B, 4] (w, x, y, z)."""
    w, xyz = quat[..., :1], quat[..., 1:]
    t = 2.0 * torch.linalg.cross(xyz, vec, dim=-1)  # t = 2 q_v × v
    return vec + w * t + torch.linalg.cross(xyz, t, dim=-1)  # v' = v + w t + q_v × t


def quat_rotate_inverse(quat: torch.Tensor, vec: torch.Tensor) -> torch.Tensor:
    """Rotates ``vec`` [*B, 3] from the world frame into the body frame of ``quat`` [*B, 4]."""
    conjugate = torch.cat([quat[..., :1], -quat[..., 1:]], dim=-1)  # q* = (w, -x, -y, -z)
    return quat_rotate(conjugate, vec)


def body_axis(quat: torch.Tensor, axis: int) -> torch.Tensor:
    """World-frame direction [*B, 3] of the body's x (0), y (1) or z (2) axis."""
    basis = torch.zeros(*quat.shape[:-1], 3, dtype=quat.dtype, device=quat.device)
    basis[..., axis] = 1.0
    return quat_rotate(quat, basis)
