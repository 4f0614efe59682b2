"""MJX backend against the threaded MuJoCo backend: env steps/s and end-to-end training frames/s over N.

For each N and backend (``task.backend=cpu`` / ``mjx``) on whatever JAX device is present:

* env steps/s: ``steps`` batched steps under uniform random actions with TorchRL partial resets, after
  ``warmup`` steps (the first MJX step at a new N carries the XLA compile, reported apart as ``compile s``);
* training frames/s (``--train-batches`` > 0): ``torchrl_ahrs.app.train.iteration.train`` (PPO, the task's reward
  components) with frames_per_batch = N × ``rollout_steps``, timed over the batches after the first.

``--device`` is ``trainer.device`` (default: the simulation's, so MJX on a GPU keeps env and learner there):
the MJX env is built on it, the CPU backend's outputs are moved to it each step, and training runs its learner
on it (a CPU backend then hands each step's data over through the collector).

Run (CPU, brief): ``python benchmarks/throughput/bench_mjx.py --task cassie --num-envs 64 1024 4096 --steps 5``
GPU: see benchmarks/RESULTS.md (``JAX_PLATFORMS=cuda``, ``--device cuda``).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import torch
from bench_env_throughput import time_torchrl_env
from bench_pipeline import TimedCollector, rates
from hydra import compose, initialize_config_module

from torchrl_ahrs.app.shared.settings import load_task_settings
from torchrl_ahrs.envs.registry import make_env, simulation_device


def env_rate(
    task: str, backend: str, num_envs: int, steps: int, threads: int, device: str | None
) -> tuple[float, float, float]:
    """(env steps/s, CPU µs per env step, seconds to build the env and take its first step)."""
    start = time.perf_counter()
    task_cfg = load_task_settings(task, [f"task.backend={backend}", f"task.num_threads={threads}"])
    env = make_env(task_cfg, num_envs, 0, device or simulation_device(task_cfg.backend))
    env.rand_step(env.reset())  # builds, resets and compiles (MJX) before the clock starts
    first = time.perf_counter() - start
    rate, cpu_us = time_torchrl_env(env, steps, warmup=2)
    env.close()
    return rate, cpu_us, first


def train_rate(task: str, backend: str, num_envs: int, rollout_steps: int, batches: int, device: str | None) -> float:
    """Training frames/s of the whole PPO iteration (collect + GAE + update), batches after the first, with
    ``trainer.device=device`` (None: the simulation's device)."""
    import torchrl_ahrs.app.train.iteration as training

    timed: list[TimedCollector] = []
    build_collector = training.build_collector

    def make_timed_collector(*a, **kw):
        timed.append(TimedCollector(build_collector(*a, **kw)))
        return timed[-1]

    frames_per_batch = num_envs * rollout_steps
    overrides = [
        f"task={task}",
        f"task.backend={backend}",
        f"trainer.num_envs={num_envs}",
        f"trainer.frames_per_batch={frames_per_batch}",
        f"trainer.total_frames={frames_per_batch * (batches + 2)}",
        f"trainer.mini_batch_size={frames_per_batch // 4}",
        "trainer.progress_bar=false",
        "checkpoint.interval=0",
        *([f"trainer.device={device}"] if device else []),
    ]
    with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    training.build_collector = make_timed_collector
    try:
        with tempfile.TemporaryDirectory() as run_dir:
            training.train(cfg, Path(run_dir))
    finally:
        training.build_collector = build_collector
    return rates(timed[0].stamps[:-1], frames_per_batch, warmup=1)[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="cassie", choices=["cassie", "ant", "quadcopter"])
    parser.add_argument("--num-envs", type=int, nargs="+", default=[64, 1024, 4096, 16384])
    parser.add_argument("--backends", nargs="+", default=["cpu", "mjx"], choices=["cpu", "mjx"])
    parser.add_argument("--steps", type=int, default=20, help="batched env steps timed per measurement")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="CPU backend stepping threads")
    parser.add_argument("--train-batches", type=int, default=0, help="timed training batches (0: env steps only)")
    parser.add_argument("--rollout-steps", type=int, default=8, help="T: frames_per_batch = N x T when training")
    parser.add_argument("--device", default=None, help="trainer.device (default: the simulation's device)")
    args = parser.parse_args()
    import jax

    load = os.getloadavg()
    print(
        f"task={args.task} JAX device={jax.devices()[0]} torch threads={torch.get_num_threads()} "
        f"cpu threads={args.threads} steps={args.steps} load={load[0]:.2f},{load[1]:.2f},{load[2]:.2f}"
    )
    print("| N | backend | env steps/s | CPU µs/env step | build + first step s | train frames/s |")
    print("|---|---|---|---|---|---|")
    for n in args.num_envs:
        for backend in args.backends:
            rate, cpu_us, first = env_rate(args.task, backend, n, args.steps, args.threads, args.device)
            trained = "—"
            if args.train_batches:
                frames = train_rate(args.task, backend, n, args.rollout_steps, args.train_batches, args.device)
                trained = f"{frames:.0f}"
            print(f"| {n} | {backend} | {rate:.0f} | {cpu_us:.1f} | {first:.1f} | {trained} |", flush=True)
    load = os.getloadavg()
    print(f"load at the end: {load[0]:.2f},{load[1]:.2f},{load[2]:.2f}")


if __name__ == "__main__":
    main()
