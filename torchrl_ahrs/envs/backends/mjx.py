"""MJX backend: the same task hooks as :class:`~torchrl_ahrs.envs.backends.mujoco_base.BatchedMujocoEnv`, with
the N simulations stepped as one ``jax.jit(jax.vmap(mjx.step))`` batch (CPU-JAX in tests, GPU/TPU for real runs).

A task written for the threaded CPU base runs on MJX unchanged: :func:`mjx_variant` puts
:class:`MjxBatchedEnv` under the task class (``class QuadcopterMjx(QuadcopterEnv, MjxBatchedEnv)``), so
``reset_state``, ``apply_action``, ``observation``, ``reward_terms``, ``terminated`` ... are the task's own
torch code — no reward formula is written twice — and only the physics and the stacked state change.

How a control step runs (``_physics_step``, everything else is the CPU base's ``_step``)::

    ctrl[N, nu]  = apply_action(action[N, A])                          # the task's hook (torch → numpy)
    data         = jit(fori_loop(decimation, vmap(mjx.step)))(data, ctrl)   # one XLA call, N envs
    state[name]  = data.<name>  for name in ("qpos", "qvel", *state_fields)  # DLPack views → float64 torch

Partial resets write the reset rows of the batched ``mjx.Data`` with ``jnp.where`` on a mask [N] inside one
jitted function (fixed shapes: any subset of envs resets without a recompile). A reset row is the model's
reference data (``mjx.make_data``: time 0, ctrl 0, warm start 0, as ``mj_resetData``) with the task's
``reset_state`` qpos/qvel. Unlike the CPU base no ``mj_forward`` runs on reset, so derived fields listed in
``state_fields`` (``sensordata``, ``actuator_force``, ...) of a just-reset env hold the reference data's
values until its next step; the next ``mjx.step`` starts with a full forward pass, so the physics is the
same. ``observation`` / ``on_reset`` may therefore read only qpos and qvel right after a reset (true for
every task here).

Precision: JAX computes in float32 unless ``jax_enable_x64`` is set (``mjx_variant(cls, x64=True)``,
``task.mjx_x64=true``); hooks always see float64 tensors on the CPU, so their dtypes and devices match the
CPU backend.

Host copies: none on a CPU JAX device (DLPack views). On an accelerator the physics stays on the device
but the hooks run on the CPU, so each control step copies the state fields to the host (O(N·(nq + nv +
fields))) and ``ctrl`` back (O(N·nu)), and a reset copies the sampled qpos/qvel rows; see docs/mjx.md.

Example:
    >>> import numpy as np, mujoco, torch
    >>> class Slider(MjxBatchedEnv):
    ...     reward_term_names = ("position",)
    ...     def reset_state(self, env_ids, rng):
    ...         return rng.uniform(-0.1, 0.1, (len(env_ids), 1)), np.zeros((len(env_ids), 1))
    ...     def observation(self):
    ...         return torch.cat([self.qpos, self.qvel], -1)
    ...     def reward_terms(self):
    ...         return {"position": -self.qpos[:, 0].abs()}
    >>> xml = '''<mujoco><worldbody><body><joint name="x" type="slide" axis="1 0 0"/>
    ...   <geom type="sphere" size="0.1" mass="1" contype="0" conaffinity="0"/></body></worldbody>
    ...   <actuator><motor joint="x" gear="1"/></actuator></mujoco>'''
    >>> import pytest; _ = pytest.importorskip("jax", reason="the [mjx] extra is not installed")
    >>> env = Slider(mujoco.MjModel.from_xml_string(xml), num_envs=4, decimation=2, max_episode_steps=10)
    >>> env.rollout(3)["next", "info", "reward_position"].shape
    torch.Size([4, 3])
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
from functools import cache

import mujoco
import numpy as np
import torch
from torchrl.envs import EnvBase

from torchrl_ahrs.envs.backends.mujoco_base import BatchedMujocoEnv

MJX_INSTALL_HINT = 'the MJX backend needs the optional extra: pip install "torchrl-ahrs[mjx]"'


def mjx_available() -> bool:
    """Whether ``jax`` and ``mujoco.mjx`` can be imported (the ``[mjx]`` extra is installed)."""
    return importlib.util.find_spec("jax") is not None and importlib.util.find_spec("mujoco.mjx") is not None


def _require_mjx():
    """Imports ``(jax, jax.numpy, mujoco.mjx)`` or raises ImportError with the install command."""
    if not mjx_available():
        raise ImportError(MJX_INSTALL_HINT)
    import jax
    import jax.numpy as jnp

    with contextlib.redirect_stdout(io.StringIO()):  # mujoco.mjx prints "Failed to import warp" without [warp]
        from mujoco import mjx

    return jax, jnp, mjx


def _to_torch(array) -> torch.Tensor:
    """A JAX array as a float64 CPU torch tensor: a DLPack view (zero-copy) when JAX runs on the CPU, one
    device-to-host copy when it runs on an accelerator (the task hooks' constants live on the CPU)."""
    return torch.from_dlpack(array).to("cpu", torch.float64)


class MjxBatchedEnv(BatchedMujocoEnv):
    """N MJX simulations of one model behind the :class:`BatchedMujocoEnv` hooks; see the module docstring.

    Args:
        model: the compiled ``mujoco.MjModel`` (copied to the JAX device with ``mjx.put_model``).
        num_envs: batch size N.
        decimation: physics substeps per control step.
        max_episode_steps: control steps before an env is truncated.
        num_threads: ignored (XLA owns the parallelism); kept for the CPU base's signature.
        seed: seed of the numpy generator used by ``reset_state``.
        device: torch device of the returned tensors.

    Class attribute ``x64``: run MJX in float64 (sets ``jax_enable_x64`` process-wide); default float32.

    State read by the hooks: ``qpos`` [N, nq], ``qvel`` [N, nv], ``state_t[name]`` [N, *shape] float64 CPU
    torch, ``state[name]`` the same memory as numpy; ``data`` is the batched ``mjx.Data`` (leading axis N).
    """

    x64: bool = False

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
        jax, jnp, mjx = _require_mjx()
        if self.x64:
            jax.config.update("jax_enable_x64", True)
        if num_envs < 1 or decimation < 1 or max_episode_steps < 1:
            raise ValueError("num_envs, decimation and max_episode_steps must be positive")
        if not self.reward_term_names:
            raise ValueError(f"{type(self).__name__} declares no reward_term_names")
        if self.per_substep_control:
            raise NotImplementedError("per_substep_control has no MJX path; build PD into the MJCF (<position kp kv>)")
        EnvBase.__init__(self, device=device, batch_size=torch.Size([num_envs]))
        self.model = model
        self.num_envs = num_envs
        self.decimation = int(decimation)
        self.max_episode_steps = int(max_episode_steps)
        self.control_dt = self.decimation * float(model.opt.timestep)
        self._fields = ("qpos", "qvel", *[f for f in self.state_fields if f not in ("qpos", "qvel")])
        self._pool = None
        self._jax, self._jnp = jax, jnp
        self.mjx_model = mjx.put_model(model)
        reference = mjx.make_data(self.mjx_model)  # mj_resetData's state: qpos0, zero velocity, ctrl, warm start
        self.data = jax.tree.map(lambda x: jnp.broadcast_to(x, (num_envs, *x.shape)), reference)
        self._reference = reference
        self._publish(self.data)
        self.ctrl = np.zeros((num_envs, model.nu), np.float64)
        self.action = torch.zeros(num_envs, self.action_dim)
        self.episode_steps = torch.zeros(num_envs, dtype=torch.int64)
        self.rng = np.random.default_rng(seed)
        self.init_buffers()
        self.reset_envs(np.arange(num_envs))
        self._make_specs()

    def _publish(self, data) -> None:
        """Points ``state`` / ``state_t`` / ``qpos`` / ``qvel`` at the fields of ``data`` (DLPack, then float64)."""
        self.data = self._jax.block_until_ready(data)  # wait outside DLPack: the step is dispatched asynchronously
        self.state_t = {name: _to_torch(getattr(data, name)) for name in self._fields}
        self.state = {name: tensor.numpy() for name, tensor in self.state_t.items()}
        self.qpos, self.qvel = self.state_t["qpos"], self.state_t["qvel"]

    def _physics_step(self) -> None:
        """Advances every env by ``decimation`` MJX steps in one jitted call."""
        ctrl = self._jnp.asarray(self.ctrl, dtype=self.data.qpos.dtype)
        step, _ = _compiled_functions()
        self._publish(step(self.mjx_model, self.data, ctrl, decimation=self.decimation))

    def reset_envs(self, env_ids: np.ndarray) -> None:
        """Resets the envs ``env_ids`` [n] to the task's ``reset_state``; the other rows are untouched."""
        qpos_rows, qvel_rows = self.reset_state(env_ids, self.rng)
        mask = np.zeros(self.num_envs, bool)
        mask[env_ids] = True
        qpos = np.zeros((self.num_envs, self.model.nq))
        qvel = np.zeros((self.num_envs, self.model.nv))
        qpos[env_ids], qvel[env_ids] = qpos_rows, qvel_rows
        dtype = self.data.qpos.dtype
        jnp = self._jnp
        _, reset = _compiled_functions()
        args = jnp.asarray(mask), jnp.asarray(qpos, dtype), jnp.asarray(qvel, dtype)
        self._publish(reset(self._reference, self.data, *args))
        ids = torch.as_tensor(env_ids, dtype=torch.long)
        self.ctrl[env_ids] = 0.0
        self.action[ids] = 0.0
        self.episode_steps[ids] = 0
        self.on_reset(env_ids)

    def close(self, *, raise_if_closed: bool = True) -> None:
        EnvBase.close(self, raise_if_closed=raise_if_closed)


@cache
def _compiled_functions():
    """``(step(model, data, ctrl, decimation) -> data, reset(reference, data, mask, qpos, qvel) -> data)``,
    jitted once per process (XLA's cache then keys on the model's shapes), vmapped over N."""
    jax, jnp, mjx = _require_mjx()

    def step(model, data, ctrl, decimation):
        def substep(_, data):
            return jax.vmap(mjx.step, in_axes=(None, 0))(model, data)  # one physics step of all N envs

        return jax.lax.fori_loop(0, decimation, substep, data.replace(ctrl=ctrl))  # decimation substeps, ctrl held

    def reset(reference, data, mask, qpos, qvel):
        fresh = jax.tree.map(lambda x: jnp.broadcast_to(x, (mask.shape[0], *x.shape)), reference)
        fresh = fresh.replace(qpos=qpos, qvel=qvel)  # mj_resetData, then the task's initial state

        def pick(new, old):
            return jnp.where(mask.reshape(-1, *([1] * (old.ndim - 1))), new, old)  # reset rows ← fresh rows

        return jax.tree.map(pick, fresh, data)

    return jax.jit(step, static_argnames="decimation"), jax.jit(reset)


def mjx_variant(task_class: type[BatchedMujocoEnv], x64: bool = False) -> type[BatchedMujocoEnv]:
    """The task class with its physics on MJX: ``type(name, (task_class, MjxBatchedEnv), {"x64": x64})``.

    The task's ``__init__`` calls ``super().__init__(model, ...)``, which the method resolution order sends
    to :class:`MjxBatchedEnv`; every other hook stays the task's. One class per (task class, x64).
    """
    key = (task_class, bool(x64))
    if key not in _VARIANTS:
        name = task_class.__name__.removesuffix("Env") + ("Mjx64Env" if x64 else "MjxEnv")
        variant = type(name, (task_class, MjxBatchedEnv), {"x64": bool(x64)})
        variant.__module__ = __name__
        variant.__doc__ = f"{task_class.__name__} stepped on MJX (see :class:`MjxBatchedEnv`)."
        _VARIANTS[key] = variant
    return _VARIANTS[key]


_VARIANTS: dict[tuple[type, bool], type[BatchedMujocoEnv]] = {}
