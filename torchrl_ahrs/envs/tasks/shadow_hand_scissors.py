"""``task=shadow_hand_scissors``: Bi-DexHands' ShadowHandScissors reward on MuJoCo (appendix C of the paper).

Two Shadow hands (EnvPool's assets, see :mod:`~torchrl_ahrs.envs.tasks.bimanual`) side by side above a pair
of scissors lying on a table (``assets/bimanual_scissors.xml``: two rigid blades on one vertical hinge).
Bi-DexHands' reward (``compute_hand_reward`` in its ``shadow_hand_scissors.py``), with d_R, d_L the sums of
the five fingertip distances of each hand to its handle and q the scissors' joint angle::

    up     = 5 (0.59 + q)  if d_R < 0.7 and d_L < 0.7  else 0
    reward = 2 + up − d_R − d_L

Bi-DexHands' joint reads q = −0.59 when closed; here the hinge angle θ = 0 when closed, so q = θ − 0.59.
The components split that sum exactly (the constant 2 shared by the two hands)::

    right_reach = 1 − d_R        left_reach = 1 − d_L        open = up

Bi-DexHands also computes an action penalty but does not add it, and gives no success bonus here; success
(q > −0.3, i.e. θ > 0.29 rad) is a metric. Its resets become terminations: up < −0.5, d_R ≥ 1.75 or
d_L ≥ 1.75; its 150-step episode is the time limit.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from torchrl.envs import EnvBase

from torchrl_ahrs.envs.backends.mujoco_base import with_reward_components
from torchrl_ahrs.envs.settings import ScissorsSettings
from torchrl_ahrs.envs.tasks.bimanual import BimanualShadowEnv, bimanual_kwargs, finger_distance

SCISSORS_TERMS = ("right_reach", "left_reach", "open")
CLOSED_Q = -0.59  # Bi-DexHands' scissors joint reading when closed (rad)


def scissors_native_reward(
    right_finger_dist: torch.Tensor, left_finger_dist: torch.Tensor, q: torch.Tensor, gate: float = 0.7
) -> torch.Tensor:
    """Bi-DexHands' ShadowHandScissors reward [N], written as in its source (the oracle of the components).

    Args:
        right_finger_dist, left_finger_dist: Σ of fingertip-to-handle distances of each hand [N] (m).
        q: scissors joint position in Bi-DexHands' convention [N] (−0.59 closed, rad).
    """
    up = torch.zeros_like(right_finger_dist)
    up = torch.where(right_finger_dist < gate, torch.where(left_finger_dist < gate, (0.59 + q) * 5, up), up)
    return 2 + up - right_finger_dist - left_finger_dist  # 2 + up − d_R − d_L


def scissors_terms(
    right_finger_dist: torch.Tensor,
    left_finger_dist: torch.Tensor,
    q: torch.Tensor,
    gate: float = 0.7,
    open_scale: float = 5.0,
) -> dict[str, torch.Tensor]:
    """Components ``{right_reach, left_reach, open}`` [N] whose sum is :func:`scissors_native_reward`.

    Example:
        >>> terms = scissors_terms(torch.tensor([0.5]), torch.tensor([0.6]), torch.tensor([0.0 - 0.59 + 0.3]))
        >>> {k: round(v.item(), 3) for k, v in terms.items()}
        {'right_reach': 0.5, 'left_reach': 0.4, 'open': 1.5}
    """
    grasped = (right_finger_dist < gate) & (left_finger_dist < gate)  # both hands at their handles
    return {
        "right_reach": 1.0 - right_finger_dist,  # 1 − d_R
        "left_reach": 1.0 - left_finger_dist,  # 1 − d_L
        "open": torch.where(grasped, open_scale * (q - CLOSED_Q), torch.zeros_like(q)),  # 5 (0.59 + q)
    }


class ShadowHandScissorsEnv(BimanualShadowEnv):
    """Open the scissors with two hands; actions [N, 52], observations [N, 210].

    Object observation [20]: scissors pose (7), linear velocity (3), angular velocity × 0.2 (3), handle
    positions (right, left: 6), joint position q (1).

    Example:
        >>> env = ShadowHandScissorsEnv(num_envs=2, num_threads=1)
        >>> td = env.rollout(2)
        >>> td["next", "observation"].shape, td["next", "info", "reward_open"].shape
        (torch.Size([2, 2, 210]), torch.Size([2, 2]))
    """

    scene_file = "bimanual_scissors.xml"
    object_sites = ("handle_r", "handle_l")
    reward_term_names = SCISSORS_TERMS

    def __init__(
        self,
        num_envs: int,
        gate: float = 0.7,
        open_scale: float = 5.0,
        success_q: float = -0.3,
        fail_up: float = -0.5,
        fail_finger_dist: float = 1.75,
        max_episode_steps: int = 150,
        **kwargs: Any,
    ):
        self.gate, self.open_scale, self.success_q = float(gate), float(open_scale), float(success_q)
        self.fail_up, self.fail_finger_dist = float(fail_up), float(fail_finger_dist)
        super().__init__(num_envs, max_episode_steps=max_episode_steps, **kwargs)

    def _index_model(self, model) -> None:
        super()._index_model(model)
        self.free_qpos = int(model.joint("scissors_free").qposadr[0])
        self.free_qvel = int(model.joint("scissors_free").dofadr[0])
        self.hinge_qpos = int(model.joint("hinge").qposadr[0])

    def reset_object(self, qpos: np.ndarray, rng: np.random.Generator) -> None:
        n = len(qpos)
        qpos[:, self.free_qpos : self.free_qpos + 2] += rng.uniform(-1, 1, (n, 2)) * self.reset_position_noise

    def q(self) -> torch.Tensor:
        """The scissors joint in Bi-DexHands' convention, θ − 0.59 [N] (rad)."""
        return self.qpos[:, self.hinge_qpos] + CLOSED_Q

    def finger_distances(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(d_R, d_L) [N] each: Σ fingertip distances of each hand to its handle (m)."""
        right = finger_distance(self.site("handle_r"), self.tips(0))
        return right, finger_distance(self.site("handle_l"), self.tips(1))

    def object_observation(self) -> torch.Tensor:
        p, v = self.free_qpos, self.free_qvel
        return torch.cat(
            [
                self.qpos[:, p : p + 7],
                self.qvel[:, v : v + 3],
                0.2 * self.qvel[:, v + 3 : v + 6],  # Bi-DexHands' vel_obs_scale on the angular velocity
                self.site("handle_r"),
                self.site("handle_l"),
                self.q().unsqueeze(-1),
            ],
            dim=-1,
        )

    def reward_terms(self) -> dict[str, torch.Tensor]:
        return scissors_terms(*self.finger_distances(), self.q(), self.gate, self.open_scale)

    def total_reward(self, terms: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return scissors_native_reward(*self.finger_distances(), self.q(), self.gate)  # the native formula

    def success(self) -> torch.Tensor:
        """Bi-DexHands' success flag [N] bool: q > −0.3."""
        return self.q() > self.success_q

    def terminated(self) -> torch.Tensor:
        right, left = self.finger_distances()
        up = self.reward_terms()["open"]
        return (up < self.fail_up) | (right >= self.fail_finger_dist) | (left >= self.fail_finger_dist)


def make_shadow_hand_scissors(task: ScissorsSettings, num_envs: int, seed: int = 0, device: str = "cpu") -> EnvBase:
    """Task builder (registry signature): ``ShadowHandScissorsEnv`` + ``RewardComponents``."""
    keys = ("gate", "open_scale", "success_q", "fail_up", "fail_finger_dist")
    env = ShadowHandScissorsEnv(num_envs, seed=seed, device=device, **bimanual_kwargs(task, keys))
    return with_reward_components(env, task.components)
