"""The RuleScheduler as a hook of a plain ``torchrl.trainers.Trainer``.

The trainer collects, ``WeightedMultiGAE`` runs on each batch (``batch_process``), a replay buffer hands
out minibatches to ``HybridClipPPOLoss``, and the scheduler registers itself (``pre_steps_log``: episode
returns; ``post_steps``: a decision every ``interval`` iterations)::

    python examples/trainer_hook.py --frames 20000          # tiny: --frames 1024
"""

from __future__ import annotations

import argparse

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.envs import TransformedEnv
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal
from torchrl.trainers import ReplayBufferTrainer, Trainer

from torchrl_ahrs import (
    ComponentRewardSum,
    HybridClipPPOLoss,
    MultiHeadCritic,
    RandomSelector,
    RewardComponents,
    RuleScheduler,
    load_repository,
)
from torchrl_ahrs.envs.tasks.point_reach import PointReachEnv

COMPONENTS = ["distance", "arrival", "ctrl"]


def main(argv: list[str] | None = None) -> list[float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20_000)
    parser.add_argument("--frames-per-batch", type=int, default=512)
    parser.add_argument("--mini-batch-size", type=int, default=128)
    args = parser.parse_args(argv)
    torch.manual_seed(0)

    env = TransformedEnv(
        PointReachEnv(num_envs=8, max_episode_steps=32),
        RewardComponents(COMPONENTS, term_keys={c: ("info", f"reward_{c}") for c in COMPONENTS}),
    )
    env.append_transform(ComponentRewardSum([*COMPONENTS, "total"]))
    actor = ProbabilisticActor(
        TensorDictModule(
            torch.nn.Sequential(MLP(6, 4, num_cells=[64]), NormalParamExtractor()), ["observation"], ["loc", "scale"]
        ),
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        return_log_prob=True,
    )
    critic = TensorDictModule(MultiHeadCritic(6, 3, hidden_sizes=[64]), ["observation"], ["state_value"])
    loss = HybridClipPPOLoss(actor, critic, components=COMPONENTS).make_value_estimator(gamma=0.99, lmbda=0.95)
    gae = loss.value_estimator
    repository = load_repository()
    scheduler = RuleScheduler(gae, selector=RandomSelector(repository, seed=0), interval=2, initial_weights=[0.5] * 3)

    optim_steps = args.frames_per_batch // args.mini_batch_size
    trainer = Trainer(
        collector=Collector(env, actor, frames_per_batch=args.frames_per_batch, total_frames=args.frames),
        total_frames=args.frames,
        frame_skip=1,
        loss_module=loss,
        optimizer=torch.optim.Adam(loss.parameters(), lr=3e-4),
        optim_steps_per_batch=optim_steps,
        progress_bar=False,
        log_interval=0,
    )
    trainer.register_op("batch_process", lambda batch: gae(batch).reshape(-1))  # advantages, then flatten
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(args.frames_per_batch),
        sampler=SamplerWithoutReplacement(),
        batch_size=args.mini_batch_size,
    )
    ReplayBufferTrainer(buffer, batch_size=None, flatten_tensordicts=False).register(trainer)
    scheduler.register(trainer)  # the hook: episode returns in, weights out
    trainer.train()
    print("final weights", [round(w, 3) for w in gae.weights.tolist()], "rule", scheduler.rule_id)
    return gae.weights.tolist()


if __name__ == "__main__":
    main()
