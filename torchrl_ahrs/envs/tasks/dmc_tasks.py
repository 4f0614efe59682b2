"""dm_control tasks (EnvPool's ports) with their multiplicative rewards split into additive components.

dm_control rewards are products of ``tolerance`` factors in [0, 1]; AHRS needs named terms that *sum*
to the reward. Each split below is exact (``sum(components) == native reward``):

* walker walk: ``r = stand * (1 + 5 move) / 6`` with ``stand = (3 standing + upright) / 4``::

      standing = 3 standing / 24,  upright = upright / 24,  move = 5 stand move / 6  (= r - stand / 6)

  ``standing`` (torso height) and ``upright`` come from the observation; ``move`` needs the walker's
  centre-of-mass velocity, which the observation lacks, so it is the remainder ``r - stand / 6``.
* quadruped run: ``r = upright * move``, written as the telescoping pair
  ``upright = upright`` and ``move = upright * (move - 1)`` (<= 0: the speed still missing), both from
  the observation (``torso_upright``, ``torso_velocity``).
* cheetah run: ``r = clip(speed / 10, 0, 1)`` has a single factor; it is split by speed band,
  ``jog = min(r, f)`` and ``sprint = r - jog`` with ``f = jog_speed / 10``.

EnvPool steps these 8-60x faster than TorchRL's ``DMControlEnv`` on this machine (see the task YAMLs).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import cast

import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase, TransformedEnv

from torchrl_ahrs.envs.backends.envpool import EnvPoolEnv
from torchrl_ahrs.envs.settings import CheetahRunSettings, DmcSettings
from torchrl_ahrs.envs.tasks.envpool_tasks import envpool_make_kwargs
from torchrl_ahrs.rewards.components import RewardComponents

# dm_control.suite constants (walker.py, quadruped.py, cheetah.py)
WALKER_STAND_HEIGHT = 1.2
WALKER_WALK_SPEED = 1.0
QUADRUPED_RUN_SPEED = 5.0
CHEETAH_RUN_SPEED = 10.0


def tolerance_gaussian_below(x: torch.Tensor, lower: float, margin: float, value_at_margin: float = 0.1):
    """dm_control ``tolerance(x, bounds=(lower, inf), margin, sigmoid="gaussian")``, [*B] → [*B]."""
    distance = (lower - x).clamp_min(0.0) / margin  # 0 inside the bound, in margins below it
    scale = math.sqrt(-2.0 * math.log(value_at_margin))  # so that value(1) = value_at_margin
    return torch.exp(-0.5 * (distance * scale).square())  # exp(-(d s)^2 / 2)


def tolerance_linear_below(x: torch.Tensor, lower: float, margin: float, value_at_margin: float = 0.0):
    """dm_control ``tolerance(x, bounds=(lower, inf), margin, sigmoid="linear")``, [*B] → [*B]."""
    distance = (lower - x).clamp_min(0.0) / margin
    return (1.0 - distance * (1.0 - value_at_margin)).clamp_min(0.0)  # max(0, 1 - d (1 - v_margin))


def walker_walk_terms(height: torch.Tensor, torso_upright: torch.Tensor, reward: torch.Tensor):
    """Walker walk components [*B] from torso height, torso zz and the native reward (all [*B])."""
    standing = tolerance_gaussian_below(height, WALKER_STAND_HEIGHT, margin=WALKER_STAND_HEIGHT / 2)
    upright = (1.0 + torso_upright) / 2.0  # zz in [-1, 1] -> [0, 1]
    stand = (3.0 * standing + upright) / 4.0
    return {
        "standing": 3.0 * standing / 24.0,  # (3/4 standing) * 1/6
        "upright": upright / 24.0,  # (1/4 upright) * 1/6
        "move": reward - stand / 6.0,  # stand * 5 move / 6: the remainder
    }


def quadruped_run_terms(torso_upright: torch.Tensor, forward_velocity: torch.Tensor):
    """Quadruped run components [*B] from torso zz and forward torso velocity (both [*B])."""
    upright = tolerance_linear_below(torso_upright, 1.0, margin=2.0)  # (1 + zz) / 2
    move = tolerance_linear_below(forward_velocity, QUADRUPED_RUN_SPEED, QUADRUPED_RUN_SPEED, value_at_margin=0.5)
    return {"upright": upright, "move": upright * (move - 1.0)}  # upright + upright (move - 1) = upright move


def cheetah_run_terms(reward: torch.Tensor, jog_speed: float = 5.0):
    """Cheetah run components [*B]: the native reward split at ``jog_speed`` (m/s)."""
    jog = reward.clamp(max=jog_speed / CHEETAH_RUN_SPEED)  # min(r, f)
    return {"jog": jog, "sprint": reward - jog}  # r - min(r, f)


def _walker(next_td: TensorDictBase, task: DmcSettings):
    orientations = next_td.get("orientations")  # [N, 14]: (xx, xz) per body, torso first
    # planar walker: the torso rotates about y, so its zz equals its xx
    return walker_walk_terms(next_td.get("height"), orientations[..., 0], next_td.get("reward").squeeze(-1))


def _quadruped(next_td: TensorDictBase, task: DmcSettings):
    return quadruped_run_terms(next_td.get("torso_upright"), next_td.get("torso_velocity")[..., 0])


def _cheetah(next_td: TensorDictBase, task: DmcSettings):
    jog_speed = cast(CheetahRunSettings, task).jog_speed  # the registry gives dmc_cheetah_run this record
    return cheetah_run_terms(next_td.get("reward").squeeze(-1), float(jog_speed))


_TERMS: dict[str, Callable[[TensorDictBase, DmcSettings], dict[str, torch.Tensor]]] = {
    "WalkerWalk-v1": _walker,
    "QuadrupedRun-v1": _quadruped,
    "CheetahRun-v1": _cheetah,
}


def make_dmc_task(task: DmcSettings, num_envs: int, seed: int, device: str) -> EnvBase:
    """EnvPool dm_control task whose components sum exactly to the native reward.

    Example:
        >>> from torchrl_ahrs.app.shared.settings import load_task_settings
        >>> env = make_dmc_task(load_task_settings("dmc_quadruped_run"), num_envs=2, seed=0, device="cpu")
        >>> sorted(env.rollout(2)["next", "reward"].keys())
        ['move', 'total', 'upright']
    """
    env_id = task.env_id
    if env_id not in _TERMS:
        raise KeyError(f"no reward split for {env_id!r}; known: {sorted(_TERMS)}")
    base = EnvPoolEnv(
        env_id,
        num_envs=num_envs,
        seed=seed,
        device=device,
        observation_keys=list(task.observation_keys),
        keep_observation_parts=True,  # the reward split reads single parts (height, torso_upright, ...)
        num_threads=int(task.num_threads or 0),  # null from an override means EnvPool's default, as 0 does
        **envpool_make_kwargs(task),
    )
    terms = _TERMS[env_id]
    return TransformedEnv(
        base, RewardComponents(list(task.components), component_fn=lambda next_td: terms(next_td, task))
    )
