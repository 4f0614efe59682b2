"""Per-minibatch cost of the PPO update: the bare loss step against what the training loop adds.

Usage::

    python benchmarks/throughput/bench_minibatch_overhead.py [--minibatch 64] [--steps 200]

Builds the ant_v5 actor/critic/loss exactly as ``train.py`` does, collects one real batch (64 envs x
32 steps), and times, per minibatch, with one torch thread:

* ``loss_step``: loss forward + backward + clip + Adam step on a ready minibatch (functional=True,
  TorchRL's default, and functional=False, what train.py uses);
* ``serve_all_keys``: gathering a minibatch from the whole collected batch, one gather per minibatch
  (what PPOMinibatches did before);
* ``serve_loss_keys``: the loss's keys only, one gather per epoch then contiguous views (now).
"""

from __future__ import annotations

import argparse
import time

import torch
from torchrl.collectors import Collector

from torchrl_ahrs.app.shared.settings import load_task_settings
from torchrl_ahrs.envs.registry import make_env
from torchrl_ahrs.training.loss import HybridClipPPOLoss
from torchrl_ahrs.training.models import RunningNorm, build_actor, build_critic
from torchrl_ahrs.value import WeightedMultiGAE


def timed(fn, repeats: int) -> float:
    """Mean wall time of ``fn()`` in milliseconds over ``repeats`` calls (after 10 warm-up calls)."""
    for _ in range(10):
        fn()
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - start) / repeats * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minibatch", type=int, default=64)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--hidden", type=int, nargs="+", default=[64, 64])
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    env = make_env(load_task_settings("ant_v5"), 64, 0, components=["total"])
    obs_dim = env.observation_spec["observation"].shape[-1]
    norm = RunningNorm(obs_dim)
    actor = build_actor(norm, obs_dim, env.full_action_spec[env.action_key], args.hidden)
    critic = build_critic(norm, obs_dim, 1, args.hidden)
    collector = Collector(env, actor, frames_per_batch=2048, total_frames=2048)
    batch = next(iter(collector))
    collector.shutdown()
    WeightedMultiGAE(["total"], gamma=0.99, lmbda=0.95, value_network=critic)(batch)
    flat = batch.reshape(-1)
    size, steps = args.minibatch, args.steps
    results = {}
    for functional in (True, False):
        loss = HybridClipPPOLoss(actor, critic, critic_coeff=0.5, loss_critic_type="l2", functional=functional)
        loss.set_keys(value_target="value_target")
        keys = [*loss.in_keys, "advantage", "value_target", "state_value", "loc", "scale"]
        minibatch = flat[:size].select(*keys, strict=False)
        optimizer = torch.optim.Adam(loss.parameters(), lr=1e-5)

        def step(loss=loss, minibatch=minibatch, optimizer=optimizer):
            losses = loss(minibatch)
            total = sum(value for key, value in losses.items() if key.startswith("loss"))
            total.backward()
            torch.nn.utils.clip_grad_norm_(loss.parameters(), 1.0)
            optimizer.step()
            optimizer.zero_grad()

        results[f"loss_step functional={functional}"] = timed(step, steps)
    chunks = flat.shape[0] // size

    def serve_all_keys():
        order = torch.randperm(flat.shape[0])
        return [flat[index] for index in order.chunk(chunks)]

    def serve_loss_keys():
        selected = flat.select(*keys, strict=False)
        order = torch.randperm(flat.shape[0])
        return list(selected[order].split(size, 0))

    results["serve_all_keys (per minibatch)"] = timed(serve_all_keys, max(steps // chunks, 5)) / chunks
    results["serve_loss_keys (per minibatch)"] = timed(serve_loss_keys, max(steps // chunks, 5)) / chunks
    print(f"minibatch {size}, hidden {args.hidden}, one torch thread")
    for name, milliseconds in results.items():
        print(f"  {name:34s} {milliseconds:7.3f} ms")


if __name__ == "__main__":
    main()
