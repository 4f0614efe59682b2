"""Where a training iteration's time goes: end to end against its floor (physics + bare loss steps), one run.

Usage::

    python benchmarks/throughput/bench_floor.py --task cassie [--method ppo] [--batches 10] [--warmup 2] [--runs 1] [override ...]
    python benchmarks/throughput/bench_floor.py --task cassie --variants default,once,compile,threads2,once+threads2

``--variants`` measures each variant in turn in this one process, one table each (and a summary): a variant is
a name of :data:`VARIANTS` or several joined by ``+``, its Hydra overrides after those of the command line.
``--runs N`` measures each variant N times, one after another; the summary then gives the medians over the runs
and each run's share of its floor, and from three runs on the mean share with its 95 % bootstrap interval
(rliable's, via ``reporting.intervals``). One run already gives an interval over its timed batches (below). The
summary's ``speed`` compares variants on iterations paced by :func:`metronome`, timed beside them, so that the VM's
drift between variants cancels.

Composes the config as ``python -m torchrl_ahrs.train task=<task> method=<method>`` does (the task's preset
included; extra Hydra overrides follow the flags), then runs :func:`torchrl_ahrs.app.train.iteration.train` itself
in this one process, with the run's torch thread count, and times per collected batch of N envs x T steps:

* ``end to end``: one iteration of the run, from one batch's delivery to the next (``bench_pipeline``'s
  ``TimedCollector``): its advantages, epochs, hooks and logging, then the next collection;
* ``collection``: the run's ``Collector`` delivering that next batch: physics, policy and TorchRL's per-step work;

and beside the run, as each batch arrives and off its clock (:class:`PartsBeside`, on its own copies):

* ``physics``: the run's environments (its reward components and transforms) stepped T times with uniformly
  random actions, partial resets included;
* ``policy forward``: the actor sampling actions for N collected observations, T times;
* ``advantages``: ``WeightedMultiGAE`` over one collected batch, once per epoch (as ``training/loop.py`` runs it
  with ``ppo.advantage_pass=every_epoch``; once per batch with ``once_per_batch``);
* ``loss steps``: loss forward, backward, gradient clipping and a fused Adam step on a ready minibatch of the
  run's size (with ``ppo.mirror=true``, the minibatch followed by its mirror image: twice the rows), times
  epochs x minibatches (the forward through ``torch.compile`` with ``trainer.compile=true``, compiled at the first,
  untimed batch).

The last three are ``network_parts.py``'s closures, which bench_precision.py times too.

The floor is physics + loss steps, what any PPO at this geometry and network size pays; ``rest`` is the end
to end time minus collection, advantages and loss steps: what the iteration's hooks, minibatch serving and
logging add. The parts beside the run are timed in the same seconds as the iterations they are compared with: two
samples, taken as the iteration's first batch and the next arrive, bracket each iteration, and their mean is the
iteration's. The table gives medians over the timed iterations, then each iteration's share of the floor (its
floor over its end to end) and their mean, from three iterations with its 95 % bootstrap interval. That mean is
the figure to read: the VM's drift cancels within each iteration, not between the medians of the table. (Timed
minutes apart, as before session 37, the parts moved up to twofold with the VM's speed, and a run's share with
them.)
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable
from typing import NamedTuple

import torch
from bench_pipeline import rates, train_with_timed_collector
from hydra import compose, initialize_config_module
from network_parts import network_parts
from tensordict import TensorDictBase

from torchrl_ahrs.app.shared.config import collection_threads, network_precision, num_minibatches
from torchrl_ahrs.app.train.build import build_networks, env_factory
from torchrl_ahrs.reporting.intervals import mean_interval
from torchrl_ahrs.training.models import compute_dtype, precision_name

# what --variants accepts: a name -> the Hydra overrides it adds (names join with "+": once+threads2)
VARIANTS: dict[str, list[str]] = {
    "default": [],  # the composed config as it is
    "once": ["ppo.advantage_pass=once_per_batch"],  # advantages once per batch instead of once per epoch
    "compile": ["trainer.compile=true"],  # the loss's forward through torch.compile (inductor)
    "threads1": ["trainer.torch_threads=1"],
    "threads2": ["trainer.torch_threads=2"],  # a second intra-op thread for the networks
    "collect1": ["trainer.collection_threads=1"],  # one torch thread while collecting, the others for the update
    "collect2": ["trainer.collection_threads=2"],
    "half": ["model.hidden_sizes=[256,128,64]"],  # half of every width of Cassie's [512, 256, 128] (RESULTS round 21)
    # half of the K heads' widths only; the anchor (PPO's critic) keeps its own (RESULTS, session 39)
    "heads_half": ["model.component_hidden_sizes=[256,128,64]"],
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
        >>> variant_overrides("fast")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: unknown variant 'fast'; known: default, once, compile, ... (join with +)
    """
    overrides = []
    for name in variant.split("+"):
        if name not in VARIANTS:
            raise ValueError(f"unknown variant {name!r}; known: {', '.join(VARIANTS)} (join with +)")
        overrides += VARIANTS[name]
    return overrides


def metronome(size: int = 256, products: int = 20) -> None:
    """Work no variant changes, timed beside each batch on one torch thread: ``products`` float32 products of two
    ``[size, size]`` matrices (~7 ms on a 2-core EPYC). Variants measured minutes apart compare iterations paced by
    it, and the physics no longer serves: a variant may change the collection's threads, and so the physics."""
    matrix = torch.ones(size, size)
    for _ in range(products):
        matrix = torch.mm(matrix, matrix).clamp_(max=1.0)  # stays finite: the same arithmetic every time


class PartsBeside:
    """The parts of an iteration timed beside each batch of the end-to-end run, off its clock.

    Called with each batch as it arrives (:class:`bench_pipeline.TimedCollector`'s ``beside``), it times once each:
    ``physics``, its own copy of the run's environments stepped T times with random actions; ``acting``, the actor
    sampling actions for N observations, T times; ``advantages``, the run's advantage passes over a batch; and
    ``loss steps``, epochs x minibatches loss steps on a ready minibatch. The networks are its own, built with the
    environments at the first batch, whose clone serves the network parts throughout.

    Timing the parts in the same seconds as the iterations they are compared with keeps the shares immune to the VM's
    drift in speed, which moved parts timed minutes apart by up to twofold (benchmarks/RESULTS.md, session 37).
    ``samples[part]`` holds one time per batch, in milliseconds; ``labels[part]`` names the part's row.
    ``samples["metronome"]`` times :func:`metronome` beside each batch too: work no variant changes, against which
    variants measured minutes apart compare their speed.
    """

    def __init__(self, cfg):
        self.cfg = cfg
        self.samples: dict[str, list[float]] = {}
        self.labels: dict[str, str] = {}
        self._parts: dict[str, tuple[Callable[[], None], int]] = {}  # part -> (its closure, its torch threads)

    def _build(self, batch: TensorDictBase) -> None:
        cfg = self.cfg
        steps = cfg.trainer.frames_per_batch // cfg.trainer.num_envs  # T
        make_envs = env_factory(cfg)
        env = make_envs(cfg.trainer.num_envs, int(cfg.seed) + 1)
        state = env.reset()

        def physics() -> None:
            nonlocal state
            for _ in range(steps):
                _, state = env.step_and_maybe_reset(env.rand_action(state))

        work = network_parts(cfg, make_envs, build_networks(cfg, make_envs), batch.clone())
        # each part on the torch threads the run gives it: physics and acting those of its collection, the network
        # work those of its update; the metronome always one
        collecting, updating = collection_threads(cfg.trainer), cfg.trainer.torch_threads
        network = work.per_batch()
        self._parts = {
            "physics": (physics, collecting),
            "acting": (network["acting"], collecting),
            "advantages": (network["advantages"], updating),
            "loss steps": (network["loss steps"], updating),
            "metronome": (metronome, 1),
        }
        passes = work.advantage_passes_per_batch
        self.labels = {
            "physics": "physics (random actions)",
            "acting": "policy forward (collection)",
            "advantages": f"advantages (x {passes} {'epochs' if passes == cfg.trainer.num_epochs else 'pass'})",
            "loss steps": f"loss steps (x {work.loss_steps_per_batch}{', mirrored' if work.mirrored else ''})",
        }
        self.samples = {part: [] for part in self._parts}

    def __call__(self, batch: TensorDictBase) -> None:
        if not self._parts:
            self._build(batch)
        threads = torch.get_num_threads()
        for part, (run, part_threads) in self._parts.items():
            torch.set_num_threads(part_threads)
            start = time.perf_counter()
            run()
            self.samples[part].append(1e3 * (time.perf_counter() - start))
        torch.set_num_threads(threads)


class Measured(NamedTuple):
    """One run of one variant: medians over its timed iterations, and means of per-iteration ratios."""

    floor: float  # [ms per batch]
    end_to_end: float  # [ms per batch]
    share: float  # mean over iterations of floor / end to end
    paced: float  # mean over iterations of end to end / the metronome beside it: a drift-free pace


def measure(cfg, task: str, method: str, variant: str, args: argparse.Namespace) -> Measured:
    """Prints the table of one variant (``cfg`` composed with its overrides) and returns its figures."""
    trainer = cfg.trainer
    # warm-up + timed batches, plus the untimed first and last batches
    trainer.total_frames = (args.batches + args.warmup + 2) * trainer.frames_per_batch
    torch.manual_seed(args.seed)
    torch.set_num_threads(trainer.torch_threads)
    load_before = os.getloadavg()
    beside = PartsBeside(cfg)
    timed = train_with_timed_collector(cfg, beside)
    stamps = timed.stamps[:-1]  # the last batch's collection carries the collector's teardown
    _, cpu_ms_per_frame = rates(stamps, trainer.frames_per_batch, args.warmup)
    # iteration i runs from batch i's stamp to batch i + 1's: its update, then the next collection. The parts are
    # timed as each batch arrives, so two samples bracket each iteration: their mean is the iteration's
    iterations = range(args.warmup, len(stamps) - 1)
    end_to_end = [1e3 * (stamps[i + 1][0] - stamps[i][0]) for i in iterations]
    collection = [1e3 * timed.collecting[i + 1] for i in iterations]
    parts = {part: [(ms[i] + ms[i + 1]) / 2 for i in iterations] for part, ms in beside.samples.items()}
    floor = [physics + loss for physics, loss in zip(parts["physics"], parts["loss steps"], strict=True)]
    shares = [floor_ms / end_ms for floor_ms, end_ms in zip(floor, end_to_end, strict=True)]
    median = {part: statistics.median(ms) for part, ms in parts.items()}
    rows = {
        beside.labels["physics"]: median["physics"],
        beside.labels["acting"]: median["acting"],
        "collection (Collector, policy acting)": statistics.median(collection),
        beside.labels["advantages"]: median["advantages"],
        beside.labels["loss steps"]: median["loss steps"],
        "floor = physics + loss steps": statistics.median(floor),
        "end to end (train)": statistics.median(end_to_end),
    }
    # the rest: what an iteration spends outside collection, advantages and loss steps (physics and acting are
    # inside collection)
    outside = ["collection (Collector, policy acting)", beside.labels["advantages"], beside.labels["loss steps"]]
    rows["rest (hooks, minibatches, logging)"] = rows["end to end (train)"] - sum(rows[name] for name in outside)
    model = cfg.model
    overrides = " ".join(variant_overrides(variant)) or "no overrides"
    print(
        f"task {task}, method {method}, variant {variant} ({overrides}): {trainer.num_envs} envs x"
        f" {trainer.frames_per_batch // trainer.num_envs} steps = {trainer.frames_per_batch} frames per batch,"
        f" {trainer.num_epochs} epochs x {num_minibatches(cfg)} minibatches of {trainer.mini_batch_size},"
        f" {list(model.hidden_sizes)} {model.activation}, actor in"
        f" {precision_name(compute_dtype(network_precision(model, 'actor')))}, critic in"
        f" {precision_name(compute_dtype(network_precision(model, 'critic')))},"
        f" torch threads {trainer.torch_threads} ({collection_threads(trainer)} collecting);"
        f" load average {load_before[0]:.2f} -> {os.getloadavg()[0]:.2f}"
    )
    end_ms = rows["end to end (train)"]
    print(f"  {'part (median of the timed iterations)':42s} {'ms/batch':>9s} {'frames/s':>9s} {'of end to end':>14s}")
    for name, milliseconds in rows.items():
        rate = 1e3 * trainer.frames_per_batch / milliseconds if milliseconds > 0 else float("nan")
        print(f"  {name:42s} {milliseconds:9.1f} {rate:9.0f} {milliseconds / end_ms:13.0%}")
    print(f"  end-to-end CPU time: {cpu_ms_per_frame:.3f} ms per frame (all threads)")
    # each iteration against the floor timed in its own seconds: the VM's drift cancels in each share
    print(f"  of floor, each timed iteration: {' '.join(f'{share:.0%}' for share in shares)}")
    mean_share = statistics.fmean(shares)
    interval = ""
    if len(shares) >= 3:
        _, low, high = mean_interval(shares)
        interval = f", 95 % bootstrap interval [{low:.0%}, {high:.0%}]"
    print(f"  of floor over the iterations: mean {mean_share:.0%}{interval}")
    # the iteration in units of the metronome timed in its own seconds: variants measured minutes apart compare on
    # this (the same work in every variant: a variant may change the physics' threads), where their frames/s would
    # carry the VM's drift
    paced = statistics.fmean(end / beat for end, beat in zip(end_to_end, parts["metronome"], strict=True))
    return Measured(rows["floor = physics + loss steps"], end_ms, mean_share, paced)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--method", default="ppo")
    parser.add_argument("--batches", type=int, default=10, help="timed batches of the end-to-end run")
    parser.add_argument(
        "--warmup", type=int, default=2, help="batches of the end-to-end run left out of its timing (at least 1)"
    )
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
    if args.warmup < 1:  # the first floor sample carries the floor's own warm-up (and compiling, where compiled)
        parser.error(f"--warmup must be at least 1, got {args.warmup}")
    variants = [variant.strip() for variant in args.variants.split(",") if variant.strip()]
    for variant in variants:  # every name checked before the first (minutes long) measurement
        try:
            variant_overrides(variant)
        except ValueError as error:
            parser.error(str(error))
    overrides = [f"task={args.task}", f"method={args.method}", f"seed={args.seed}", *args.overrides]
    overrides += ["trainer.progress_bar=false", "checkpoint.interval=0", "logger.backends=[csv]"]
    results: dict[str, tuple[list[Measured], int]] = {}  # variant -> (its runs, frames per batch)
    for variant in variants:
        with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
            cfg = compose(config_name="config", overrides=[*overrides, *variant_overrides(variant)])
        runs = [measure(cfg, args.task, args.method, variant, args) for _ in range(args.runs)]
        results[variant] = (runs, cfg.trainer.frames_per_batch)
    if len(results) > 1 or args.runs > 1:  # one line per variant: medians over its runs
        first = results[variants[0]][0]
        first_floor = statistics.median(run.floor for run in first)
        first_paced = statistics.median(run.paced for run in first)
        print(
            f"variants side by side (medians of {args.runs} run(s); of its own floor, of {variants[0]}'s, and its"
            f" speed against {variants[0]}'s, each iteration timed against a fixed matrix product beside it)"
        )
        print(
            f"  {'variant':34s} {'end to end ms':>13s} {'frames/s':>9s} {'floor ms':>9s} {'of floor':>9s} {'of first':>9s}"
            f" {'speed':>6s}  of floor, each run"
        )
        intervals = {}
        for variant, (runs, frames) in results.items():
            end_to_end = statistics.median(run.end_to_end for run in runs)
            floor = statistics.median(run.floor for run in runs)
            shares = [run.share for run in runs]  # each run's mean share over its iterations
            speed = first_paced / statistics.median(run.paced for run in runs)
            print(
                f"  {variant:34s} {end_to_end:13.1f} {1e3 * frames / end_to_end:9.0f} {floor:9.1f}"
                f" {statistics.median(shares):9.0%} {first_floor / end_to_end:9.0%} {speed:5.2f}x"
                f"  {' '.join(f'{share:.0%}' for share in shares)}"
            )
            # say how well the mean over runs is known
            if len(shares) >= 3:
                intervals[variant] = mean_interval(shares)
        for variant, (mean, low, high) in intervals.items():
            print(f"  {variant}: of floor, mean over runs {mean:.0%}, 95 % bootstrap interval [{low:.0%}, {high:.0%}]")


if __name__ == "__main__":
    main()
