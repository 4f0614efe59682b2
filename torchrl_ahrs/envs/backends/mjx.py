"""MJX backend: the same task hooks as :class:`~torchrl_ahrs.envs.backends.mujoco_base.BatchedMujocoEnv`, with
the N simulations stepped as one ``jax.jit(jax.vmap(mjx.step))`` batch (CPU-JAX in tests, GPU/TPU for real runs).

A task written for the threaded CPU base runs on MJX unchanged: :func:`mjx_variant` puts
:class:`MjxBatchedEnv` under the task class (``class QuadcopterMjx(QuadcopterEnv, MjxBatchedEnv)``), so
``reset_state``, ``apply_action``, ``observation``, ``reward_terms``, ``terminated`` ... are the task's own
torch code — no reward formula is written twice — and only the physics and the stacked state change.

How a control step runs (``_physics_step``, everything else is the CPU base's ``_step``)::

    ctrl[N, nu]  = apply_action(action[N, A])                      # the task's torch hook, on the env's device
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
``task.mjx_x64=true``); hooks always see float64 tensors, so their dtypes match the CPU backend.

Devices: the torch side (the hooks' state, the task's constants and buffers, every returned tensor) lives
on the env's ``device``; the physics on JAX's device. When the two are the same (``device="cuda:0"`` with
JAX on GPU 0, or both on the CPU) a control step moves no data between host and device: state and ctrl
cross between JAX and torch as DLPack views, and the task's constants are moved to ``device`` once, at
construction (and by ``env.to(device)``). When they differ, each step copies the state fields and ctrl
across. Resets draw on the host (the CPU backend's numpy generator, so that a seed gives the same episodes
on both backends) and copy the reset rows [n, nq + nv] and the mask to the device. The full list of the
remaining copies is in docs/mjx.md ("Where the copies are").

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
import copy
import importlib.util
import io
import pickle
from functools import cache

import mujoco
import numpy as np
import torch
from torchrl.envs import EnvBase

from torchrl_ahrs.envs.backends.mujoco_base import BatchedMujocoEnv
from torchrl_ahrs.envs.common.snapshot import pickled

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


def torch_device_of(jax_device) -> torch.device:
    """The torch device holding the same memory as a JAX device: ``cpu`` → ``cpu``, GPU ``k`` → ``cuda:k``.

    Example:
        >>> import pytest; jax = pytest.importorskip("jax", reason="the [mjx] extra is not installed")
        >>> torch_device_of(jax.devices("cpu")[0])
        device(type='cpu')
    """
    platform = jax_device.platform
    if platform == "cpu":
        return torch.device("cpu")
    if platform in ("gpu", "cuda", "rocm"):  # torch names ROCm devices "cuda" too
        index = getattr(jax_device, "local_hardware_id", None)  # the CUDA ordinal, as torch counts devices
        return torch.device("cuda", jax_device.id if index is None else index)
    raise ValueError(f"torch has no device for JAX's {platform!r} device {jax_device}; use a CPU or GPU JAX")


def default_torch_device() -> torch.device:
    """The torch device matching JAX's default device (where MJX steps): ``trainer.device=null`` for MJX."""
    jax, _, _ = _require_mjx()
    return torch_device_of(jax.devices()[0])


class MjxBatchedEnv(BatchedMujocoEnv):
    """N MJX simulations of one model behind the :class:`BatchedMujocoEnv` hooks; see the module docstring.

    Args:
        model: the compiled ``mujoco.MjModel`` (copied to the JAX device with ``mjx.put_model``).
        num_envs: batch size N.
        decimation: physics substeps per control step.
        max_episode_steps: control steps before an env is truncated.
        num_threads: ignored (XLA owns the parallelism); kept for the CPU base's signature.
        seed: seed of the numpy generator used by ``reset_state``.
        device: torch device of the hooks' state and the returned tensors; JAX's own device for zero copies.

    Class attribute ``x64``: run MJX in float64 (sets ``jax_enable_x64`` process-wide); default float32.

    State read by the hooks: ``qpos`` [N, nq], ``qvel`` [N, nv], ``state_t[name]`` [N, *shape] float64 torch
    on ``device``; ``ctrl`` [N, nu] float64 torch; ``data`` the batched ``mjx.Data`` (leading axis N).
    ``state`` (numpy) exists for the CPU base's API only: it is a host copy, off the per-step path.
    """

    x64: bool = False
    ctrl: torch.Tensor  # type: ignore[assignment]  # a tensor on the env's device; the CPU base keeps numpy for its threads

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
        self._physics_dtype = torch.float64 if self.x64 else torch.float32  # the dtype ctrl/qpos cross to JAX in
        self.mjx_model = mjx.put_model(model)
        reference = mjx.make_data(self.mjx_model)  # mj_resetData's state: qpos0, zero velocity, ctrl, warm start
        self.data = jax.tree.map(lambda x: jnp.broadcast_to(x, (num_envs, *x.shape)), reference)
        self._reference = reference
        self._publish(self.data)
        self.ctrl = torch.zeros(num_envs, model.nu, dtype=torch.float64, device=self.device)
        self.action = torch.zeros(num_envs, self.action_dim, device=self.device)
        self.episode_steps = torch.zeros(num_envs, dtype=torch.int64, device=self.device)
        self.rng = np.random.default_rng(seed)
        self.init_buffers()
        self._move_tensors()  # the task's constants (set before this __init__) and buffers, once
        self.reset_envs(np.arange(num_envs))
        self._make_specs()

    # ---------------------------------------------------------------- devices
    def _move_tensors(self) -> None:
        """Moves every torch tensor the task holds (directly or in a dict) to ``self.device``."""
        for name, value in list(vars(self).items()):
            if isinstance(value, torch.Tensor):
                setattr(self, name, value.to(self.device))
            elif isinstance(value, dict) and value and all(isinstance(v, torch.Tensor) for v in value.values()):
                setattr(self, name, {key: v.to(self.device) for key, v in value.items()})

    def to(self, device) -> MjxBatchedEnv:
        """TorchRL's ``env.to(device)``: also moves the hooks' state and the task's tensors (JAX stays put)."""
        super().to(device)
        self._move_tensors()
        self._publish(self.data)
        return self

    def _to_torch(self, array) -> torch.Tensor:
        """A JAX array as a float64 torch tensor on the env's device: a DLPack view, then the cast (no copy
        across devices when JAX runs on the env's device; one copy when it does not)."""
        return torch.from_dlpack(array).to(self.device, torch.float64)

    def _to_jax(self, tensor: torch.Tensor):
        """A torch tensor as a JAX array in the physics dtype (bools stay bool), through DLPack."""
        if tensor.dtype != torch.bool:
            tensor = tensor.to(self._physics_dtype)
        return self._jax.dlpack.from_dlpack(tensor.contiguous())

    @property
    def state(self) -> dict[str, np.ndarray]:  # type: ignore[override]
        """``state_fields`` as numpy [N, ...] float64: host copies (the per-step hooks read ``state_t``)."""
        return {name: tensor.cpu().numpy() for name, tensor in self.state_t.items()}

    # ---------------------------------------------------------------- physics
    def _publish(self, data) -> None:
        """Points ``state_t`` / ``qpos`` / ``qvel`` at the fields of ``data`` (DLPack, then float64)."""
        self.data = self._jax.block_until_ready(data)  # wait outside DLPack: the step is dispatched asynchronously
        self.state_t = {name: self._to_torch(getattr(data, name)) for name in self._fields}
        self.qpos, self.qvel = self.state_t["qpos"], self.state_t["qvel"]

    def _write_ctrl(self, ctrl) -> None:
        """Keeps ``apply_action``'s ctrl as a float64 tensor on the env's device (numpy ctrl: one copy)."""
        self.ctrl = torch.as_tensor(ctrl, dtype=torch.float64, device=self.device)

    def _physics_step(self) -> None:
        """Advances every env by ``decimation`` MJX steps in one jitted call."""
        step, _ = _compiled_functions()
        self._publish(step(self.mjx_model, self.data, self._to_jax(self.ctrl), decimation=self.decimation))

    def reset_envs(self, env_ids: np.ndarray) -> None:
        """Resets the envs ``env_ids`` [n] to the task's ``reset_state``; the other rows are untouched."""
        qpos_rows, qvel_rows = self.reset_state(env_ids, self.rng)  # host draws: the CPU backend's generator
        ids = torch.as_tensor(env_ids, dtype=torch.long, device=self.device)
        n, dtype = self.num_envs, self._physics_dtype
        mask = torch.zeros(n, dtype=torch.bool, device=self.device)
        mask[ids] = True
        qpos = torch.zeros(n, self.model.nq, dtype=dtype, device=self.device)
        qvel = torch.zeros(n, self.model.nv, dtype=dtype, device=self.device)
        qpos[ids] = torch.as_tensor(qpos_rows, dtype=dtype).to(self.device)  # the n drawn rows: the only copy
        qvel[ids] = torch.as_tensor(qvel_rows, dtype=dtype).to(self.device)
        _, reset = _compiled_functions()
        self._publish(reset(self._reference, self.data, self._to_jax(mask), self._to_jax(qpos), self._to_jax(qvel)))
        self.ctrl[ids] = 0.0
        self.action[ids] = 0.0
        self.episode_steps[ids] = 0
        self.on_reset(env_ids)

    # ---------------------------------------------------------------- snapshot
    def get_extra_state(self) -> dict:
        """Everything the next step depends on: every leaf of the batched ``mjx.Data`` (host copies), ctrl,
        action, step counters, the reset generator and the task's ``episode_state``."""
        leaves = self._jax.tree.leaves(self.data)
        return {
            "mjx_data": [np.array(leaf) for leaf in leaves],  # one device-to-host copy per checkpoint
            "ctrl": self.ctrl.clone(),
            "action": self.action.clone(),
            "episode_steps": self.episode_steps.clone(),
            "rng": pickled(self.rng.bit_generator.state),
            "task": {name: copy.deepcopy(getattr(self, name)) for name in self.episode_state},
        }

    def set_extra_state(self, state: dict) -> None:
        """Restores a :meth:`get_extra_state` snapshot of an env with the same model and ``num_envs``."""
        leaves, treedef = self._jax.tree.flatten(self.data)
        saved = [np.asarray(leaf) for leaf in state["mjx_data"]]
        if [x.shape for x in saved] != [leaf.shape for leaf in leaves]:
            raise ValueError("the MJX snapshot was taken from another model or num_envs")
        jnp = self._jnp
        self._publish(
            self._jax.tree.unflatten(
                treedef, [jnp.asarray(x, leaf.dtype) for x, leaf in zip(saved, leaves, strict=True)]
            )
        )
        self.ctrl = torch.as_tensor(state["ctrl"]).to(self.device, torch.float64)
        self.action = torch.as_tensor(state["action"]).to(self.device)
        self.episode_steps = torch.as_tensor(state["episode_steps"]).to(self.device)
        self.rng.bit_generator.state = pickle.loads(np.asarray(state["rng"], np.uint8).tobytes())
        for name, value in state["task"].items():
            setattr(self, name, copy.deepcopy(value))
        self._move_tensors()  # a snapshot saved on another device

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
