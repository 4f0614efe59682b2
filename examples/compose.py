"""The README's composition example, verbatim (``tests/system/test_examples.py`` keeps the two identical).

Split-reward MuJoCo task, TorchRL's ``Collector``, a ``HybridClipPPOLoss`` that computes its own
advantage, and the bandit rescheduling the weights; run with ``python examples/compose.py``.
"""

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torchrl.collectors import Collector
from torchrl.envs import TransformedEnv
from torchrl.modules import ProbabilisticActor, TanhNormal

from torchrl_ahrs import (
    BanditSelector,
    ComponentRewardSum,
    HybridClipPPOLoss,
    MultiHeadCritic,
    RewardComponents,
    RuleScheduler,
    WeightedMultiGAE,
    load_repository,
)
from torchrl_ahrs.envs.tasks.point_reach import PointReachEnv

components = ["distance", "arrival", "ctrl"]
env = TransformedEnv(
    PointReachEnv(num_envs=8, max_episode_steps=16),  # writes ("info", "reward_<term>") every step
    RewardComponents(components, term_keys={c: ("info", f"reward_{c}") for c in components}),
)
env.append_transform(ComponentRewardSum(components + ["total"]))  # ("episode_reward", c)
assert env.reward_key == ("reward", "total")

torch.manual_seed(0)
actor = ProbabilisticActor(
    TensorDictModule(
        torch.nn.Sequential(torch.nn.Linear(6, 4), NormalParamExtractor()), ["observation"], ["loc", "scale"]
    ),
    in_keys=["loc", "scale"],
    distribution_class=TanhNormal,
    return_log_prob=True,
)
critic = TensorDictModule(MultiHeadCritic(6, num_heads=3, hidden_sizes=[64, 64]), ["observation"], ["state_value"])
gae = WeightedMultiGAE(components, gamma=0.99, lmbda=0.95, value_network=critic, weights=torch.tensor([1.0, 0.5, 0.5]))
loss = HybridClipPPOLoss(actor, critic).make_value_estimator(gae)  # no precomputed advantage needed
scheduler = RuleScheduler(gae, selector=BanditSelector(load_repository(), seed=0), interval=1)  # keeps gae's weights
optimizer = torch.optim.Adam(loss.parameters(), lr=3e-4)

collector = Collector(env, actor, frames_per_batch=8 * 32, total_frames=2 * 8 * 32)
for batch in collector:  # [N=8, T=32]
    gae(batch)
    print(batch["advantage_components"].shape, batch["advantage"].shape)  # [8, 32, 3] and [8, 32, 1]
    losses = loss(batch.reshape(-1))
    (losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]).backward()
    optimizer.step(), optimizer.zero_grad()
    scheduler.observe_batch(batch)  # the returns of the episodes that ended
    scheduler.step()  # a decision every `interval` iterations
    print("weights", [round(w, 3) for w in gae.weights.tolist()])
collector.shutdown()
