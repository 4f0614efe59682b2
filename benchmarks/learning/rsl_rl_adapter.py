"""Our batched TorchRL task env as rsl-rl-lib's ``VecEnv`` (the interface of rsl-rl-lib 5.x, ``rsl_rl/env/vec_env.py``).

rsl_rl's runner steps a GPU-style vectorised env that resets finished environments itself and returns
the observation after the reset; ``step_and_maybe_reset`` of TorchRL's ``EnvBase`` gives exactly that.
Observations go in the ``"policy"`` group of a TensorDict (rsl_rl's default observation set for actor
and critic), rewards are the task's native reward ``("next", "reward", "total")``, ``dones`` mark ended
episodes (terminated or truncated) and ``extras["time_outs"]`` the truncated ones, on which rsl_rl
bootstraps (``r += γ V(s)``), as legged_gym reports them.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence

import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict
from torchrl.envs import EnvBase

from torchrl_ahrs.envs.common.mirror import SignedPermutation
from torchrl_ahrs.evaluation.render import base_env


class StopTraining(Exception):
    """Raised by :meth:`RslRlVecEnv.step` when ``should_stop()`` says so (the run's budget is spent)."""


class RslRlVecEnv(VecEnv):
    """rsl_rl ``VecEnv`` over a TorchRL env of batch size ``[N]`` from :func:`torchrl_ahrs.envs.registry.make_env`.

    Args:
        env: the batched env; writes ``"observation"`` ``[N, O]``, ``("next", "reward", "total")`` and
            ``("next", "episode_reward", "total")`` ``[N, 1]``, ``done``/``terminated``/``truncated`` ``[N, 1]``.
        steps_per_rollout: the runner's ``num_steps_per_env``; ``on_rollout`` is called after every that many steps.
        on_rollout: ``(wall_s, frames, returns)`` with the native returns of the episodes that ended in the rollout.
        clock: wall seconds for ``on_rollout``.
        should_stop: checked before each step; True raises :class:`StopTraining`.

    ``step(actions [N, A])`` returns ``(TensorDict {"policy": [N, O]}, rewards [N], dones [N] long,
    {"time_outs": [N] float})``.

    Example:
        >>> from torchrl_ahrs.envs.registry import make_env
        >>> from torchrl_ahrs.app.shared.settings import load_task_settings
        >>> vec = RslRlVecEnv(make_env(load_task_settings("point_reach"), 2, components=["total"]), steps_per_rollout=4)
        >>> obs, rewards, dones, extras = vec.step(torch.zeros(2, vec.num_actions))
        >>> obs["policy"].shape, rewards.shape, dones.dtype, extras["time_outs"].shape
        (torch.Size([2, 6]), torch.Size([2]), torch.int64, torch.Size([2]))
    """

    def __init__(
        self,
        env: EnvBase,
        steps_per_rollout: int,
        on_rollout: Callable[[float, int, Sequence[float]], None] | None = None,
        clock: Callable[[], float] = time.perf_counter,
        should_stop: Callable[[], bool] | None = None,
    ):
        if len(env.batch_size) != 1:
            raise ValueError(f"RslRlVecEnv needs an env of batch size [N], got {list(env.batch_size)}")
        self.env = env
        self.num_envs = env.batch_size[0]
        self.num_actions = env.action_spec.shape[-1]
        self.max_episode_length = int(getattr(base_env(env), "max_episode_steps", 1000))
        self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.long)
        self.device = "cpu"
        self.cfg: dict = {}
        self.steps_per_rollout = steps_per_rollout
        self.on_rollout, self.clock, self.should_stop = on_rollout, clock, should_stop
        self.steps = 0
        self._finished: list[float] = []
        self._td = env.reset()

    def get_observations(self) -> TensorDict:
        """The current observations ``{"policy": [N, O] float32}``."""
        return TensorDict(policy=self._td.get("observation").to(torch.float32), batch_size=[self.num_envs])

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        if self.should_stop is not None and self.should_stop():
            raise StopTraining
        stepped, self._td = self.env.step_and_maybe_reset(self._td.set("action", actions.detach().to(torch.float32)))
        n = self.num_envs
        reward = stepped.get(("next", "reward", "total")).reshape(n).to(torch.float32)
        done = stepped.get(("next", "done")).reshape(n)
        terminated = stepped.get(("next", "terminated")).reshape(n)
        time_outs = stepped.get(("next", "truncated")).reshape(n) & ~terminated  # bootstrap only on truncation
        self._finished += stepped.get(("next", "episode_reward", "total")).reshape(n)[done].tolist()
        self.episode_length_buf = torch.where(done, 0, self.episode_length_buf + 1)
        self.steps += 1
        if self.on_rollout is not None and self.steps % self.steps_per_rollout == 0:
            self.on_rollout(self.clock(), self.steps * n, self._finished)
            self._finished = []
        return self.get_observations(), reward, done.long(), {"time_outs": time_outs.to(torch.float32)}


def mirror_augmentation(maps: Mapping[str, SignedPermutation]) -> Callable[..., tuple]:
    """rsl-rl-lib's ``data_augmentation_func`` (``algorithm.symmetry_cfg``) from a task's mirror maps
    (:func:`torchrl_ahrs.envs.registry.task_mirror`): observations ``{"policy": [B, O]}`` and actions ``[B, A]``, each
    followed by its mirror image ``[2B]``, as our ``ppo.mirror`` trains every minibatch; ``None`` stays ``None``.

    Example:
        >>> flip = SignedPermutation((1, 0), (-1.0, -1.0))  # swap and negate: its own inverse
        >>> augment = mirror_augmentation({"observation": flip, "action": flip})
        >>> obs, actions = augment(env=None, obs=TensorDict(policy=torch.tensor([[1.0, 2.0]]), batch_size=[1]),
        ...                        actions=torch.tensor([[3.0, 4.0]]))
        >>> obs["policy"].tolist(), actions.tolist()
        ([[1.0, 2.0], [-2.0, -1.0]], [[3.0, 4.0], [-4.0, -3.0]])
    """
    observation, action = maps["observation"], maps["action"]

    def augment(env=None, obs: TensorDict | None = None, actions: torch.Tensor | None = None) -> tuple:
        if obs is not None:
            obs = torch.cat([obs, obs.apply(observation)], 0)  # every observation group of the policy: [2B, O]
        if actions is not None:
            actions = torch.cat([actions, action(actions)], 0)
        return obs, actions

    return augment
