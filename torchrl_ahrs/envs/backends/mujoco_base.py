"""Batched MuJoCo environment: N simulations of one model stepped by a thread pool, read as [N, ...] arrays.

This module is the contract for robot authors. A task subclasses :class:`BatchedMujocoEnv`, loads one
``mujoco.MjModel`` and fills in a few small hooks; the base owns the ``MjData`` objects, stepping,
partial resets, seeding, time limits and every TorchRL spec.

How a control step runs (``_step``)::

    ctrl[N, nu]  = apply_action(action[N, A])                 # main thread, vectorised
    workers      : for each env they take: data.ctrl = ctrl[i]; mj_step(model, data, nstep=decimation)
                   (or, with ``substep_control``, one mj_step at a time with fresh PD torques)
                   then copy ``state_fields`` of that env into the stacked arrays
    after_physics_step()                                       # optional bookkeeping (e.g. previous potential)
    terms        = reward_terms()        -> {name: Tensor[N]}  # vectorised over N
    reward[N, 1] = total_reward(terms)   (default Σ terms)
    terminated   = terminated()          -> Tensor[N] bool
    truncated    = episode_steps >= max_episode_steps
    obs          = observation()         -> Tensor[N, obs_dim]

``mj_step`` releases the GIL, so ``num_threads`` plain threads (the main thread is one of them) step in
parallel, each taking the next unstepped env from a shared counter (with ``per_substep_control`` each owns
a contiguous slice instead). No reward or observation is computed per environment: hooks read the
stacked state. Every hook except ``substep_control`` runs on the main thread.

Stacked state (read-only for hooks, refreshed after every step and reset)::

    self.state[name]      numpy float64 [N, *field_shape] for name in state_fields (always qpos, qvel)
    self.state_t[name]    torch views of the same memory (float64, CPU) — no copies
    self.qpos, self.qvel  torch views [N, nq], [N, nv]
    self.action           the last policy action clipped to [-1, 1], torch float32 [N, A] (zeros after reset)
    self.ctrl             numpy float64 [N, nu], the control written to MjData
    self.episode_steps    torch int64 [N], control steps since each env's last reset
    self.control_dt       decimation * model.opt.timestep (seconds per control step)

``state_fields`` names ``MjData`` attributes (``"xpos"``, ``"xquat"``, ``"sensordata"``, ``"cfrc_ext"``,
``"qacc"``, ``"actuator_force"``, ...). After ``mj_step`` the derived quantities (xpos, sensordata,
cfrc_ext, ...) belong to the state before the last integration substep, as in gymnasium and EnvPool;
read positions and velocities of free-joint bodies from qpos/qvel when that lag matters. Asking for
``cacc``, ``cfrc_int`` or ``cfrc_ext`` makes the base call ``mj_rnePostConstraint`` after stepping
(``mj_step`` leaves them stale unless a sensor needs them).

Hooks (override in the subclass):

* ``reset_state(env_ids, rng) -> (qpos [n, nq], qvel [n, nv])`` — initial state of the envs being reset,
  sampled vectorised from the one seeded ``numpy.random.Generator``; required.
* ``init_buffers()`` — allocate per-env tensors [N, ...]; called once in ``__init__`` before the first reset
  (set task attributes the hooks need *before* calling ``super().__init__``).
* ``on_reset(env_ids)`` — clear per-env buffers (previous potential, last action); state is fresh.
* ``apply_action(action [N, A] float32) -> ctrl [N, nu]`` float64, numpy or torch on the action's device (MJX
  then stays on its device) — default: clip to [-1, 1] (ctrlrange scaling: ``gear``). Once per control step.
* ``substep_control(env_slice, qpos [n, nq], qvel [n, nv]) -> ctrl numpy [n, nu]`` — set
  ``per_substep_control = True`` to recompute ctrl before every physics substep (PD torques). Runs in the
  worker threads on disjoint slices: read ``self.ctrl[env_slice]`` (the targets), write nothing shared.
  Alternatively, build PD into the MJCF with ``<position kp=.. kv=..>`` actuators and skip this hook.
* ``after_physics_step()`` — optional bookkeeping between physics and rewards.
* ``episode_state`` (class attribute) — names of the per-env attributes a task carries from one step to
  the next (targets, commands, previous potentials, history buffers): they are part of the env's
  snapshot, so leave none out (``tests/envs/test_env_snapshot.py`` checks every task).
* ``observation() -> Tensor [N, obs_dim]`` (cast to float32 by the base); required.
* ``reward_terms() -> dict[str, Tensor [N]]``; required. Names are fixed by ``reward_term_names``.
* ``total_reward(terms) -> Tensor [N]`` — default Σ terms (override for the task's own formula).
* ``terminated() -> Tensor [N] bool`` — default never.

TensorDict layout written per step (batch size [N])::

    "observation"                 float32 [N, obs_dim]
    ("info", "reward_<term>")     float32 [N]        one per reward term
    "reward"                      float32 [N, 1]     total_reward(terms)
    "done", "terminated", "truncated"   bool [N, 1]

Snapshot (exact resume): ``state_dict()`` holds, under ``_extra_state``, everything the next step
depends on — each ``MjData``'s full integration state (``mjSTATE_INTEGRATION``: time, qpos, qvel, act,
warm start, ctrl, applied forces, mocap, ...), the stacked ``state_fields``, ``ctrl``, ``action``,
``episode_steps``, the reset-noise generator's state and the task's ``episode_state`` attributes.
``load_state_dict`` puts them back, so an env built anew continues the episodes bit for bit.

Each env resets on its own termination or time limit through TorchRL's ``"_reset"`` mask; the others
keep their MjData untouched. A task builder then appends
``RewardComponents(components, term_keys={c: ("info", f"reward_{c}")})`` (see :func:`component_term_keys`).

Example:
    >>> import numpy as np, mujoco, torch
    >>> class Slider(BatchedMujocoEnv):
    ...     reward_term_names = ("position",)
    ...     def reset_state(self, env_ids, rng):
    ...         return rng.uniform(-0.1, 0.1, (len(env_ids), 1)), np.zeros((len(env_ids), 1))
    ...     def observation(self):
    ...         return torch.cat([self.qpos, self.qvel], -1)
    ...     def reward_terms(self):
    ...         return {"position": -self.qpos[:, 0].abs()}
    >>> xml = '''<mujoco><worldbody><body><joint name="x" type="slide" axis="1 0 0"/>
    ...   <geom type="sphere" size="0.1" mass="1"/></body></worldbody>
    ...   <actuator><motor joint="x" gear="1"/></actuator></mujoco>'''
    >>> env = Slider(mujoco.MjModel.from_xml_string(xml), num_envs=4, decimation=2, max_episode_steps=10)
    >>> env.rollout(3)["next", "info", "reward_position"].shape
    torch.Size([4, 3])
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import mujoco
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase, TransformedEnv

from torchrl_ahrs.envs.common.snapshot import mujoco_snapshot, restore_mujoco_snapshot
from torchrl_ahrs.rewards.components import RewardComponents

REWARD_TERM_PREFIX = "reward_"


def component_term_keys(components: Sequence[str]) -> dict[str, tuple[str, str]]:
    """``{c: ("info", "reward_<c>")}`` for every component except ``"total"`` (RewardComponents' term_keys)."""
    return {name: ("info", REWARD_TERM_PREFIX + name) for name in components if name != "total"}


def with_reward_components(env: EnvBase, components: Sequence[str]) -> TransformedEnv:
    """``env`` with its ``("info", "reward_<c>")`` terms as reward leaves: what every task builder returns."""
    components = list(components)
    return TransformedEnv(env, RewardComponents(components, term_keys=component_term_keys(components)))


class BatchedMujocoEnv(EnvBase):
    """N simulations of one MuJoCo model as a TorchRL env with batch size [N]; see the module docstring.

    Args:
        model: the compiled ``mujoco.MjModel`` shared by every simulation.
        num_envs: batch size N.
        decimation: physics substeps per control step (control dt = decimation · model.opt.timestep).
        max_episode_steps: control steps before an env is truncated and reset.
        num_threads: stepping threads (default: ``min(os.cpu_count(), N)``); 1 steps in the main thread.
        seed: seed of the one ``numpy.random.Generator`` used by ``reset_state``.
        device: torch device of the returned tensors (the physics runs on the CPU).
    """

    reward_term_names: tuple[str, ...] = ()
    state_fields: tuple[str, ...] = ()
    per_substep_control: bool = False
    episode_state: tuple[str, ...] = ()

    def __init__(
        self,
        model: mujoco.MjModel,
        num_envs: int,
        decimation: int = 1,
        max_episode_steps: int = 1000,
        num_threads: int | None = None,
        seed: int = 0,
        device: str | torch.device = "cpu",
    ):
        if num_envs < 1 or decimation < 1 or max_episode_steps < 1:
            raise ValueError("num_envs, decimation and max_episode_steps must be positive")
        if not self.reward_term_names:
            raise ValueError(f"{type(self).__name__} declares no reward_term_names")
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.model = model
        self.num_envs = num_envs
        self.decimation = int(decimation)
        self.max_episode_steps = int(max_episode_steps)
        self.control_dt = self.decimation * float(model.opt.timestep)
        self.datas = [mujoco.MjData(model) for _ in range(num_envs)]
        for data in self.datas:
            mujoco.mj_forward(model, data)
        fields = ("qpos", "qvel", *[f for f in self.state_fields if f not in ("qpos", "qvel")])
        self._fields = fields
        # mj_step leaves cacc / cfrc_int / cfrc_ext stale unless a sensor needs them (gymnasium calls this too)
        self._post_constraint = any(name in ("cacc", "cfrc_int", "cfrc_ext") for name in fields)
        self.state = {
            name: np.zeros((num_envs, *np.shape(getattr(self.datas[0], name))), np.float64) for name in fields
        }
        self.state_t = {name: torch.from_numpy(array) for name, array in self.state.items()}
        self.qpos, self.qvel = self.state_t["qpos"], self.state_t["qvel"]
        self.ctrl = np.zeros((num_envs, model.nu), np.float64)
        self.action = torch.zeros(num_envs, self.action_dim)
        self.episode_steps = torch.zeros(num_envs, dtype=torch.int64)
        # contiguous slices, one per thread; the main thread takes the last one itself
        threads = max(1, min(num_threads or os.cpu_count() or 1, num_envs))
        bounds = np.linspace(0, num_envs, threads + 1).round().astype(int)
        self._slices = [slice(int(lo), int(hi)) for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)]
        self._pool = ThreadPoolExecutor(max_workers=threads - 1) if threads > 1 else None
        self.rng = np.random.default_rng(seed)
        self.init_buffers()
        self.reset_envs(np.arange(num_envs))
        self._make_specs()

    # ---------------------------------------------------------------- hooks
    @property
    def action_dim(self) -> int:
        """Policy action size A; default the number of actuators."""
        return self.model.nu

    def reset_state(self, env_ids: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Initial (qpos [n, nq], qvel [n, nv]) of the envs ``env_ids`` [n]."""
        raise NotImplementedError

    def init_buffers(self) -> None:
        """Allocates per-env buffers ([N, ...] tensors); called once before the first reset."""

    def on_reset(self, env_ids: np.ndarray) -> None:
        """Clears per-env buffers of the envs ``env_ids`` after their state was reset."""

    def apply_action(self, action: torch.Tensor) -> np.ndarray | torch.Tensor:
        """Maps the policy action [N, A] to MuJoCo ctrl [N, nu] (numpy or torch, float64); default: clip to [-1, 1]."""
        return action.clamp(-1.0, 1.0).double()

    def substep_control(self, env_slice: slice, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """Ctrl [n, nu] for the slice before each substep (only if ``per_substep_control``)."""
        raise NotImplementedError

    def after_physics_step(self) -> None:
        """Bookkeeping between physics and rewards (state arrays are fresh)."""

    def observation(self) -> torch.Tensor:
        """Policy input [N, obs_dim]."""
        raise NotImplementedError

    def reward_terms(self) -> dict[str, torch.Tensor]:
        """``{name: [N]}`` for every name in ``reward_term_names``."""
        raise NotImplementedError

    def total_reward(self, terms: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The task's native reward [N]; default Σ_k terms_k."""
        return torch.stack(list(terms.values()), dim=0).sum(0)

    def terminated(self) -> torch.Tensor:
        """Terminal-state flags [N] bool; default never."""
        return torch.zeros(self.num_envs, dtype=torch.bool, device=self.qpos.device)

    # ---------------------------------------------------------------- physics
    def _gather(self, env_slice: slice) -> None:
        """Copies ``state_fields`` of the envs in ``env_slice`` into the stacked arrays."""
        for name in self._fields:
            array = self.state[name]
            for i in range(env_slice.start, env_slice.stop):
                array[i] = getattr(self.datas[i], name)

    def _run_queue(self, next_env: Iterator[int]) -> None:
        """Steps envs taken one at a time from a shared counter (load-balances when a thread is preempted)."""
        model, datas, ctrl, decimation = self.model, self.datas, self.ctrl, self.decimation
        fields = [(name, self.state[name]) for name in self._fields]
        for i in next_env:  # itertools.count's next() is atomic under the GIL
            if i >= self.num_envs:
                return
            data = datas[i]
            data.ctrl[:] = ctrl[i]
            mujoco.mj_step(model, data, nstep=decimation)  # releases the GIL for all substeps
            if self._post_constraint:
                mujoco.mj_rnePostConstraint(model, data)
            for name, array in fields:
                array[i] = getattr(data, name)

    def _run_slice(self, env_slice: slice) -> None:
        """Steps a fixed slice one substep at a time, recomputing ctrl before each (per-substep control)."""
        model, datas = self.model, self.datas
        qpos, qvel = self.state["qpos"][env_slice], self.state["qvel"][env_slice]
        for _ in range(self.decimation):
            substep_ctrl = self.substep_control(env_slice, qpos, qvel)
            for j, i in enumerate(range(env_slice.start, env_slice.stop)):
                datas[i].ctrl[:] = substep_ctrl[j]
                mujoco.mj_step(model, datas[i])
                qpos[j] = datas[i].qpos
                qvel[j] = datas[i].qvel
        if self._post_constraint:
            for i in range(env_slice.start, env_slice.stop):
                mujoco.mj_rnePostConstraint(model, datas[i])
        self._gather(env_slice)

    def _write_ctrl(self, ctrl: np.ndarray | torch.Tensor) -> None:
        self.ctrl[:] = ctrl  # apply_action's ctrl, numpy for the worker threads (a CPU tensor converts in place)

    def _physics_step(self) -> None:
        """Advances every env by ``decimation`` substeps on the pool plus the main thread."""
        if self.per_substep_control:
            tasks: list[tuple[Callable[[Any], None], Any]] = [(self._run_slice, s) for s in self._slices]
        else:
            counter = itertools.count()
            tasks = [(self._run_queue, counter)] * len(self._slices)
        futures = [self._pool.submit(fn, arg) for fn, arg in tasks[:-1]] if self._pool else []
        tasks[-1][0](tasks[-1][1])
        for future in futures:
            future.result()

    # ---------------------------------------------------------------- TorchRL
    def _make_specs(self) -> None:
        n = self.num_envs
        obs_dim = int(self._observation_dim())
        info = Composite(
            {REWARD_TERM_PREFIX + name: Unbounded(shape=(n,), dtype=torch.float32) for name in self.reward_term_names},
            shape=(n,),
        )
        self.observation_spec = Composite(
            observation=Unbounded(shape=(n, obs_dim), dtype=torch.float32), info=info, shape=(n,)
        )
        self.action_spec = Bounded(-1.0, 1.0, shape=(n, self.action_dim), dtype=torch.float32)
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32)
        flags = ("done", "terminated", "truncated")
        self.done_spec = Composite({k: Categorical(2, shape=(n, 1), dtype=torch.bool) for k in flags}, shape=(n,))

    def _observation_dim(self) -> int:
        return self.observation().shape[-1]

    def _info(self, terms: Mapping[str, torch.Tensor]) -> TensorDict:
        missing = set(self.reward_term_names) - set(terms)
        if missing:
            raise KeyError(f"reward_terms() returned no {sorted(missing)}")
        return TensorDict(
            {REWARD_TERM_PREFIX + name: terms[name].to(torch.float32) for name in self.reward_term_names},
            batch_size=self.batch_size,
        )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        # rewards see the action the robot executed: Gaussian policies may sample outside the box
        self.action = tensordict.get("action").detach().to(self.qpos.device, torch.float32).clamp(-1.0, 1.0)
        self._write_ctrl(self.apply_action(self.action))
        self._physics_step()
        self.episode_steps += 1
        self.after_physics_step()
        terms = self.reward_terms()
        reward = self.total_reward(terms).to(torch.float32)
        terminated = self.terminated().reshape(-1, 1)
        truncated = (self.episode_steps >= self.max_episode_steps).reshape(-1, 1) & ~terminated
        out = TensorDict(
            {
                "observation": self.observation().to(torch.float32),
                "info": self._info(terms),
                "reward": reward.reshape(-1, 1),
                "done": terminated | truncated,
                "terminated": terminated,
                "truncated": truncated,
            },
            batch_size=self.batch_size,
        )
        return out.to(self.device) if self.device != torch.device("cpu") else out

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        reset_mask = None if tensordict is None else tensordict.get("_reset", None)
        if reset_mask is None:
            env_ids = np.arange(self.num_envs)
        else:
            env_ids = reset_mask.reshape(self.num_envs).cpu().numpy().nonzero()[0]
        if len(env_ids):
            self.reset_envs(env_ids)
        zeros = torch.zeros(self.num_envs, 1, dtype=torch.bool, device=self.qpos.device)  # the hooks' device
        zero_terms = {name: torch.zeros(self.num_envs, device=self.qpos.device) for name in self.reward_term_names}
        out = TensorDict(
            {
                "observation": self.observation().to(torch.float32),
                "info": self._info(zero_terms),
                "done": zeros.clone(),
                "terminated": zeros.clone(),
                "truncated": zeros.clone(),
            },
            batch_size=self.batch_size,
        )
        return out.to(self.device) if self.device != torch.device("cpu") else out

    def reset_envs(self, env_ids: np.ndarray) -> None:
        """Resets the envs ``env_ids`` [n] (sorted indices) to fresh initial states; others untouched."""
        qpos, qvel = self.reset_state(env_ids, self.rng)
        for j, i in enumerate(env_ids):
            data = self.datas[i]
            mujoco.mj_resetData(self.model, data)
            data.qpos[:] = qpos[j]
            data.qvel[:] = qvel[j]
            mujoco.mj_forward(self.model, data)
            if self._post_constraint:
                mujoco.mj_rnePostConstraint(self.model, data)
            for name in self._fields:
                self.state[name][i] = getattr(data, name)
        ids = torch.as_tensor(env_ids, dtype=torch.long)
        self.ctrl[env_ids] = 0.0
        self.action[ids] = 0.0
        self.episode_steps[ids] = 0
        self.on_reset(env_ids)

    # ---------------------------------------------------------------- snapshot
    def get_extra_state(self) -> dict:
        """Everything the next step depends on (see the module docstring); ``state_dict()`` carries it."""
        return mujoco_snapshot(self)

    def set_extra_state(self, state: dict) -> None:
        """Restores a :meth:`get_extra_state` snapshot of an env with the same model and ``num_envs``."""
        restore_mujoco_snapshot(self, state)

    def _set_seed(self, seed: int | None) -> None:
        self.rng = np.random.default_rng(seed)

    def close(self, *, raise_if_closed: bool = True) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        super().close(raise_if_closed=raise_if_closed)
