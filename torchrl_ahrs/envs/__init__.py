"""Tasks: the registry, their settings records, and the environment bases they are built on (imported on demand)."""

from torchrl_ahrs.envs.registry import available_tasks, get_builder, make_env, register_task, settings_type
from torchrl_ahrs.envs.settings import TaskSettings

__all__ = ["TaskSettings", "available_tasks", "get_builder", "make_env", "register_task", "settings_type"]
