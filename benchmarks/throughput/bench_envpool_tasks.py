"""Throughput of the EnvPool-backed tasks: raw EnvPool, our TorchRL env, and a TorchRL Collector over it.

Three numbers per task (steps/s = env steps summed over the N envs, uniform random actions):
``raw`` steps ``envpool.make(...)`` directly; ``rollout`` is ``make_env(task).rollout`` (EnvPoolEnv,
reward components, episode-return tracking); ``collector`` is ``torchrl.collectors.Collector`` on it.

Run: ``python benchmarks/throughput/bench_envpool_tasks.py --tasks ant_v5 dmc_walker_walk --num-envs 64``
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from torchrl.collectors import Collector

from torchrl_ahrs.app.shared.settings import load_task_settings
from torchrl_ahrs.envs.registry import make_env

TASKS = [
    "ant_v5",
    "humanoid",
    "go1_terrain",
    "leap_cube",
    "shadow_hand",
    "dmc_walker_walk",
    "dmc_quadruped_run",
    "dmc_cheetah_run",
]


def bench_task(task: str, num_envs: int, steps: int) -> dict[str, float]:
    """``{"raw": ..., "rollout": ..., "collector": ...}`` in steps/s for one task."""
    import envpool

    cfg = load_task_settings(task)
    raw = envpool.make(cfg.env_id, env_type="gymnasium", num_envs=num_envs, seed=0)
    raw.reset()
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, num_envs, *raw.action_space.shape))
    actions = actions.astype(np.float32)
    start = time.perf_counter()
    for action in actions:
        raw.step(action)
    result = {"raw": num_envs * steps / (time.perf_counter() - start)}
    raw.close()

    env = make_env(cfg, num_envs=num_envs, seed=0)
    torch.manual_seed(0)
    env.rollout(5, break_when_any_done=False)  # warm-up
    start = time.perf_counter()
    env.rollout(steps, break_when_any_done=False)
    result["rollout"] = num_envs * steps / (time.perf_counter() - start)

    frames = num_envs * max(steps // 4, 1)
    collector = Collector(env, policy=None, frames_per_batch=frames, total_frames=frames * 5)
    batches = iter(collector)
    next(batches)  # warm-up
    start = time.perf_counter()
    for _ in range(4):
        next(batches)
    result["collector"] = 4 * frames / (time.perf_counter() - start)
    collector.shutdown()
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=TASKS)
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--steps", type=int, default=200)
    args = parser.parse_args()
    print(f"{'task':20s} {'raw':>10s} {'rollout':>10s} {'collector':>10s}   steps/s, N={args.num_envs}")
    for task in args.tasks:
        r = bench_task(task, args.num_envs, args.steps)
        print(f"{task:20s} {r['raw']:10.0f} {r['rollout']:10.0f} {r['collector']:10.0f}")


if __name__ == "__main__":
    main()
