"""Where a training iteration's time goes: end to end against its floor (physics + bare loss steps), one run.

Usage::

    python benchmarks/throughput/bench_floor.py --task cassie [--method ppo] [--batches 10] [--warmup 2] [--runs 1] [override ...]
    python benchmarks/throughput/bench_floor.py --task cassie --variants default,once,compile,threads2,once+threads2

``--variants`` measures each variant in turn in this one process, one table each (and a summary): a variant is
a name of :data:`VARIANTS` or several joined by ``+``, its Hydra overrides after those of the command line.
``--runs N`` measures each variant N times, one after another; the summary then gives the medians over the runs
and each run's share of its floor (two runs a minute apart have differed by 17 points: benchmarks/RESULTS.md), and
from three runs on the mean share with its 95 % bootstrap interval (rliable's, via ``reporting.intervals``).

Composes the config as ``python -m torchrl_ahrs.train task=<task> method=<method>`` does (the task's preset
included; extra Hydra overrides follow the flags), then measures in this one process, with the run's torch
thread count and per collected batch of N envs x T steps:

* ``end to end``: :func:`torchrl_ahrs.app.train.iteration.train` itself, timed between batch deliveries after the
  warm-up batches (``bench_pipeline.timed_train``): collection, advantages, epochs, hooks, logging;
* ``physics``: the run's environments (its reward components and transforms) stepped T times with uniformly
  random actions, partial resets included;
* ``policy forward``: the actor sampling actions for N observations, T times;
* ``collection``: the run's ``Collector`` delivering a batch: physics, policy and TorchRL's per-step work;
* ``advantages``: ``WeightedMultiGAE`` over one collected batch, once per epoch (as ``training/loop.py`` runs it
  with ``ppo.advantage_pass=every_epoch``; once per batch with ``once_per_batch``);
* ``loss steps``: loss forward, backward, gradient clipping and a fused Adam step on a ready minibatch of the
  run's size (with ``ppo.mirror=true``, the minibatch followed by its mirror image: twice the rows), times
  epochs x minibatches (the forward through ``torch.compile`` with ``trainer.compile=true``,
  compiled in the untimed warm-up).

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

from torchrl_ahrs.app.shared.config import network_precision, num_minibatches
from torchrl_ahrs.app.train.build import (
    build_collector,
    build_estimator_and_loss,
    build_mirror,
    build_networks,
    env_factory,
)
from torchrl_ahrs.reporting.intervals import mean_interval
from torchrl_ahrs.training.loop import MINIBATCH_KEYS
from torchrl_ahrs.training.models import compute_dtype, precision_name

# what --variants accepts: a name -> the Hydra overrides it adds (names join with "+": once+threads2)
VARIANTS: dict[str, list[str]] = {
    "default": [],  # the composed config as it is
    "once": ["ppo.advantage_pass=once_per_batch"],  # advantages once per batch instead of once per epoch
    "compile": ["trainer.compile=true"],  # the loss's forward through torch.compile (inductor)
    "threads1": ["trainer.torch_threads=1"],
    "threads2": ["trainer.torch_threads=2"],  # a second intra-op thread for the networks
    "half": ["model.hidden_sizes=[256,128,64]"],  # half of every width of Cassie's [512, 256, 128] (RESULTS round 21)
    # the hidden layers' matrix products in bfloat16 (training/models.py, AutocastMLP), and in float32
    "bf16": ["model.precision=bfloat16"],
    "fp32": ["model.precision=float32"],
    "bf16_critic": ["model.actor_precision=float32", "model.critic_precision=bfloat16"],  # the critic's alone
    "bf16_actor": ["model.actor_precision=bfloat16", "model.critic_precision=float32"],  # the actor's alone
}


def variant_overrides(variant: str) -> list[str]:
    """The Hydra overrides of ``variant`` (names of :data:`VARIANTS` joined by ``+``).

    Example:
        >>> variant_overrides("once+threads2")
        ['ppo.advantage_pass=once_per_batch', 'trainer.torch_threads=2']
        >>> variant_overrides("fast")
        Traceback (most recent call last):
        ...
        ValueError: unknown variant 'fast'; known: default, once, compile, threads1, threads2, half, bf16, fp32 (join with +)
    """
    overrides = []
    for name in variant.split("+"):
        if name not in VARIANTS:
            raise ValueError(f"unknown variant {name!r}; known: {', '.join(VARIANTS)} (join with +)")
        overrides += VARIANTS[name]
    return overrides


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

    passes = 1 if cfg.ppo.get("advantage_pass", "every_epoch") == "once_per_batch" else trainer.num_epochs
    parts[f"advantages (x {passes} {'epochs' if passes == trainer.num_epochs else 'pass'})"] = passes * median_ms(
        advantages, repeats
    )
    keys = [*loss.in_keys, *MINIBATCH_KEYS]  # what training/loop.py gathers into minibatches
    minibatch = batch.reshape(-1)[: trainer.mini_batch_size].select(*keys, strict=False)
    augment = build_mirror(cfg, make_envs.task, loss, networks.critic_key)
    if augment is not None:  # ppo.mirror: the loss trains on the minibatch and its image, as any symmetric PPO does
        minibatch = augment(minibatch)  # made once, untimed: the floor is the loss on the ready, twice-sized minibatch
    optimizer = torch.optim.Adam(loss.parameters(), lr=1e-5, eps=1e-5, fused=True)  # as train() builds it
    loss_forward = torch.compile(loss) if trainer.get("compile", False) else loss  # as training/loop.py calls it

    def loss_step() -> None:
        losses = loss_forward(minibatch)
        sum(value for key, value in losses.items() if key.startswith("loss_")).backward()
        torch.nn.utils.clip_grad_norm_(loss.parameters(), trainer.max_grad_norm)
        optimizer.step()
        optimizer.zero_grad()

    steps_per_batch = trainer.num_epochs * num_minibatches(cfg)
    name = f"loss steps (x {steps_per_batch}{', mirrored' if augment is not None else ''})"
    parts[name] = steps_per_batch * median_ms(loss_step, 10 * repeats, warmup=10)
    return parts


def measure(cfg, task: str, method: str, variant: str, args: argparse.Namespace) -> tuple[float, float]:
    """Prints the table of one variant (``cfg`` composed with its overrides); returns (floor, end to end) [ms]."""
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
    overrides = " ".join(variant_overrides(variant)) or "no overrides"
    print(
        f"task {task}, method {method}, variant {variant} ({overrides}): {trainer.num_envs} envs x"
        f" {trainer.frames_per_batch // trainer.num_envs} steps = {trainer.frames_per_batch} frames per batch,"
        f" {trainer.num_epochs} epochs x {num_minibatches(cfg)} minibatches of {trainer.mini_batch_size},"
        f" {list(model.hidden_sizes)} {model.activation}, actor in"
        f" {precision_name(compute_dtype(network_precision(model, 'actor')))}, critic in"
        f" {precision_name(compute_dtype(network_precision(model, 'critic')))},"
        f" torch threads {trainer.torch_threads};"
        f" load average {load_before[0]:.2f} -> {os.getloadavg()[0]:.2f}"
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
    return floor, end_to_end


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--method", default="ppo")
    parser.add_argument("--batches", type=int, default=10, help="timed batches of the end-to-end run")
    parser.add_argument("--warmup", type=int, default=2, help="batches of the end-to-end run left out of its timing")
    parser.add_argument("--repeats", type=int, default=5, help="repeats of each part (loss steps: 10x as many)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--runs", type=int, default=1, help="measurements of each variant, one after another; the summary gives medians"
    )
    parser.add_argument(
        "--variants",
        default="default",
        help=f"comma-separated variants measured in turn, each a name or names joined by +: {', '.join(VARIANTS)}",
    )
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. trainer.torch_threads=2")
    args = parser.parse_args()
    variants = [variant.strip() for variant in args.variants.split(",") if variant.strip()]
    for variant in variants:  # every name checked before the first (minutes long) measurement
        try:
            variant_overrides(variant)
        except ValueError as error:
            parser.error(str(error))
    overrides = [f"task={args.task}", f"method={args.method}", f"seed={args.seed}", *args.overrides]
    overrides += ["trainer.progress_bar=false", "checkpoint.interval=0", "logger.backends=[csv]"]
    results: dict[str, tuple[list[tuple[float, float]], int]] = {}  # variant -> ([(floor, end to end)] per run, frames)
    for variant in variants:
        with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
            cfg = compose(config_name="config", overrides=[*overrides, *variant_overrides(variant)])
        runs = [measure(cfg, args.task, args.method, variant, args) for _ in range(args.runs)]
        results[variant] = (runs, cfg.trainer.frames_per_batch)
    if len(results) > 1 or args.runs > 1:  # one line per variant: medians over its runs; "of floor": floor / end to end
        first_floor = statistics.median(floor for floor, _ in results[variants[0]][0])
        print(f"variants side by side (medians of {args.runs} run(s); of its own floor, and of {variants[0]}'s)")
        print(
            f"  {'variant':34s} {'end to end ms':>13s} {'frames/s':>9s} {'floor ms':>9s} {'of floor':>9s} {'of first':>9s}"
            "  of floor, each run"
        )
        intervals = {}
        for variant, (runs, frames) in results.items():
            end_to_end = statistics.median(end for _, end in runs)
            floor = statistics.median(floor for floor, _ in runs)
            shares = [floor_ms / end_ms for floor_ms, end_ms in runs]
            print(
                f"  {variant:34s} {end_to_end:13.1f} {1e3 * frames / end_to_end:9.0f} {floor:9.1f}"
                f" {statistics.median(shares):9.0%} {first_floor / end_to_end:9.0%}"
                f"  {' '.join(f'{share:.0%}' for share in shares)}"
            )
            # runs of one variant scatter by up to 30 points on a shared 2-core VM: say how well the mean is known
            if len(shares) >= 3:
                intervals[variant] = mean_interval(shares)
        for variant, (mean, low, high) in intervals.items():
            print(f"  {variant}: of floor, mean over runs {mean:.0%}, 95 % bootstrap interval [{low:.0%}, {high:.0%}]")


if __name__ == "__main__":
    main()
