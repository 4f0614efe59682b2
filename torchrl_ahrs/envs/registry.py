"""Task registry: a task name → a batched TorchRL environment whose reward is a component tree.

A task is a YAML file in ``conf/task/`` (shipped inside the package as ``torchrl_ahrs.conf``; composed by
``torchrl_ahrs.app.shared.settings.load_task_config``), the frozen settings record its builder reads
(:mod:`torchrl_ahrs.envs.settings`; ``task_settings`` in the app converts the config to it) and a builder
function registered here under the same name. A builder takes the settings, the number of environments and a
seed, and returns an ``EnvBase`` with batch size ``[num_envs]`` that writes
``("next", "reward", c)`` for each ``c`` in ``task.components`` and ``("next", "reward", "total")``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from typing import Any

import torch
from torchrl.envs import EnvBase, Transform, TransformedEnv

from torchrl_ahrs.envs import settings as task_records
from torchrl_ahrs.envs.common.mirror import SignedPermutation
from torchrl_ahrs.envs.common.snapshot import BaseEnvSnapshot
from torchrl_ahrs.envs.settings import TaskSettings
from torchrl_ahrs.rewards.auxiliary import AUX, TOTAL_AUX
from torchrl_ahrs.rewards.components import TOTAL, ComponentRewardSum, component_reward_keys

TaskBuilder = Callable[[Any, int, int, str], EnvBase]  # (settings record, num_envs, seed, device)

# name -> "module:function"; imported on first use so that optional backends load only when asked.
_BUILDERS: dict[str, str] = {
    "ant_v5": "torchrl_ahrs.envs.tasks.envpool_tasks:make_ant_v5",
    "go1_terrain": "torchrl_ahrs.envs.tasks.envpool_tasks:make_info_terms_task",
    "leap_cube": "torchrl_ahrs.envs.tasks.envpool_tasks:make_info_terms_task",
    "humanoid": "torchrl_ahrs.envs.tasks.envpool_tasks:make_info_terms_task",
    "shadow_hand": "torchrl_ahrs.envs.tasks.shadow_hand:make_shadow_hand",
    "shadow_hand_scissors": "torchrl_ahrs.envs.tasks.shadow_hand_scissors:make_shadow_hand_scissors",
    "shadow_hand_bottle_cap": "torchrl_ahrs.envs.tasks.shadow_hand_bottle_cap:make_shadow_hand_bottle_cap",
    "dmc_walker_walk": "torchrl_ahrs.envs.tasks.dmc_tasks:make_dmc_task",
    "dmc_quadruped_run": "torchrl_ahrs.envs.tasks.dmc_tasks:make_dmc_task",
    "dmc_cheetah_run": "torchrl_ahrs.envs.tasks.dmc_tasks:make_dmc_task",
    "ant": "torchrl_ahrs.envs.tasks.ant:make_ant",
    "quadcopter": "torchrl_ahrs.envs.tasks.quadcopter:make_quadcopter",
    "cassie": "torchrl_ahrs.envs.tasks.cassie:make_cassie",
    "point_reach": "torchrl_ahrs.envs.tasks.point_reach:make_point_reach",
}
# task.backend=mjx: the same tasks stepped by MJX on JAX (the [mjx] extra); task.backend=cpu uses _BUILDERS
_MJX_BUILDERS = dict.fromkeys(("ant", "cassie", "quadcopter"), "torchrl_ahrs.envs.tasks.mjx_tasks:make_mjx_task")
BACKENDS = ("cpu", "mjx")
# name -> "module:function" giving the task's left-right mirror maps, {"observation": ..., "action": ...}
# (SignedPermutation, envs/common/mirror.py), for ppo.mirror; a task absent here has none
_MIRRORS: dict[str, str] = {"cassie": "torchrl_ahrs.envs.tasks.cassie:cassie_mirror"}
# name -> the settings record its builder reads (torchrl_ahrs.envs.settings); the same for both backends
_SETTINGS: dict[str, type[TaskSettings]] = {
    "ant_v5": task_records.AntV5Settings,
    "go1_terrain": task_records.InfoTermsSettings,
    "leap_cube": task_records.InfoTermsSettings,
    "humanoid": task_records.InfoTermsSettings,
    "shadow_hand": task_records.ShadowHandSettings,
    "shadow_hand_scissors": task_records.ScissorsSettings,
    "shadow_hand_bottle_cap": task_records.BottleCapSettings,
    "dmc_walker_walk": task_records.DmcSettings,
    "dmc_quadruped_run": task_records.DmcSettings,
    "dmc_cheetah_run": task_records.CheetahRunSettings,
    "ant": task_records.AntSettings,
    "quadcopter": task_records.QuadcopterSettings,
    "cassie": task_records.CassieSettings,
    "point_reach": task_records.PointReachSettings,
}


# backends whose environments compute on their torch device (the hooks' state follows env.to(device));
# the others step on the CPU and hand their output to a collector that moves it (policy/storing device)
DEVICE_RESIDENT_BACKENDS = ("mjx",)


def simulation_device(backend: str) -> torch.device:
    """Where a task on ``backend`` simulates, as a torch device: ``cpu`` for the CPU backends; for ``mjx`` the
    device matching JAX's default one (``cuda:k`` on a GPU). ``trainer.device=null`` resolves to it."""
    if backend != "mjx":
        return torch.device("cpu")
    from torchrl_ahrs.envs.backends.mjx import default_torch_device  # imports JAX: only when asked for

    return default_torch_device()


def env_device(backend: str, device: torch.device) -> torch.device:
    """The device to build a ``backend`` task's environments on when the learner is on ``device``: ``device``
    itself for a device-resident backend (MJX: no copy between simulation and learner), else the CPU."""
    return device if backend in DEVICE_RESIDENT_BACKENDS else torch.device("cpu")


def register_task(name: str, builder: TaskBuilder | str, settings: type[TaskSettings] = TaskSettings) -> None:
    """Registers ``builder`` (a callable or ``"module:function"``) under ``name``, reading a ``settings`` record
    (a frozen dataclass deriving from :class:`~torchrl_ahrs.envs.settings.TaskSettings`)."""
    _BUILDERS[name] = builder  # type: ignore[assignment]
    _SETTINGS[name] = settings


def settings_type(name: str) -> type[TaskSettings]:
    """The settings record that task ``name``'s builder reads; unknown names raise with the accepted ones."""
    if name not in _SETTINGS:
        raise KeyError(f"unknown task {name!r}; available tasks: {', '.join(available_tasks())}")
    return _SETTINGS[name]


def available_tasks() -> list[str]:
    """Names accepted by :func:`make_env`, sorted."""
    return sorted(_BUILDERS)


def get_builder(name: str, backend: str = "cpu") -> TaskBuilder:
    """The builder registered as ``name`` for ``backend`` (``cpu`` or ``mjx``); unknown names raise with the accepted ones."""
    if backend not in BACKENDS:
        raise KeyError(f"unknown backend {backend!r}; backends: {', '.join(BACKENDS)}")
    builders = _MJX_BUILDERS if backend == "mjx" else _BUILDERS
    if name not in builders:
        kind = "" if backend == "cpu" else f"{backend} "
        raise KeyError(f"unknown {kind}task {name!r}; available {kind}tasks: {', '.join(sorted(builders))}")
    builder = builders[name]
    if isinstance(builder, str):
        module_name, function_name = builder.split(":")
        builder = getattr(importlib.import_module(module_name), function_name)
    return builder


def task_mirror(task: TaskSettings) -> dict[str, SignedPermutation]:
    """Task ``task.name``'s mirror maps ``{"observation": SignedPermutation, "action": SignedPermutation}``
    (the same for both backends: they share the observation's layout). A task without one, or settings its map
    does not hold for, raise ``ValueError`` with a one-line reason."""
    if task.name not in _MIRRORS:
        having = ", ".join(sorted(_MIRRORS))
        raise ValueError(f"task {task.name!r} defines no left-right mirror (tasks with one: {having})")
    module_name, function_name = _MIRRORS[task.name].split(":")
    return getattr(importlib.import_module(module_name), function_name)(task)


def make_env(
    task: TaskSettings,
    num_envs: int,
    seed: int = 0,
    device: str | torch.device = "cpu",
    components: Sequence[str] | None = None,
    transforms: Sequence[Callable[[], Transform]] = (),
) -> TransformedEnv:
    """Builds the task and tracks each component's episode return.

    Args:
        task: the task's settings (:mod:`torchrl_ahrs.envs.settings`; from ``conf/task/<name>.yaml`` by
            ``torchrl_ahrs.app.shared.settings.load_task_settings``); ``task.name`` and ``task.backend`` pick
            the builder.
        num_envs: batch size N.
        seed: environment seed.
        device: the environment's torch device (:func:`env_device`: where an MJX env's state and output live).
        components: the reward leaves that form the K axis; default ``task.components``.
            ``["total"]`` gives plain PPO's single head.
        transforms: factories (zero-argument callables, picklable for collector workers) of transforms
            appended after the task's own, before the episode returns are tracked — e.g. the
            :class:`~torchrl_ahrs.rewards.auxiliary.AuxiliaryReward` that writes ``("reward", "aux")``.

    Returns:
        A ``TransformedEnv`` with batch size ``[N]`` whose ``next`` tensordict holds
        ``("reward", c)`` and ``("episode_reward", c)`` for every c in ``components`` and ``"total"``;
        its ``state_dict()`` holds the simulator's running episodes when the backend can snapshot them
        (:mod:`torchrl_ahrs.envs.common.snapshot`).

    Example:
        >>> from torchrl_ahrs.app.shared.settings import load_task_settings
        >>> env = make_env(load_task_settings("ant_v5"), num_envs=2)
        >>> env.rollout(3)["next", "reward", "forward"].shape
        torch.Size([2, 3, 1])
    """
    if num_envs < 1:
        raise ValueError(f"num_envs must be at least 1, got {num_envs}")
    components = list(components if components is not None else task.components)
    tracked = components + ([TOTAL] if TOTAL not in components else [])
    env = get_builder(task.name, task.backend)(task, num_envs, seed, str(device))
    if transforms and not isinstance(env, TransformedEnv):
        env = TransformedEnv(env)
    for make_transform in transforms:
        env.append_transform(make_transform())
    written = set(env.full_reward_spec.keys(True, True)) | set(env.full_observation_spec.keys(True, True))
    missing = [key for key in component_reward_keys(tracked) if key not in written]
    if missing and any(key[-1] in (AUX, TOTAL_AUX) for key in missing):
        raise ValueError(
            f"components {components} name the auxiliary reward but no AuxiliaryReward transform was given; "
            "pass transforms=[lambda: AuxiliaryReward.from_file(path)]"
        )
    if missing:
        raise ValueError(f"task {task.name!r} does not write the reward leaves {missing}")
    if not isinstance(env, TransformedEnv):
        env = TransformedEnv(env)
    env.append_transform(ComponentRewardSum(tracked))
    env.append_transform(BaseEnvSnapshot())  # env.state_dict() holds the simulator's state when it has one
    return env
