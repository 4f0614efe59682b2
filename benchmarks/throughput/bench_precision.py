"""The network arithmetic of one collected batch in each precision split, measured in interleaved rounds.

Usage::

    python benchmarks/throughput/bench_precision.py --task cassie --method ahrs [--rounds 15] [override ...]

bench_floor.py measures each variant in turn, minutes apart; on a 2-core VM two runs of one variant a minute apart
have differed by 30 % in their loss steps (benchmarks/RESULTS.md, session 36), more than the differences between the
splits. Here every split is built once in one process, and each round times each split in turn on the same
ready minibatch, so drift in the machine's speed falls on all of them alike. Per collected batch and split:

* ``loss steps``: loss forward, backward, gradient clipping and a fused Adam step on a ready minibatch (mirrored with
  ``ppo.mirror=true``), times epochs x minibatches;
* ``advantages``: ``WeightedMultiGAE`` over one batch, once per epoch (once with ``ppo.advantage_pass=once_per_batch``);
* ``acting``: the actor sampling actions for the batch's N observations, T times.

The closures are ``network_parts.py``'s, the ones bench_floor.py times.

The splits set ``model.actor_precision`` and ``model.critic_precision``: both float32, the critic alone in
bfloat16, the actor alone, both. Printed: per split, the median over rounds of each part, and its ratio to float32's.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

import torch
from hydra import compose, initialize_config_module
from network_parts import network_parts
from omegaconf import DictConfig
from tensordict import TensorDictBase

from torchrl_ahrs.app.shared.config import num_minibatches
from torchrl_ahrs.app.train.build import build_collector, build_networks, env_factory

# split name -> (actor precision, critic precision)
SPLITS = {
    "float32": ("float32", "float32"),
    "critic bf16": ("float32", "bfloat16"),
    "actor bf16": ("bfloat16", "float32"),
    "both bf16": ("bfloat16", "bfloat16"),
}


def build_parts(cfg: DictConfig, batch: TensorDictBase) -> dict[str, Callable[[], None]]:
    """The split's timed closures over one shared collected ``batch`` (a float32 TensorDict [N, T]), each the
    work of one whole batch."""
    make_envs = env_factory(cfg)
    return network_parts(cfg, make_envs, build_networks(cfg, make_envs), batch).per_batch()


def collected_batch(cfg: DictConfig) -> TensorDictBase:
    """One batch from the run's collector (float32 networks), shared by every split."""
    make_envs = env_factory(cfg)
    networks = build_networks(cfg, make_envs)
    collector = build_collector(cfg, networks.actor, make_envs)
    batch = next(iter(collector))
    collector.shutdown()
    return batch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="cassie")
    parser.add_argument("--method", default="ahrs")
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    with initialize_config_module("torchrl_ahrs.conf", version_base=None):
        base = [f"task={args.task}", f"method={args.method}", *args.overrides]
        configs = {
            name: compose("config", [*base, f"model.actor_precision={actor}", f"model.critic_precision={critic}"])
            for name, (actor, critic) in SPLITS.items()
        }
    cfg = configs["float32"]
    torch.manual_seed(0)
    torch.set_num_threads(cfg.trainer.torch_threads)
    batch = collected_batch(cfg)
    splits = {name: build_parts(split_cfg, batch.clone()) for name, split_cfg in configs.items()}
    for parts in splits.values():  # warm-up: oneDNN's kernels for each shape and dtype
        for part in parts.values():
            part()
    load_before = os.getloadavg()[0]
    times: dict[str, dict[str, list[float]]] = {s: {p: [] for p in parts} for s, parts in splits.items()}
    for _ in range(args.rounds):
        for name, parts in splits.items():
            for part, run in parts.items():
                start = time.perf_counter()
                run()
                times[name][part].append(1e3 * (time.perf_counter() - start))
    trainer = cfg.trainer
    print(
        f"task {args.task}, method {args.method}: {trainer.num_envs} envs x"
        f" {trainer.frames_per_batch // trainer.num_envs} steps, {trainer.num_epochs} epochs x {num_minibatches(cfg)}"
        f" minibatches of {trainer.mini_batch_size}{' mirrored' if cfg.ppo.get('mirror') else ''},"
        f" {list(cfg.model.hidden_sizes)} {cfg.model.activation}, torch threads {trainer.torch_threads},"
        f" {args.rounds} interleaved rounds; load average {load_before:.2f} -> {os.getloadavg()[0]:.2f}"
    )
    medians = {s: {p: statistics.median(t) for p, t in parts.items()} for s, parts in times.items()}
    parts = list(medians["float32"])
    print(f"  {'split (ms per batch)':<16}" + "".join(f"{p:>14}{'vs fp32':>9}" for p in [*parts, "sum"]))
    for name, row in medians.items():
        row = {**row, "sum": sum(row.values())}
        reference = {**medians["float32"], "sum": sum(medians["float32"].values())}
        print(f"  {name:<16}" + "".join(f"{row[p]:>14.1f}{row[p] / reference[p]:>9.2f}" for p in [*parts, "sum"]))


if __name__ == "__main__":
    main()
