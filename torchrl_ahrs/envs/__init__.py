"""Tasks: the registry, and the environment bases they are built on (imported on demand)."""

from torchrl_ahrs.envs.registry import available_tasks, get_builder, make_env, register_task

__all__ = ["available_tasks", "get_builder", "make_env", "register_task"]
