"""Hybrid-reward PPO on a gymnasium MuJoCo env, written as a plain TorchRL loop (sota-script style).

HalfCheetah-v5 reports its reward terms in ``info``; ``with_info_reward_terms`` turns them into components
``("reward", "forward")`` and ``("reward", "ctrl")`` while ``env.reward_key`` stays the native total. One
critic head per component, per-component GAE mixed by weights, PPO on the mixed advantage, and the
bandit rescheduling the weights every iteration::

    python examples/ppo_gymnasium.py --frames 100000            # tiny: --frames 2048 --frames-per-batch 1024
"""

from __future__ import annotations

import argparse

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.envs import DoubleToFloat, GymEnv
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal

from torchrl_ahrs import (
    BanditSelector,
    ComponentRewardSum,
    HybridClipPPOLoss,
    MultiHeadCritic,
    RuleScheduler,
    load_repository,
    with_info_reward_terms,
)


def make_env(env_name: str, max_episode_steps: int):
    env = with_info_reward_terms(
        GymEnv(env_name, max_episode_steps=max_episode_steps), ["reward_forward", "reward_ctrl"]
    )
    env.append_transform(DoubleToFloat())  # gymnasium's observations are float64
    env.append_transform(ComponentRewardSum(["forward", "ctrl", "total"]))  # ("episode_reward", c)
    return env


def main(argv: list[str] | None = None) -> list[list[float]]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="HalfCheetah-v5")
    parser.add_argument("--frames", type=int, default=100_000)
    parser.add_argument("--frames-per-batch", type=int, default=2048)
    parser.add_argument("--mini-batch-size", type=int, default=256)
    parser.add_argument("--epochs", type=int, default=4)
    parser.add_argument("--max-episode-steps", type=int, default=256)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    torch.manual_seed(args.seed)

    env = make_env(args.env, args.max_episode_steps)
    components = ["forward", "ctrl"]
    obs_dim, act_dim = env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1]
    actor = ProbabilisticActor(
        TensorDictModule(
            torch.nn.Sequential(MLP(obs_dim, 2 * act_dim, num_cells=[64, 64]), NormalParamExtractor()),
            ["observation"],
            ["loc", "scale"],
        ),
        in_keys=["loc", "scale"],
        spec=env.action_spec,
        distribution_class=TanhNormal,
        return_log_prob=True,
    )
    critic = TensorDictModule(
        MultiHeadCritic(obs_dim, len(components), hidden_sizes=[64, 64]), ["observation"], ["state_value"]
    )
    loss = HybridClipPPOLoss(actor, critic, components=components, clip_epsilon=0.2, entropy_coeff=1e-3)
    loss.make_value_estimator(gamma=0.99, lmbda=0.95, normalize_components=True)
    gae = loss.value_estimator  # a WeightedMultiGAE over the two components
    scheduler = RuleScheduler(gae, selector=BanditSelector(load_repository(), seed=args.seed), interval=1)
    optimizer = torch.optim.Adam(loss.parameters(), lr=3e-4)
    collector = Collector(env, actor, frames_per_batch=args.frames_per_batch, total_frames=args.frames)
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(args.frames_per_batch),
        sampler=SamplerWithoutReplacement(),
        batch_size=args.mini_batch_size,
    )

    history = []
    for i, batch in enumerate(collector):
        with torch.no_grad():
            gae(batch)  # advantage_components [T, K], value_target [T, K], advantage [T, 1]
        buffer.extend(batch.reshape(-1))
        for _ in range(args.epochs):
            for _ in range(args.frames_per_batch // args.mini_batch_size):
                out = loss(buffer.sample())
                total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
                total.backward()
                torch.nn.utils.clip_grad_norm_(loss.parameters(), 1.0)
                optimizer.step()
                optimizer.zero_grad()
        collector.update_policy_weights_()
        scheduler.observe_batch(batch)
        scheduler.step()
        history.append(gae.weights.tolist())
        done = batch["next", "done"].squeeze(-1)
        ret = batch["next", "episode_reward", "total"][done].mean().item() if done.any() else float("nan")
        weights = ", ".join(f"{c}={w:.2f}" for c, w in zip(components, gae.weights.tolist(), strict=True))
        print(f"iteration {i + 1}: return {ret:.1f}, weights {weights}")
    collector.shutdown()
    return history


if __name__ == "__main__":
    main()
