"""Advantage cost: ``WeightedMultiGAE`` over K reward components against TorchRL's one-head ``GAE``.

Both see the same batch ``[N, T]`` (same observations, dones, terminations); the K-component
estimator reads K reward leaves ``("next", "reward", c)`` and a K-output critic, the one-head GAE
reads ``("next", "reward")`` ``[N, T, 1]`` and a one-output critic of the same widths. Two settings:

- ``with critic``: the estimator runs its value network on ``observation`` and ``next.observation``
  (what PPO does once per epoch);
- ``precomputed``: ``value_network=None``, values are already in the batch (the GAE recursion,
  stacking and mixing alone).

Each timing is the median of ``--repeat`` calls after ``--warmup`` untimed ones, the two estimators
alternating call by call.

Run: ``python benchmarks/throughput/bench_gae.py --sizes 64x64 256x128 --components 16 --repeat 30``
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import MLP, ValueOperator
from torchrl.objectives.value import GAE

from torchrl_ahrs.value import MultiHeadCritic, WeightedMultiGAE


def make_batches(num_envs: int, steps: int, num_components: int, obs_dim: int, seed: int = 0):
    """(K-component batch, one-reward batch) ``[N, T]`` sharing observations, dones and terminations.

    About one step in a hundred ends an episode (terminated or truncated), so the recursion's
    reset masking is exercised.
    """
    generator = torch.Generator().manual_seed(seed)
    shape = (num_envs, steps)
    observation = torch.randn(*shape, obs_dim, generator=generator)
    next_observation = torch.randn(*shape, obs_dim, generator=generator)
    done = torch.rand(*shape, 1, generator=generator) < 0.01
    terminated = done & (torch.rand(*shape, 1, generator=generator) < 0.5)
    rewards = torch.randn(*shape, num_components, generator=generator)
    components = [f"c{k}" for k in range(num_components)]

    def batch(reward) -> TensorDict:
        return TensorDict(
            {
                "observation": observation,
                "next": {
                    "observation": next_observation,
                    "reward": reward,
                    "done": done.clone(),
                    "terminated": terminated.clone(),
                },
            },
            batch_size=shape,
        )

    multi = batch({name: rewards[..., k : k + 1] for k, name in enumerate(components)})
    single = batch(rewards.sum(-1, keepdim=True))
    return multi, single, components


def time_pair(multi_call, single_call, repeat: int, warmup: int) -> tuple[float, float]:
    """Medians [s] of two calls, alternated call by call so that load changes hit both alike."""
    multi_times, single_times = [], []
    for index in range(warmup + repeat):
        for call, times in ((multi_call, multi_times), (single_call, single_times)):
            start = time.perf_counter()
            call()
            if index >= warmup:
                times.append(time.perf_counter() - start)
    return statistics.median(multi_times), statistics.median(single_times)


def bench(num_envs: int, steps: int, num_components: int, args: argparse.Namespace) -> dict[str, tuple[float, float]]:
    """``{"with critic": (multi_s, single_s), "precomputed": (multi_s, single_s)}``."""
    torch.manual_seed(0)
    multi, single, components = make_batches(num_envs, steps, num_components, args.obs_dim)
    multi_critic = TensorDictModule(
        MultiHeadCritic(args.obs_dim, num_components, args.hidden), in_keys=["observation"], out_keys=["state_value"]
    )
    single_critic = ValueOperator(
        MLP(in_features=args.obs_dim, out_features=1, num_cells=args.hidden, activation_class=nn.Tanh),
        in_keys=["observation"],
    )
    results = {}
    multi_gae = WeightedMultiGAE(
        components, gamma=0.99, lmbda=0.95, value_network=multi_critic, weights=torch.rand(num_components)
    )
    single_gae = GAE(gamma=0.99, lmbda=0.95, value_network=single_critic)
    with torch.no_grad():
        results["with critic"] = time_pair(lambda: multi_gae(multi), lambda: single_gae(single), args.repeat, 3)
        # the values the critics just wrote stay in the batches; estimators without a network reuse them
        multi_gae = WeightedMultiGAE(
            components, gamma=0.99, lmbda=0.95, value_network=None, weights=torch.rand(num_components)
        )
        single_gae = GAE(gamma=0.99, lmbda=0.95, value_network=None)
        results["precomputed"] = time_pair(lambda: multi_gae(multi), lambda: single_gae(single), args.repeat, 3)
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["64x64", "256x128"], help="N x T batches")
    parser.add_argument("--components", type=int, default=16, help="K")
    parser.add_argument("--obs-dim", type=int, default=105, help="Ant-v5's observation size")
    parser.add_argument("--hidden", type=int, nargs="+", default=[256, 256])
    parser.add_argument("--repeat", type=int, default=30)
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(
        f"K={args.components} obs_dim={args.obs_dim} critic hidden={args.hidden} torch threads={args.threads} "
        f"median of {args.repeat} (ms)"
    )
    print(f"{'N x T':>10s} {'values':>12s} {'multi K':>10s} {'one-head':>10s} {'ratio':>7s}")
    for size in args.sizes:
        num_envs, steps = (int(part) for part in size.lower().split("x"))
        for setting, (multi_s, single_s) in bench(num_envs, steps, args.components, args).items():
            print(f"{size:>10s} {setting:>12s} {1e3 * multi_s:10.3f} {1e3 * single_s:10.3f} {multi_s / single_s:6.2f}x")


if __name__ == "__main__":
    main()
