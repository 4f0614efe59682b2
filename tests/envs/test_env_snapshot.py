"""An environment's ``state_dict()`` holds its running episodes: a twin built with another seed and
loaded with it continues bit for bit (every batched-MuJoCo task, through resets and time limits); an
EnvPool task has no snapshot, says so, and still saves and loads."""

import pytest
import torch
from tensordict import TensorDictBase

from torchrl_ahrs.app.shared.settings import load_task_settings
from torchrl_ahrs.envs.common.snapshot import restores_episodes
from torchrl_ahrs.envs.registry import make_env

MUJOCO_TASKS = {"point_reach": ["task.max_episode_steps=7"], "quadcopter": [], "ant": [], "cassie": []}


def step(env, carried: TensorDictBase, actions: torch.Tensor) -> tuple[TensorDictBase, list[TensorDictBase]]:
    outputs = []
    for action in actions:
        carried.set("action", action)
        out, carried = env.step_and_maybe_reset(carried)
        outputs.append(out.get("next").exclude("episode_reward").clone())
    return carried, outputs


@pytest.mark.parametrize("task", sorted(MUJOCO_TASKS))
def test_a_loaded_twin_continues_the_episodes_exactly(task):
    cfg = load_task_settings(task, MUJOCO_TASKS[task])
    env = make_env(cfg, num_envs=3, seed=0)
    assert restores_episodes(env)
    dim = env.action_spec.shape[-1]
    actions = torch.rand(30, 3, dim, generator=torch.Generator().manual_seed(0)) * 2 - 1
    carried, _ = step(env, env.reset(), actions[:12])
    snapshot, carried_then = env.state_dict(), carried.clone()
    _, expected = step(env, carried, actions[12:])

    twin = make_env(cfg, num_envs=3, seed=99)
    twin.reset()
    twin.load_state_dict(snapshot)
    _, got = step(twin, carried_then, actions[12:])
    for i, (a, b) in enumerate(zip(expected, got, strict=True)):
        assert (a == b).all(), f"step {12 + i} differs"
    assert sum(int(a["done"].sum()) for a in expected) > 0 or task != "point_reach"  # resets were crossed
    if task == "cassie":  # its host mirror of the step counters (command resampling) is restored with them
        assert (twin.base_env.resample_clock == twin.base_env.episode_steps.numpy()).all()


def test_an_envpool_task_has_no_snapshot_and_still_loads():
    pytest.importorskip("envpool")
    env = make_env(load_task_settings("ant_v5"), num_envs=2, seed=0)
    try:
        assert not restores_episodes(env)
        env.load_state_dict(env.state_dict())
    finally:
        env.close()
