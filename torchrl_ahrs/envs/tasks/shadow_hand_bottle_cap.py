"""``task=shadow_hand_bottle_cap``: Bi-DexHands' ShadowHandBottleCap reward on MuJoCo (appendix C of the paper).

Two Shadow hands (EnvPool's assets, see :mod:`~torchrl_ahrs.envs.tasks.bimanual`) face each other across a
bottle standing on a table (``assets/bimanual_bottle_cap.xml``): the left hand's palm is against the
bottle, the right hand hovers over the cap. The cap turns on a hinge and rises on a slide, coupled by a
thread (0.01 m per radian). Bi-DexHands' reward (``compute_hand_reward`` in its
``shadow_hand_bottle_cap.py``), with d_R the sum of the right hand's five fingertip distances to the cap's
seat on the bottle, d_L the distance of the left hand's palm point to the bottle, and u the cap's lift::

    up     = 30 u   if d_R <= 0.3  else 0
    reward = 2 − d_R − d_L + up

Bi-DexHands measures u = ‖cap link − bottle root‖, the two coinciding when the cap is on; here the cap
body's displacement from its seat, u = ‖cap − seat‖, is the same quantity. The components split the sum
exactly (the constant 2 shared by the two hands)::

    right_reach = 1 − d_R        left_reach = 1 − d_L        lift = up

Bi-DexHands computes an action penalty but does not add it and gives no success bonus; success (u > 0.03 m)
is a metric. Its resets become terminations: cap seat below 0.5 m (the bottle fell), the right palm point
0.5 m or more from the cap, the left palm point 0.2 m or more from the bottle; its 125 steps, the time limit.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from torchrl.envs import EnvBase

from torchrl_ahrs.envs.backends.mujoco_base import with_reward_components
from torchrl_ahrs.envs.settings import BottleCapSettings
from torchrl_ahrs.envs.tasks.bimanual import BimanualShadowEnv, bimanual_kwargs, finger_distance

BOTTLE_CAP_TERMS = ("right_reach", "left_reach", "lift")


def bottle_cap_native_reward(
    right_finger_dist: torch.Tensor, left_hand_dist: torch.Tensor, cap_lift: torch.Tensor, gate: float = 0.3
) -> torch.Tensor:
    """Bi-DexHands' ShadowHandBottleCap reward [N], written as in its source (the oracle of the components).

    Args:
        right_finger_dist: Σ of the right fingertips' distances to the cap seat [N] (m).
        left_hand_dist: left palm point to bottle distance [N] (m).
        cap_lift: ‖cap − seat‖ [N] (m).
    """
    up = torch.zeros_like(right_finger_dist)
    up = torch.where(right_finger_dist <= gate, cap_lift * 30, up)
    return 2.0 - right_finger_dist - left_hand_dist + up  # 2 − d_R − d_L + up


def bottle_cap_terms(
    right_finger_dist: torch.Tensor,
    left_hand_dist: torch.Tensor,
    cap_lift: torch.Tensor,
    gate: float = 0.3,
    lift_scale: float = 30.0,
) -> dict[str, torch.Tensor]:
    """Components ``{right_reach, left_reach, lift}`` [N] whose sum is :func:`bottle_cap_native_reward`.

    Example:
        >>> terms = bottle_cap_terms(torch.tensor([0.25]), torch.tensor([0.05]), torch.tensor([0.02]))
        >>> {k: round(v.item(), 3) for k, v in terms.items()}
        {'right_reach': 0.75, 'left_reach': 0.95, 'lift': 0.6}
    """
    at_cap = right_finger_dist <= gate  # the right fingers are around the cap
    return {
        "right_reach": 1.0 - right_finger_dist,  # 1 − d_R
        "left_reach": 1.0 - left_hand_dist,  # 1 − d_L
        "lift": torch.where(at_cap, lift_scale * cap_lift, torch.zeros_like(cap_lift)),  # 30 u
    }


class ShadowHandBottleCapEnv(BimanualShadowEnv):
    """Hold the bottle with the left hand and unscrew its cap with the right; actions [N, 52], obs [N, 213].

    Object observation [23]: bottle pose (7), linear velocity (3), angular velocity × 0.2 (3), bottle point,
    cap seat and cap positions (9), cap twist (1).

    Example:
        >>> env = ShadowHandBottleCapEnv(num_envs=2, num_threads=1)
        >>> td = env.rollout(2)
        >>> td["next", "observation"].shape, td["next", "info", "reward_lift"].shape
        (torch.Size([2, 2, 213]), torch.Size([2, 2]))
    """

    scene_file = "bimanual_bottle_cap.xml"
    hand_poses = (((-1.0, 0.0, 0.0), (0.0, 0.0, -1.0)), ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)))  # facing
    object_sites = ("bottle", "cap_rest", "cap_link")
    reward_term_names = BOTTLE_CAP_TERMS

    def __init__(
        self,
        num_envs: int,
        gate: float = 0.3,
        lift_scale: float = 30.0,
        success_lift: float = 0.03,
        fail_cap_height: float = 0.5,
        fail_right_dist: float = 0.5,
        fail_left_dist: float = 0.2,
        max_episode_steps: int = 125,
        **kwargs: Any,
    ):
        self.gate, self.lift_scale, self.success_lift = float(gate), float(lift_scale), float(success_lift)
        self.fail_cap_height, self.fail_right_dist = float(fail_cap_height), float(fail_right_dist)
        self.fail_left_dist = float(fail_left_dist)
        super().__init__(num_envs, max_episode_steps=max_episode_steps, **kwargs)

    def _index_model(self, model) -> None:
        super()._index_model(model)
        self.free_qpos = int(model.joint("bottle_free").qposadr[0])
        self.free_qvel = int(model.joint("bottle_free").dofadr[0])
        self.twist_qpos = int(model.joint("cap_twist").qposadr[0])

    def reset_object(self, qpos: np.ndarray, rng: np.random.Generator) -> None:
        n = len(qpos)
        qpos[:, self.free_qpos : self.free_qpos + 2] += rng.uniform(-1, 1, (n, 2)) * self.reset_position_noise

    def cap_lift(self) -> torch.Tensor:
        """u = ‖cap − seat‖ [N] (m)."""
        return (self.site("cap_link") - self.site("cap_rest")).norm(dim=-1)

    def distances(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(d_R, d_L) [N]: right fingertips to the cap seat (Σ, m), left palm point to the bottle (m)."""
        right = finger_distance(self.site("cap_rest"), self.tips(0))
        return right, (self.site("bottle") - self.grasp_point(1)).norm(dim=-1)

    def object_observation(self) -> torch.Tensor:
        p, v = self.free_qpos, self.free_qvel
        return torch.cat(
            [
                self.qpos[:, p : p + 7],
                self.qvel[:, v : v + 3],
                0.2 * self.qvel[:, v + 3 : v + 6],  # Bi-DexHands' vel_obs_scale on the angular velocity
                self.site("bottle"),
                self.site("cap_rest"),
                self.site("cap_link"),
                self.qpos[:, self.twist_qpos : self.twist_qpos + 1],
            ],
            dim=-1,
        )

    def reward_terms(self) -> dict[str, torch.Tensor]:
        return bottle_cap_terms(*self.distances(), self.cap_lift(), self.gate, self.lift_scale)

    def total_reward(self, terms: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return bottle_cap_native_reward(*self.distances(), self.cap_lift(), self.gate)  # the native formula

    def success(self) -> torch.Tensor:
        """Bi-DexHands' success flag [N] bool: the cap rose more than 0.03 m."""
        return self.cap_lift() > self.success_lift

    def terminated(self) -> torch.Tensor:
        right_palm = (self.site("cap_rest") - self.grasp_point(0)).norm(dim=-1)
        _, left = self.distances()
        fell = self.site("cap_rest")[:, 2] <= self.fail_cap_height
        return fell | (right_palm >= self.fail_right_dist) | (left >= self.fail_left_dist)


def make_shadow_hand_bottle_cap(task: BottleCapSettings, num_envs: int, seed: int = 0, device: str = "cpu") -> EnvBase:
    """Task builder (registry signature): ``ShadowHandBottleCapEnv`` + ``RewardComponents``."""
    keys = ("gate", "lift_scale", "success_lift", "fail_cap_height", "fail_right_dist", "fail_left_dist")
    env = ShadowHandBottleCapEnv(num_envs, seed=seed, device=device, **bimanual_kwargs(task, keys))
    return with_reward_components(env, task.components)
