"""EnvPoolEnv (our TorchRL wrapper over EnvPool 1.2.5) and the Ant-v5 task built on it.

Oracles: EnvPool's own ``info`` (reward terms, ``elapsed_step``) and its native reward.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torchrl.collectors import Collector
from torchrl.envs.utils import check_env_specs

pytest.importorskip("envpool")

from torchrl_ahrs.app.shared.settings import load_task_settings  # noqa: E402
from torchrl_ahrs.envs.backends.envpool import EnvPoolEnv  # noqa: E402
from torchrl_ahrs.envs.registry import make_env  # noqa: E402

ANT_TERMS = ("reward_forward", "reward_ctrl", "reward_contact", "reward_survive")
MAX_STEPS = 40


def _short_ant(num_envs: int = 8, seed: int = 0) -> EnvPoolEnv:
    # healthy_z_min 0.5 makes random actions end some episodes by termination, MAX_STEPS by truncation
    return EnvPoolEnv("Ant-v5", num_envs=num_envs, seed=seed, max_episode_steps=MAX_STEPS, healthy_z_min=0.5)


def _collect(env, frames: int) -> torch.Tensor:
    torch.manual_seed(0)
    collector = Collector(env, policy=None, frames_per_batch=frames, total_frames=frames)
    batch = next(iter(collector))
    collector.shutdown()
    return batch


def test_specs_flat_and_dict_observations():
    check_env_specs(_short_ant(num_envs=3))
    go1 = EnvPoolEnv("Go1JoystickFlatTerrain-v1", num_envs=2, observation_keys=["state"])
    check_env_specs(go1)
    assert go1.observation_spec["observation"].shape == (2, 48)
    assert go1.observation_spec["privileged_state"].shape == (2, 123)
    both = EnvPoolEnv("Go1JoystickFlatTerrain-v1", num_envs=2)  # default: all parts concatenated
    assert both.observation_spec["observation"].shape == (2, 48 + 123)


def test_collector_batch_has_no_autoreset_transitions():
    env = _short_ant()
    batch = _collect(env, frames=8 * 100)  # [N=8, T=100]
    nxt = batch["next"]
    # every transition's reward is the sum of the env's reported terms
    terms = sum(nxt["info", key] for key in ANT_TERMS)
    torch.testing.assert_close(nxt["reward"].squeeze(-1), terms, atol=1e-4, rtol=0)
    # EnvPool's autoreset step reports elapsed_step 0 (and reward 0): it must never be a transition
    elapsed_before, elapsed_after = batch["info", "elapsed_step"], nxt["info", "elapsed_step"]
    assert (elapsed_after >= 1).all()
    assert (elapsed_after == elapsed_before + 1).all()
    # episode boundaries follow elapsed_step: truncation exactly at MAX_STEPS, a fresh episode after done
    done = nxt["done"].squeeze(-1)
    truncated = nxt["truncated"].squeeze(-1)
    assert torch.equal(truncated, (elapsed_after == MAX_STEPS) & ~nxt["terminated"].squeeze(-1))
    assert done.any() and nxt["terminated"].any() and truncated.any()
    starts_after_done = elapsed_before[:, 1:][done[:, :-1]]
    assert (starts_after_done == 0).all()


def test_rollout_without_break_matches_collector_semantics():
    torch.manual_seed(1)
    rollout = _short_ant(num_envs=4).rollout(90, break_when_any_done=False)
    assert (rollout["next", "info", "elapsed_step"] == rollout["info", "elapsed_step"] + 1).all()


def test_stepping_an_ended_env_without_reset_raises():
    env = EnvPoolEnv("Ant-v5", num_envs=2, seed=0, max_episode_steps=2)
    td = env.reset()
    for _ in range(2):
        td = env.step(env.rand_action(td))["next"].clone()
    assert td["done"].all()
    with pytest.raises(RuntimeError, match="not reset"):
        env.step(env.rand_action(td))


def test_same_seed_same_trajectories():
    def run(seed):
        torch.manual_seed(0)  # same random actions
        return _short_ant(num_envs=4, seed=seed).rollout(60, break_when_any_done=False)

    a, b, c = run(3), run(3), run(4)
    assert torch.equal(a["next", "observation"], b["next", "observation"])
    assert torch.equal(a["next", "done"], b["next", "done"])
    assert not torch.equal(a["next", "observation"], c["next", "observation"])


def test_set_seed_reproduces_a_fresh_env():
    env = _short_ant(num_envs=2, seed=0)
    env.set_seed(5)
    torch.manual_seed(0)
    reseeded = env.rollout(10, break_when_any_done=False)
    torch.manual_seed(0)
    fresh = _short_ant(num_envs=2, seed=5).rollout(10, break_when_any_done=False)
    assert torch.equal(reseeded["next", "observation"], fresh["next", "observation"])


def test_set_seed_keeps_running_episodes_valid():
    # a collector resets first and its trainer seeds afterwards: stepping on must not break
    env = _short_ant(num_envs=2, seed=0)
    td = env.reset()
    env.set_seed(0)
    out = env.step(env.rand_action(td))
    assert (out["next", "info", "elapsed_step"] == 1).all()
    # all envs ending together (a masked reset) must not restart the seed's initial states
    first = td["observation"].clone()
    again = env.reset(out["next"].clone().set("_reset", torch.ones(2, 1, dtype=torch.bool)))
    assert not torch.equal(again["observation"], first)


def test_ant_v5_components_sum_to_native_reward():
    cfg = load_task_settings("ant_v5")
    env = make_env(cfg, num_envs=4, seed=0)
    torch.manual_seed(0)
    rollout = env.rollout(100, break_when_any_done=False)
    reward = rollout["next", "reward"]
    parts = torch.stack([reward[c] for c in cfg.components], dim=-1).sum(-1)
    assert (parts - reward["total"]).abs().max().item() < 1e-4
    # each component is an actual signal (not a zero placeholder) and has the documented sign
    assert reward["forward"].abs().max() > 1e-2
    assert (reward["ctrl"] < 0).all()
    assert (reward["contact"] <= 0).all()
    assert np.isclose(reward["survive"].max().item(), 1.0)


def test_ant_v5_steps_like_gymnasium_from_the_same_state():
    """Differential against gymnasium's own Ant-v5 (the oracle): from EnvPool's reset state, the same
    actions give the same observations, every reward term and the same termination flags."""
    gym = pytest.importorskip("gymnasium")
    pool = EnvPoolEnv("Ant-v5", num_envs=1, seed=3)._pool
    reference = gym.make("Ant-v5").unwrapped
    reference.reset(seed=0)
    obs, _ = pool.reset()
    # the observation excludes the torso's x, y (qpos[:2]); the dynamics do not depend on them.
    # No re-synchronisation afterwards: set_state refreshes MuJoCo's body positions, which a plain step
    # leaves one substep old, so it would shift gymnasium's x displacement (reward_forward) by ~3 %.
    reference.set_state(np.concatenate([[0.0, 0.0], obs[0, :13]]), obs[0, 13:27])
    rng = np.random.default_rng(0)
    for step in range(40):  # rounding differences grow chaotically through contacts: ~1e-8 after ~60 steps
        action = rng.uniform(-1.0, 1.0, size=(1, 8))
        obs, reward, terminated, truncated, info = pool.step(action)
        ref_obs, ref_reward, ref_terminated, _, ref_info = reference.step(action[0])
        np.testing.assert_allclose(obs[0], ref_obs, atol=1e-9, err_msg=f"step {step}")
        for term in ("reward_forward", "reward_ctrl", "reward_contact", "reward_survive"):
            assert info[term][0] == pytest.approx(ref_info[term], abs=1e-9), (term, step)
        assert reward[0] == pytest.approx(ref_reward, abs=1e-5)  # EnvPool's reward is float32
        assert bool(terminated[0]) == ref_terminated and not truncated[0]
        if ref_terminated:
            break


def test_ant_v5_without_contact_forces_observes_and_pays_like_gymnasium():
    """``include_cfrc_ext_in_observation: false`` against gymnasium's Ant-v5 with the same option: the
    27-entry observation and the whole reward, contact cost included, step for step."""
    gym = pytest.importorskip("gymnasium")
    cfg = load_task_settings("ant_v5", ["task.include_cfrc_ext_in_observation=false"])
    env = make_env(cfg, num_envs=1, seed=3)
    assert env.observation_spec["observation"].shape == (1, 27)
    check_env_specs(env)
    reference = gym.make("Ant-v5", include_cfrc_ext_in_observation=False).unwrapped
    reference.reset(seed=0)
    td = env.reset()
    start = td["observation"][0].double().numpy()
    assert start.shape == (27,)
    # float32 observation: start gymnasium from the rounded state (both then run the same physics)
    reference.set_state(np.concatenate([[0.0, 0.0], start[:13]]), start[13:27])
    rng = np.random.default_rng(0)
    paid_contact = 0.0
    for step in range(20):  # float32 starting state: the two trajectories drift apart (~1e-3 by step 30)
        action = rng.uniform(-1.0, 1.0, size=(1, 8))
        td["action"] = torch.as_tensor(action, dtype=torch.float32)
        out = env.step(td)
        ref_obs, ref_reward, ref_terminated, _, ref_info = reference.step(action[0])
        np.testing.assert_allclose(out["next", "observation"][0].numpy(), ref_obs, atol=1e-4, err_msg=f"step {step}")
        assert out["next", "reward", "total"].item() == pytest.approx(ref_reward, abs=1e-4), step
        assert out["next", "reward", "contact"].item() == pytest.approx(ref_info["reward_contact"], abs=1e-6), step
        paid_contact += ref_info["reward_contact"]
        assert bool(out["next", "terminated"].item()) == ref_terminated
        if ref_terminated:
            break
        td = out["next"].clone()
    assert paid_contact < 0.0, "no contact cost in these steps: the comparison would not see it dropped"
