"""Reward terms from a gym-like env's ``info`` dict as reward components.

gymnasium's MuJoCo envs report their reward terms in ``info`` (``reward_forward``, ``reward_ctrl``, ...)
as Python or NumPy ``float64`` scalars, and nothing at reset. :class:`InfoRewardTerms` reads them as
float32 ``("info", term)`` ``[*B]`` entries (zeros where a term is absent, e.g. after a reset) with a
matching spec, and :func:`with_info_reward_terms` adds :class:`~torchrl_ahrs.rewards.RewardComponents`
on top, so ``check_env_specs`` passes without hand-written spec fixes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import TransformedEnv
from torchrl.envs.gym_like import BaseInfoDictReader, GymLikeEnv

from torchrl_ahrs.rewards.components import RewardComponents

INFO = "info"


class InfoRewardTerms(BaseInfoDictReader):
    """An info-dict reader writing each term as float32 ``("info", term)`` ``[*B]`` (0 when absent).

    Args:
        terms: the ``info`` keys to read, e.g. ``["reward_forward", "reward_ctrl"]``.
        batch_size: the env's batch size (``[]`` for one gymnasium env).

    Example:
        >>> from tensordict import TensorDict
        >>> reader = InfoRewardTerms(["reward_forward", "reward_ctrl"])
        >>> td = reader({"reward_forward": np.float64(0.5), "reward_ctrl": -0.25}, TensorDict())
        >>> td["info", "reward_forward"].dtype, td["info", "reward_ctrl"].item()
        (torch.float32, -0.25)
        >>> reader({}, TensorDict())["info", "reward_ctrl"].item()  # a reset reports no terms
        0.0
    """

    def __init__(self, terms: Sequence[str], batch_size: Sequence[int] = ()):
        self.terms = list(terms)
        self.batch_size = torch.Size(batch_size)
        leaves = {term: Unbounded(shape=self.batch_size, dtype=torch.float32) for term in self.terms}
        self._info_spec = Composite({INFO: Composite(leaves, shape=self.batch_size)}, shape=self.batch_size)

    def __call__(self, info_dict: Mapping[str, Any], tensordict: TensorDictBase) -> TensorDictBase:
        for term in self.terms:
            value = info_dict.get(term) if isinstance(info_dict, Mapping) else None
            if value is None:
                tensor = torch.zeros(self.batch_size)
            else:  # Python float or NumPy float64 -> float32 [*B]
                tensor = torch.as_tensor(np.asarray(value, dtype=np.float32)).reshape(self.batch_size)
            tensordict.set((INFO, term), tensor)
        return tensordict

    def reset(self) -> None:
        pass

    @property
    def info_spec(self) -> Composite:
        return self._info_spec


def with_info_reward_terms(
    env: GymLikeEnv,
    terms: Sequence[str] | Mapping[str, str],
    scales: Mapping[str, float] | None = None,
) -> TransformedEnv:
    """``env`` whose ``info`` reward terms are components ``("reward", c)``; ``env.reward_key`` is the total.

    Args:
        env: a gym-like TorchRL env (``GymEnv("HalfCheetah-v5")``, ...).
        terms: ``{component: info key}``, or info keys named ``reward_<component>``.
        scales: ``{component: factor}`` (e.g. to undo a weight gymnasium already applied).

    Example:
        >>> from torchrl.envs import GymEnv
        >>> from torchrl.envs.utils import check_env_specs
        >>> env = with_info_reward_terms(GymEnv("HalfCheetah-v5"), ["reward_forward", "reward_ctrl"])
        >>> check_env_specs(env)
        >>> env.reward_key, env.rollout(2)["next", "reward", "forward"].shape
        (('reward', 'total'), torch.Size([2, 1]))
    """
    if not isinstance(terms, Mapping):
        terms = {(t[len("reward_") :] if t.startswith("reward_") else t): t for t in terms}
    env.set_info_dict_reader(InfoRewardTerms(list(terms.values()), env.batch_size))
    term_keys = {component: (INFO, key) for component, key in terms.items()}
    return TransformedEnv(env, RewardComponents(list(terms), term_keys=term_keys, scales=scales))
