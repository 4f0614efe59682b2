"""Where a training iteration's time goes: end to end against its floor (physics + bare loss steps), one run.

Usage::

    python benchmarks/throughput/bench_floor.py --task cassie [--method ppo] [--batches 10] [--warmup 2] [override ...]

Composes the config as ``python -m torchrl_ahrs.train task=<task> method=<method>`` does (the task's preset
included; extra Hydra overrides follow the flags), then measures in this one process, with the run's torch
thread count and per collected batch of N envs x T steps:

* ``end to end``: :func:`torchrl_ahrs.app.train.iteration.train` itself, timed between batch deliveries after the
  warm-up batches (``bench_pipeline.timed_train``): collection, advantages, epochs, hooks, logging;
* ``physics``: the run's environments (its reward components and transforms) stepped T times with uniformly
  random actions, partial resets included;
* ``policy forward``: the actor sampling actions for N observations, T times;
* ``collection``: the run's ``Collector`` delivering a batch: physics, policy and TorchRL's per-step work;
* ``advantages``: ``WeightedMultiGAE`` over one collected batch, once per epoch (as ``training/loop.py`` runs it);
* ``loss steps``: loss forward, backward, gradient clipping and a fused Adam step on a ready minibatch of the
  run's size, times epochs x minibatches.

The floor is physics + loss steps, what any PPO at this geometry and network size pays; ``rest`` is the end
to end time minus collection, advantages and loss steps: what the iteration's hooks, minibatch serving and
logging add. Times are medians of repeats.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import torch
from bench_pipeline import rates, timed_train
from hydra import compose, initialize_config_module
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_ahrs.app.shared.config import num_minibatches
from torchrl_ahrs.app.train.build import build_collector, build_estimator_and_loss, build_networks, env_factory
from torchrl_ahrs.training.loop import MINIBATCH_KEYS


def median_ms(fn, repeats: int, warmup: int = 2) -> float:
    """Median wall time of ``fn()`` in milliseconds over ``repeats`` calls, after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def floor_parts(cfg, repeats: int) -> dict[str, float]:
    """Milliseconds per collected batch of each part of an iteration, measured apart (see the module docstring)."""
    trainer = cfg.trainer
    num_envs, frames_per_batch = trainer.num_envs, trainer.frames_per_batch
    steps = frames_per_batch // num_envs  # T
    make_envs = env_factory(cfg)
    networks = build_networks(cfg, make_envs)
    estimator, loss = build_estimator_and_loss(cfg, networks, make_envs.components)

    env = make_envs(num_envs, int(cfg.seed))
    state = env.reset()

    def physics() -> None:
        nonlocal state
        for _ in range(steps):
            _, state = env.step_and_maybe_reset(env.rand_action(state))

    observations = state.select(*networks.actor.in_keys).clone()

    def policy_forward() -> None:
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            for _ in range(steps):
                networks.actor(observations.clone(False))

    parts = {"physics (random actions)": median_ms(physics, repeats)}
    parts["policy forward (collection)"] = median_ms(policy_forward, repeats)
    env.close()

    collector = build_collector(cfg, networks.actor, make_envs)
    batches = iter(collector)
    batch: TensorDictBase = next(batches)

    def collection() -> None:
        nonlocal batch
        batch = next(batches)

    parts["collection (Collector, policy acting)"] = median_ms(collection, repeats, warmup=0)
    collector.shutdown()

    def advantages() -> None:
        with torch.no_grad():
            estimator(batch)

    parts[f"advantages (x {trainer.num_epochs} epochs)"] = trainer.num_epochs * median_ms(advantages, repeats)
    keys = [*loss.in_keys, *MINIBATCH_KEYS]  # what training/loop.py gathers into minibatches
    minibatch = batch.reshape(-1)[: trainer.mini_batch_size].select(*keys, strict=False)
    optimizer = torch.optim.Adam(loss.parameters(), lr=1e-5, eps=1e-5, fused=True)  # as train() builds it

    def loss_step() -> None:
        losses = loss(minibatch)
        sum(value for key, value in losses.items() if key.startswith("loss_")).backward()
        torch.nn.utils.clip_grad_norm_(loss.parameters(), trainer.max_grad_norm)
        optimizer.step()
        optimizer.zero_grad()

    steps_per_batch = trainer.num_epochs * num_minibatches(cfg)
    parts[f"loss steps (x {steps_per_batch})"] = steps_per_batch * median_ms(loss_step, 10 * repeats, warmup=10)
    return parts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--method", default="ppo")
    parser.add_argument("--batches", type=int, default=10, help="timed batches of the end-to-end run")
    parser.add_argument("--warmup", type=int, default=2, help="batches of the end-to-end run left out of its timing")
    parser.add_argument("--repeats", type=int, default=5, help="repeats of each part (loss steps: 10x as many)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. trainer.torch_threads=2")
    args = parser.parse_args()
    overrides = [f"task={args.task}", f"method={args.method}", f"seed={args.seed}", *args.overrides]
    overrides += ["trainer.progress_bar=false", "checkpoint.interval=0", "logger.backends=[csv]"]
    with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    trainer = cfg.trainer
    # warm-up + timed batches, plus the untimed first and last batches (timed_train drops the last)
    trainer.total_frames = (args.batches + args.warmup + 2) * trainer.frames_per_batch
    torch.manual_seed(args.seed)
    torch.set_num_threads(trainer.torch_threads)
    load_before = os.getloadavg()
    parts = floor_parts(cfg, args.repeats)
    fps, cpu_ms_per_frame = rates(timed_train(cfg), trainer.frames_per_batch, args.warmup)
    end_to_end = 1e3 * trainer.frames_per_batch / fps
    floor = parts["physics (random actions)"] + next(v for k, v in parts.items() if k.startswith("loss steps"))
    model = cfg.model
    print(
        f"task {args.task}, method {args.method}: {trainer.num_envs} envs x {trainer.frames_per_batch // trainer.num_envs}"
        f" steps = {trainer.frames_per_batch} frames per batch, {trainer.num_epochs} epochs x {num_minibatches(cfg)}"
        f" minibatches of {trainer.mini_batch_size}, {list(model.hidden_sizes)} {model.activation},"
        f" torch threads {trainer.torch_threads}; load average {load_before[0]:.2f} -> {os.getloadavg()[0]:.2f}"
    )
    rows = [*parts.items(), ("floor = physics + loss steps", floor), ("end to end (train)", end_to_end)]
    # physics and the policy's forward pass are inside collection
    outside = sum(ms for name, ms in parts.items() if not name.startswith(("physics", "policy")))
    rows.append(("rest (hooks, minibatches, logging)", end_to_end - outside))
    print(f"  {'part':42s} {'ms/batch':>9s} {'frames/s':>9s} {'of end to end':>14s}")
    for name, milliseconds in rows:
        rate = 1e3 * trainer.frames_per_batch / milliseconds if milliseconds > 0 else float("nan")
        print(f"  {name:42s} {milliseconds:9.1f} {rate:9.0f} {milliseconds / end_to_end:13.0%}")
    print(f"  end-to-end CPU time: {cpu_ms_per_frame:.3f} ms per frame (all threads)")


if __name__ == "__main__":
    main()
