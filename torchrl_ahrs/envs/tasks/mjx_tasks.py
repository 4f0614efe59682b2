"""``task.backend=mjx`` builders: the project's MuJoCo tasks with their physics on MJX (the ``[mjx]`` extra).

Each builder is the CPU task's own builder called with the task class's MJX variant
(:func:`~torchrl_ahrs.envs.backends.mjx.mjx_variant`), so the config keys, observations, reward terms and
``("reward", c)`` tree are the CPU task's. The models are the CPU models unchanged (same contact pairs,
solver and iterations); ``task.mjx_x64=true`` runs MJX in float64.

Example:
    >>> import pytest; _ = pytest.importorskip("jax", reason="the [mjx] extra is not installed")
    >>> from torchrl_ahrs.app.shared.settings import load_task_settings
    >>> env = make_mjx_task(load_task_settings("quadcopter", ["task.backend=mjx"]), num_envs=2)
    >>> env.rollout(2)["next", "reward", "pos_up"].shape
    torch.Size([2, 2, 1])
"""

from __future__ import annotations

from torchrl.envs import EnvBase

from torchrl_ahrs.envs.backends.mjx import mjx_variant
from torchrl_ahrs.envs.settings import MjxSettings
from torchrl_ahrs.envs.tasks.ant import AntEnv, make_ant
from torchrl_ahrs.envs.tasks.cassie import CassieEnv, make_cassie
from torchrl_ahrs.envs.tasks.quadcopter import QuadcopterEnv, make_quadcopter

MJX_TASKS = {
    "ant": (make_ant, AntEnv),
    "cassie": (make_cassie, CassieEnv),
    "quadcopter": (make_quadcopter, QuadcopterEnv),
}


def make_mjx_task(task: MjxSettings, num_envs: int, seed: int = 0, device: str = "cpu") -> EnvBase:
    """Task builder (registry signature) for ``task.backend=mjx``: the CPU builder with the MJX env class."""
    name = task.name
    if name not in MJX_TASKS:
        raise KeyError(f"task {name!r} has no MJX backend; MJX tasks: {', '.join(sorted(MJX_TASKS))}")
    builder, task_class = MJX_TASKS[name]
    env_class = mjx_variant(task_class, x64=bool(task.mjx_x64))
    return builder(task, num_envs, seed, device, env_class=env_class)  # type: ignore[operator]
