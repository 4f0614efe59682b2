"""The reward key layout against TorchRL's defaults, on a split-reward MuJoCo task and a gymnasium env."""

import pytest
import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torchrl.envs import GymEnv, RewardSum, TransformedEnv
from torchrl.envs.utils import check_env_specs
from torchrl.modules import ProbabilisticActor, TanhNormal
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE
from torchrl.trainers import LogScalar

from torchrl_ahrs import HybridClipPPOLoss, MultiHeadCritic, RewardComponents
from torchrl_ahrs.envs.tasks.point_reach import PointReachEnv
from torchrl_ahrs.rewards import ComponentRewardSum, with_info_reward_terms

NAMES = ["distance", "arrival", "ctrl"]


def point_reach(num_envs=3, max_episode_steps=4):
    base = PointReachEnv(num_envs=num_envs, max_episode_steps=max_episode_steps)
    return TransformedEnv(base, RewardComponents(NAMES, term_keys={c: ("info", f"reward_{c}") for c in NAMES}))


def cheetah():
    return with_info_reward_terms(GymEnv("HalfCheetah-v5"), ["reward_forward", "reward_ctrl"])


def actor_critic(obs_dim, act_dim, heads):
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(obs_dim, 2 * act_dim), NormalParamExtractor())
    actor = ProbabilisticActor(
        TensorDictModule(net, ["observation"], ["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        return_log_prob=True,
    )
    critic = TensorDictModule(MultiHeadCritic(obs_dim, heads, hidden_sizes=[8]), ["observation"], ["state_value"])
    return actor, critic


@pytest.mark.parametrize("make", [point_reach, cheetah], ids=["point_reach", "gymnasium"])
def test_reward_key_is_the_native_total_and_specs_hold(make):
    env = make()
    assert env.reward_key == ("reward", "total") and env.reward_keys == [("reward", "total")]
    check_env_specs(env)
    rollout = env.rollout(3)
    leaves = set(rollout["next", "reward"].keys())
    assert "total" in leaves and len(leaves) >= 3
    assert all(v.dtype == torch.float32 for v in rollout["next", "reward"].values())


def test_total_is_the_native_reward_and_components_sum_to_it():
    rollout = point_reach().rollout(6, break_when_any_done=False)
    reward = rollout["next", "reward"]
    # point_reach's native reward is the sum of its three terms (oracle: the env's own definition)
    torch.testing.assert_close(reward["total"], sum(reward[c] for c in NAMES))


def test_default_reward_sum_and_component_returns_accumulate_over_episodes():
    env = point_reach(max_episode_steps=4)
    env.append_transform(RewardSum())  # TorchRL's default: in_keys = env.reward_keys
    env.append_transform(ComponentRewardSum(NAMES))
    assert env.reward_key == ("reward", "total")  # appended transforms do not add reward leaves
    check_env_specs(env)
    rollout = env.rollout(8, break_when_any_done=False)  # two 4-step episodes per env
    nxt = rollout["next"]
    for t in (3, 7):  # the last step of each episode: its return is the sum of its 4 rewards
        torch.testing.assert_close(
            nxt["reward", "episode_total"][:, t], nxt["reward", "total"][:, t - 3 : t + 1].sum(1)
        )
        for c in NAMES:
            torch.testing.assert_close(nxt["episode_reward", c][:, t], nxt["reward", c][:, t - 3 : t + 1].sum(1))


def test_log_scalar_reads_the_env_reward_key():
    env = point_reach()
    batch = env.rollout(5, break_when_any_done=False)
    hook = LogScalar(key=("next", *env.reward_key))
    logged = hook(batch)
    assert logged[hook.logname] == pytest.approx(batch["next", "reward", "total"].mean().item(), rel=1e-5)


def test_clip_ppo_loss_without_advantage_uses_the_total():
    env = point_reach()
    actor, _ = actor_critic(6, 2, heads=1)
    critic = TensorDictModule(torch.nn.Linear(6, 1), ["observation"], ["state_value"])
    loss = ClipPPOLoss(actor, critic)
    loss.set_keys(reward=env.reward_key)  # TorchRL's usual call for a nested reward
    with torch.no_grad():
        batch = env.rollout(5, actor, break_when_any_done=False)
    out = loss(batch.clone())
    assert torch.isfinite(out["loss_objective"]) and torch.isfinite(out["loss_critic"])
    # oracle: the advantage the loss computes is TorchRL's GAE on ("next", "reward", "total")
    oracle = GAE(gamma=0.99, lmbda=0.95, value_network=critic)
    oracle.set_keys(reward=("reward", "total"))
    expected = oracle(batch.clone())["advantage"]
    torch.testing.assert_close(loss.value_estimator(batch.clone())["advantage"], expected)


@pytest.mark.parametrize("make", [point_reach, cheetah], ids=["point_reach", "gymnasium"])
def test_hybrid_loss_without_advantage_builds_its_weighted_gae(make):
    env = make()
    components = [c for c in env.full_observation_spec["reward"].keys()]
    obs_dim = env.observation_spec["observation"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    actor, critic = actor_critic(obs_dim, act_dim, heads=len(components))
    if obs_dim == 17:  # gymnasium's observations are float64
        actor, critic = actor.double(), critic.double()
    loss = HybridClipPPOLoss(actor, critic, components=components, weights=[2.0] + [0.5] * (len(components) - 1))
    with torch.no_grad():
        batch = env.rollout(4, actor, break_when_any_done=False)
    out = loss(batch.clone())
    assert torch.isfinite(out["loss_objective"])
    mixed = loss.value_estimator(batch.clone())
    ak = mixed["advantage_components"]
    torch.testing.assert_close(mixed["advantage"][..., 0], (ak * loss.value_estimator.weights.to(ak.dtype)).sum(-1))


def test_hybrid_loss_refuses_a_single_reward_estimator():
    actor, critic = actor_critic(6, 2, heads=3)
    loss = HybridClipPPOLoss(actor, critic)
    with pytest.raises(TypeError, match="needs a WeightedMultiGAE"):
        loss.make_value_estimator(GAE(gamma=0.99, lmbda=0.95, value_network=critic))
    with pytest.raises(ValueError, match="pass components"):
        loss.make_value_estimator()
