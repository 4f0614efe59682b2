"""A thin TorchRL ``EnvBase`` over an EnvPool 1.2.5 batch (gymnasium API).

Why our own wrapper: TorchRL's ``MultiThreadedEnv`` imports ``gym``/``treevalue`` (absent here), drops
``info`` and mis-keys dict observations. This one keeps the pieces AHRS needs:

* observations: a flat ``Box`` becomes ``"observation"``; a ``Dict`` space keeps each part under its
  own name and ``"observation"`` (the policy input) is the chosen part, or the concatenation of the
  chosen parts (``observation_keys``);
* ``info`` entries (by default every ``reward_*`` term plus ``elapsed_step``) at ``("info", name)``;
* EnvPool's *next-step autoreset* never leaks into a batch: an env that ended is reset explicitly
  (``reset(env_id=...)``) when TorchRL calls ``_reset`` with a ``"_reset"`` mask, so the "reset step"
  EnvPool would otherwise return on the next ``step`` (reward 0, action ignored) never happens.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

OBSERVATION = "observation"
INFO = "info"
ELAPSED_STEP = "elapsed_step"


def _to_tensor(array: np.ndarray, device: torch.device) -> torch.Tensor:
    """numpy → torch; float64 becomes float32 (one copy), float32/ints/bools are shared, not copied."""
    tensor = torch.from_numpy(array)
    if tensor.dtype == torch.float64:
        tensor = tensor.to(torch.float32)
    return tensor if device.type == "cpu" else tensor.to(device, non_blocking=True)


def _numpy_dtype_to_torch(dtype: np.dtype) -> torch.dtype:
    """Spec dtype of an EnvPool array once converted by :func:`_to_tensor`."""
    if dtype == np.float64:
        return torch.float32
    return torch.from_numpy(np.zeros((), dtype=dtype)).dtype


class EnvPoolEnv(EnvBase):
    """EnvPool batch of ``num_envs`` environments as one TorchRL env with batch size ``[num_envs]``.

    Step output (``next`` tensordict), shapes for ``N = num_envs``:

    * ``"observation"`` float32 ``[N, obs_dim]`` and, for dict spaces, every other part by name;
    * ``("info", name)`` ``[N, *shape]`` for each of ``info_keys`` (``reward_*`` float32 ``[N]``);
    * ``"reward"`` float32 ``[N, 1]``; ``"done"``, ``"terminated"``, ``"truncated"`` bool ``[N, 1]``.

    Args:
        task_id: EnvPool task, e.g. ``"Ant-v5"``.
        num_envs: batch size N.
        seed: EnvPool seed (env i is seeded from it); the same seed gives the same trajectories.
        device: where output tensors live (EnvPool steps on the CPU).
        observation_keys: for ``Dict`` spaces, the parts that form ``"observation"`` (concatenated in
            this order, scalars count as width 1); default: all parts. Parts not listed stay under their
            own key. Ignored for ``Box`` spaces.
        info_keys: ``info`` entries to expose under ``"info"``; default every ``reward_*`` term and
            ``elapsed_step``.
        keep_observation_parts: also keep the parts that form ``"observation"`` under their own names
            (e.g. a goal that a reward transform reads); a part named ``"observation"`` is not duplicated.
        num_threads: EnvPool worker threads (0 = EnvPool's default).
        **make_kwargs: forwarded to ``envpool.make`` (e.g. ``max_episode_steps``).

    Example:
        >>> env = EnvPoolEnv("Ant-v5", num_envs=4, seed=0)
        >>> rollout = env.rollout(5, break_when_any_done=False)
        >>> rollout["next", "observation"].shape, rollout["next", "info", "reward_forward"].shape
        (torch.Size([4, 5, 105]), torch.Size([4, 5]))
    """

    def __init__(
        self,
        task_id: str,
        num_envs: int,
        seed: int = 0,
        device: str | torch.device = "cpu",
        observation_keys: Sequence[str] | None = None,
        info_keys: Sequence[str] | None = None,
        keep_observation_parts: bool = False,
        num_threads: int = 0,
        **make_kwargs: Any,
    ):
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.task_id = task_id
        self.num_envs = num_envs
        self.num_threads = num_threads
        self.make_kwargs = dict(make_kwargs)
        self._seed = int(seed)
        self._pool, probe_info = self._make_pool(self._seed)
        self._all_ids = np.arange(num_envs, dtype=np.int32)
        # envs whose episode ended and that EnvPool would autoreset on their next step
        self._pending_reset = np.zeros(num_envs, dtype=bool)
        self._reseed_at_reset = False  # set_seed was called: make a new pool at the next full reset

        space = self._pool.observation_space
        self._dict_obs = hasattr(space, "spaces")
        if self._dict_obs:
            parts = list(space.spaces)
            self.policy_observation_keys = list(observation_keys) if observation_keys is not None else parts
            unknown = [k for k in self.policy_observation_keys if k not in parts]
            if unknown:
                raise KeyError(f"observation_keys {unknown} not in {task_id}'s observation parts {parts}")
            self.extra_observation_keys = [
                k
                for k in parts
                if k != OBSERVATION and (keep_observation_parts or k not in self.policy_observation_keys)
            ]
        else:
            self.policy_observation_keys, self.extra_observation_keys = [], []

        if info_keys is None:
            info_keys = [k for k in probe_info if k.startswith("reward_")] + [ELAPSED_STEP]
        missing = [k for k in info_keys if k not in probe_info]
        if missing:
            raise KeyError(f"info keys {missing} not reported by {task_id}; it reports {sorted(probe_info)}")
        self.info_keys = list(info_keys)
        self._make_specs(space, probe_info)

    # ------------------------------------------------------------------ construction
    def _make_pool(self, seed: int):
        """A new EnvPool batch and the ``info`` of its first reset.

        The first reset tells the info entries' shapes and dtypes; doing it for every new pool (also
        on :meth:`set_seed`) keeps "same seed, same trajectories" true however the pool was made.
        """
        import envpool

        pool = envpool.make(
            self.task_id,
            env_type="gymnasium",
            num_envs=self.num_envs,
            seed=seed,
            num_threads=self.num_threads,
            **self.make_kwargs,
        )
        _, info = pool.reset()
        return pool, info

    def _make_specs(self, space, probe_info: Mapping[str, np.ndarray]) -> None:
        n = self.num_envs
        obs_spec = Composite(shape=self.batch_size, device=self.device)
        if self._dict_obs:
            widths = [int(np.prod(space.spaces[k].shape)) for k in self.policy_observation_keys]
            obs_spec[OBSERVATION] = Unbounded((n, sum(widths)), dtype=torch.float32, device=self.device)
            for key in self.extra_observation_keys:
                shape = space.spaces[key].shape
                obs_spec[key] = Unbounded((n, *shape), dtype=torch.float32, device=self.device)
        else:
            obs_spec[OBSERVATION] = Unbounded((n, *space.shape), dtype=torch.float32, device=self.device)
        info_spec = Composite(shape=self.batch_size, device=self.device)
        for key in self.info_keys:
            value = np.asarray(probe_info[key])
            info_spec[key] = Unbounded(value.shape, dtype=_numpy_dtype_to_torch(value.dtype), device=self.device)
        obs_spec[INFO] = info_spec
        self.observation_spec = obs_spec

        action_space = self._pool.action_space
        if hasattr(action_space, "n"):
            self.action_spec = Categorical(int(action_space.n), shape=(n,), device=self.device)
        else:
            self.action_spec = Bounded(
                low=torch.as_tensor(action_space.low, dtype=torch.float32).expand(n, *action_space.shape),
                high=torch.as_tensor(action_space.high, dtype=torch.float32).expand(n, *action_space.shape),
                shape=(n, *action_space.shape),
                dtype=torch.float32,
                device=self.device,
            )
        self.reward_spec = Unbounded((n, 1), dtype=torch.float32, device=self.device)
        bool_leaf = Categorical(2, shape=(n, 1), dtype=torch.bool, device=self.device)
        self.done_spec = Composite(
            done=bool_leaf.clone(), terminated=bool_leaf.clone(), truncated=bool_leaf.clone(), shape=self.batch_size
        )

    # ------------------------------------------------------------------ conversion
    def _observation_entries(self, obs) -> dict[str, torch.Tensor]:
        """EnvPool observation (array or dict of arrays, leading dim = rows) → ``{key: tensor}``."""
        if not self._dict_obs:
            return {OBSERVATION: _to_tensor(obs, self.device)}
        rows = len(next(iter(obs.values())))
        chosen = [np.reshape(obs[k], (rows, -1)) for k in self.policy_observation_keys]
        # one part: no concatenation copy; several: np.concatenate writes float64 once, then cast
        policy_input = chosen[0] if len(chosen) == 1 else np.concatenate(chosen, axis=-1)
        entries = {OBSERVATION: _to_tensor(policy_input, self.device)}
        for key in self.extra_observation_keys:
            entries[key] = _to_tensor(np.asarray(obs[key]), self.device)
        return entries

    def _info_entries(self, info: Mapping[str, np.ndarray]) -> dict[str, torch.Tensor]:
        return {key: _to_tensor(np.asarray(info[key]), self.device) for key in self.info_keys}

    # ------------------------------------------------------------------ EnvBase API
    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self._pending_reset.any():
            raise RuntimeError(
                f"envs {np.flatnonzero(self._pending_reset).tolist()} ended and were not reset; call "
                "env.reset with a '_reset' mask (collectors and rollout do) before stepping again, "
                "otherwise EnvPool would return its autoreset step as a transition."
            )
        action = tensordict.get("action").detach()  # env.rollout(policy) outside no_grad hands a graph-carrying action
        action_np = action.numpy() if action.device.type == "cpu" else action.cpu().numpy()
        obs, reward, terminated, truncated, info = self._pool.step(action_np)
        env_id = info["env_id"]
        if not np.array_equal(env_id, self._all_ids):  # sync mode returns ids in order; guard anyway
            order = np.argsort(env_id)
            obs, reward, terminated, truncated = _take(obs, order), reward[order], terminated[order], truncated[order]
            info = {k: v[order] for k, v in info.items() if isinstance(v, np.ndarray)}
        done = np.logical_or(terminated, truncated)
        self._pending_reset = done.copy()  # own copy: the done tensor below shares `done`'s memory
        entries = self._observation_entries(obs)
        entries[INFO] = TensorDict(self._info_entries(info), batch_size=self.batch_size, device=self.device)
        entries["reward"] = _to_tensor(reward, self.device).to(torch.float32).unsqueeze(-1)
        entries["terminated"] = _to_tensor(terminated, self.device).unsqueeze(-1)
        entries["truncated"] = _to_tensor(truncated, self.device).unsqueeze(-1)
        entries["done"] = _to_tensor(done, self.device).unsqueeze(-1)
        return TensorDict(entries, batch_size=self.batch_size, device=self.device)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        reset_mask = None if tensordict is None else tensordict.get("_reset", None)
        if reset_mask is None or bool(reset_mask.all()):
            if self._reseed_at_reset and reset_mask is None:  # a fresh start, not episodes that all ended
                self._pool.close()
                self._pool, _ = self._make_pool(self._seed)
                self._reseed_at_reset = False
            obs, info = self._pool.reset()
            ids = self._all_ids
            out = self._full_reset_td(obs, info)
        else:
            ids = np.flatnonzero(reset_mask.reshape(self.num_envs).cpu().numpy()).astype(np.int32)
            if len(ids) == 0:
                raise RuntimeError("_reset called with an all-False '_reset' mask")
            obs, info = self._pool.reset(ids)
            out = self._partial_reset_td(ids, obs, info)
        self._pending_reset[ids] = False
        return out

    def _full_reset_td(self, obs, info) -> TensorDictBase:
        order = np.argsort(info["env_id"])
        if not np.array_equal(order, self._all_ids):
            obs, info = _take(obs, order), {k: v[order] for k, v in info.items() if isinstance(v, np.ndarray)}
        entries = self._observation_entries(obs)
        entries[INFO] = TensorDict(self._info_entries(info), batch_size=self.batch_size, device=self.device)
        return self._with_done_false(entries)

    def _partial_reset_td(self, ids: np.ndarray, obs, info) -> TensorDictBase:
        # Rows of envs that were not reset are ignored by TorchRL (it merges with ``where(~_reset)``),
        # so they are left at zero; rows of reset envs get the fresh initial observation.
        rows = torch.as_tensor(info["env_id"], dtype=torch.long)
        if getattr(self, "_zero_observation", None) is None:
            # spec.zero() rebuilds the whole tree each call; resets happen on most steps of a batch
            self._zero_observation = self.full_observation_spec.zero()
        out = self._zero_observation.clone()
        fresh = TensorDict(self._observation_entries(obs), batch_size=[len(ids)], device=self.device)
        fresh[INFO] = TensorDict(self._info_entries(info), batch_size=[len(ids)], device=self.device)
        out[rows] = fresh
        return self._with_done_false(out)

    def _with_done_false(self, entries) -> TensorDictBase:
        out = entries if isinstance(entries, TensorDictBase) else TensorDict(entries, batch_size=self.batch_size)
        false = torch.zeros((self.num_envs, 1), dtype=torch.bool, device=self.device)
        out.set("done", false)
        out.set("terminated", false.clone())
        out.set("truncated", false.clone())
        return out

    def _set_seed(self, seed: int | None) -> None:
        # EnvPool seeds its envs when the pool is made, so a new seed means a new pool. It is made at
        # the next reset without a "_reset" mask, not now: running episodes (e.g. a collector's, which
        # only resets ended envs, with a mask) stay valid and do not restart the seed's initial states
        # when all envs end together; "set_seed(s); reset()" equals a fresh env made with seed s.
        if seed is None:
            return
        self._seed = int(seed)
        self._reseed_at_reset = True

    def close(self, *, raise_if_closed: bool = True) -> None:
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.close()
            self._pool = None
        super().close(raise_if_closed=raise_if_closed)


def _take(obs, order: np.ndarray):
    """Rows ``order`` of an observation array or dict of arrays."""
    if isinstance(obs, Mapping):
        return {k: v[order] for k, v in obs.items()}
    return obs[order]
