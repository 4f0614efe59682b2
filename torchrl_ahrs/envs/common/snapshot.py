"""Environment snapshots for exact resume, carried by TorchRL's own ``state_dict`` mechanism.

TorchRL saves a ``TransformedEnv`` through its transforms only (``Collector.state_dict`` stores
``env.transform.state_dict()``), so the base environment's state needs a transform to ride on:
:class:`BaseEnvSnapshot`, which every :func:`~torchrl_ahrs.envs.make_env` environment ends with, puts the
base environment's own ``state_dict()`` (its ``_extra_state``) into the chain's, and loads it back.

A base environment takes part by overriding ``nn.Module.get_extra_state`` / ``set_extra_state``:
:class:`~torchrl_ahrs.envs.backends.mujoco_base.BatchedMujocoEnv` does (:func:`mujoco_snapshot`). One that
does not (EnvPool's C++ simulators) has no snapshot: :func:`restores_episodes` is then false and a
resumed run starts new episodes.
"""

from __future__ import annotations

import copy
import pickle
from typing import Any

import mujoco
import numpy as np
import torch
from torch import nn
from torchrl.envs import EnvBase, Transform, TransformedEnv


def mujoco_snapshot(env: Any) -> dict[str, Any]:
    """A ``BatchedMujocoEnv``'s state: every ``MjData``'s ``mjSTATE_INTEGRATION`` (time, qpos, qvel, act,
    warm start, ctrl, applied forces, mocap, ...), the stacked ``state_fields``, ``ctrl``, ``action``,
    ``episode_steps``, the reset generator's state and the task's ``episode_state`` attributes."""
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    physics = np.empty((env.num_envs, mujoco.mj_stateSize(env.model, spec)), np.float64)
    for i, data in enumerate(env.datas):
        mujoco.mj_getState(env.model, data, physics[i], spec)
    return {
        "physics": physics,
        "fields": {name: array.copy() for name, array in env.state.items()},
        "ctrl": env.ctrl.copy(),
        "action": env.action.clone(),
        "episode_steps": env.episode_steps.clone(),
        "rng": pickled(env.rng.bit_generator.state),  # 128-bit integers: bytes, so TensorDict can carry it
        "task": {name: copy.deepcopy(getattr(env, name)) for name in env.episode_state},
    }


def pickled(value: Any) -> torch.Tensor:
    """``value`` pickled into a uint8 tensor (128-bit generator states survive TensorDict and pipes)."""
    return torch.frombuffer(bytearray(pickle.dumps(value)), dtype=torch.uint8)


def restore_mujoco_snapshot(env: Any, state: dict[str, Any]) -> None:
    """Puts a :func:`mujoco_snapshot` back into an env of the same model and ``num_envs``."""
    physics = np.asarray(state["physics"], np.float64)  # a tensor when it came through a worker's pipe
    if physics.shape[0] != env.num_envs:
        raise ValueError(f"a snapshot of {physics.shape[0]} envs cannot be loaded into {env.num_envs}")
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    for i, data in enumerate(env.datas):
        mujoco.mj_setState(env.model, data, physics[i], spec)
        mujoco.mj_forward(env.model, data)  # derived quantities (rendering, sensors) agree with the state
        mujoco.mj_setState(env.model, data, physics[i], spec)  # and the warm start is the saved one
    for name, array in env.state.items():
        array[...] = np.asarray(state["fields"][name])  # in place: qpos, qvel and state_t are views of these arrays
    env.ctrl[...] = np.asarray(state["ctrl"])
    env.action = state["action"].clone()
    env.episode_steps = state["episode_steps"].clone()
    env.rng.bit_generator.state = pickle.loads(np.asarray(state["rng"], np.uint8).tobytes())
    for name, value in state["task"].items():
        setattr(env, name, copy.deepcopy(value))


def _innermost(env: EnvBase) -> EnvBase:
    while isinstance(env, TransformedEnv):
        env = env.base_env
    return env


def has_snapshot(env: EnvBase) -> bool:
    """Whether the (innermost) base environment of ``env`` saves its state (overrides ``get_extra_state``)."""
    return type(_innermost(env)).get_extra_state is not nn.Module.get_extra_state


def restores_episodes(env: EnvBase) -> bool:
    """Whether ``env.state_dict()`` holds the running episodes: a :class:`BaseEnvSnapshot` over a base
    environment that has a snapshot."""
    transforms = getattr(env, "transform", None)
    return has_snapshot(env) and transforms is not None and any(isinstance(t, BaseEnvSnapshot) for t in transforms)


class BaseEnvSnapshot(Transform):
    """Carries the base environment's ``state_dict()`` inside the transform chain's (``None`` when the
    base environment has no snapshot); changes no data.

    Example:
        >>> from torchrl_ahrs.envs import make_env
        >>> from torchrl_ahrs.app.shared.settings import load_task_settings
        >>> env = make_env(load_task_settings("point_reach"), num_envs=2, seed=0)
        >>> _ = env.rollout(3, break_when_any_done=False)
        >>> twin = make_env(load_task_settings("point_reach"), num_envs=2, seed=1)
        >>> twin.load_state_dict(env.state_dict())
        >>> bool((twin.base_env.qpos == env.base_env.qpos).all())
        True
    """

    def __init__(self):
        super().__init__(in_keys=[], out_keys=[])

    def get_extra_state(self) -> Any:
        container = self.container
        if container is None or not has_snapshot(container):
            return None
        return _innermost(container).state_dict()

    def set_extra_state(self, state: Any) -> None:
        if state is not None:
            _innermost(self.container).load_state_dict(state)
