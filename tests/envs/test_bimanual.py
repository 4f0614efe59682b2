"""The Bi-DexHands bimanual tasks (shadow_hand_scissors, shadow_hand_bottle_cap): components against the
native reward, hand-derived task quantities, thread physics, partial resets, seeding, specs, training."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_module
from torchrl.envs.utils import check_env_specs

from torchrl_ahrs.app.shared.settings import load_task_settings
from torchrl_ahrs.app.train.runs import read_scalar
from torchrl_ahrs.envs.registry import make_env
from torchrl_ahrs.envs.tasks.shadow_hand_bottle_cap import (
    ShadowHandBottleCapEnv,
    bottle_cap_native_reward,
    bottle_cap_terms,
)
from torchrl_ahrs.envs.tasks.shadow_hand_scissors import (
    ShadowHandScissorsEnv,
    scissors_native_reward,
    scissors_terms,
)
from torchrl_ahrs.evaluation.task_metrics import step_probe
from torchrl_ahrs.train import train

TASKS = ["shadow_hand_scissors", "shadow_hand_bottle_cap"]


def refresh(env, i: int) -> None:
    """Recomputes env ``i``'s derived quantities after its MjData was edited and copies its state in."""
    mujoco.mj_forward(env.model, env.datas[i])
    env._gather(slice(i, i + 1))


def test_scissors_components_sum_to_the_native_reward_on_both_sides_of_the_gate():
    g = torch.Generator().manual_seed(0)
    right, left = torch.rand(1000, generator=g) * 1.4, torch.rand(1000, generator=g) * 1.4  # gate at 0.7
    q = torch.rand(1000, generator=g) * 1.2 - 0.59
    terms = scissors_terms(right, left, q)
    torch.testing.assert_close(sum(terms.values()), scissors_native_reward(right, left, q))
    grasped = (right < 0.7) & (left < 0.7)
    assert 100 < int(grasped.sum()) < 900  # both branches exercised
    assert (terms["open"][~grasped] == 0).all() and (terms["open"][grasped] > 0).all()


def test_bottle_cap_components_sum_to_the_native_reward_on_both_sides_of_the_gate():
    g = torch.Generator().manual_seed(1)
    right, left = torch.rand(1000, generator=g) * 0.6, torch.rand(1000, generator=g) * 0.2  # gate at 0.3
    lift = torch.rand(1000, generator=g) * 0.05
    terms = bottle_cap_terms(right, left, lift)
    torch.testing.assert_close(sum(terms.values()), bottle_cap_native_reward(right, left, lift))
    at_cap = right <= 0.3
    assert 100 < int(at_cap.sum()) < 900
    assert (terms["lift"][~at_cap] == 0).all()


@pytest.mark.parametrize("task", TASKS)
def test_env_reward_is_the_native_formula_and_the_leaves_sum_to_it(task):
    cfg = load_task_settings(task)
    env = make_env(cfg, num_envs=3, seed=0)
    check_env_specs(env)
    td = env.rollout(20, break_when_any_done=False)
    leaves = td["next", "reward"]
    assert sorted(leaves.keys()) == sorted([*cfg.components, "total"])
    total = sum(leaves[c] for c in cfg.components)
    torch.testing.assert_close(total, leaves["total"], rtol=1e-5, atol=1e-5)
    assert leaves["total"].abs().sum() > 0


def test_scissors_opening_is_read_from_the_hinge_and_gated_by_both_hands():
    env = ShadowHandScissorsEnv(num_envs=2, num_threads=1, reset_dof_noise=0.0, reset_position_noise=0.0)
    env.reset()
    hinge = env.model.joint("hinge").qposadr[0]
    env.datas[1].qpos[hinge] = 0.5  # opened by 0.5 rad
    refresh(env, 1)
    right, left = env.finger_distances()
    assert (right < 0.7).all() and (left < 0.7).all()  # the hands start at their handles
    terms = env.reward_terms()
    torch.testing.assert_close(terms["open"], torch.tensor([0.0, 2.5], dtype=torch.float64))  # 5 (0.59 + q)
    assert env.success().tolist() == [False, True]  # q = 0.5 − 0.59 > −0.3
    # the handle sites follow the blades: the left handle turned by 0.5 rad about the hinge
    handle = env.site("handle_l")[1, :2] - torch.from_numpy(env.datas[1].xpos[env.model.body("upper_blade").id][:2])
    closed = env.site("handle_l")[0, :2] - torch.from_numpy(env.datas[0].xpos[env.model.body("upper_blade").id][:2])
    angle = torch.atan2(handle[1], handle[0]) - torch.atan2(closed[1], closed[0])
    assert abs(angle.item() - 0.5) < 1e-6


def test_bottle_cap_thread_lifts_the_cap_as_it_turns():
    env = ShadowHandBottleCapEnv(num_envs=1, num_threads=1, reset_dof_noise=0.0, reset_position_noise=0.0)
    env.reset()
    model, data = env.model, env.datas[0]
    twist, slide = model.joint("cap_twist"), model.joint("cap_slide")
    for _ in range(100):
        data.qfrc_applied[twist.dofadr[0]] = 0.02  # unscrewing torque (N m) > m g pitch + friction = 0.004
        mujoco.mj_step(model, data)
    turned, risen = data.qpos[twist.qposadr[0]], data.qpos[slide.qposadr[0]]
    assert turned > 1.0
    assert abs(risen - 0.01 * turned) < 1e-3  # slide = 0.01 m/rad · twist, up to the thread's compliance
    refresh(env, 0)  # site positions after mj_step lag one substep behind qpos
    torch.testing.assert_close(env.cap_lift(), torch.tensor([risen], dtype=torch.float64), atol=1e-6, rtol=0)


def test_bottle_cap_success_and_gate():
    env = ShadowHandBottleCapEnv(num_envs=2, num_threads=1, reset_dof_noise=0.0, reset_position_noise=0.0)
    env.reset()
    twist, slide = env.model.joint("cap_twist").qposadr[0], env.model.joint("cap_slide").qposadr[0]
    env.datas[1].qpos[twist], env.datas[1].qpos[slide] = 4.0, 0.04
    refresh(env, 1)
    assert env.success().tolist() == [False, True]
    right, left = env.distances()
    assert (right > 0.3).all()  # the right fingers start above, not around, the cap: no lift reward yet
    assert (env.reward_terms()["lift"] == 0).all()
    assert (left < 0.2).all()  # the left palm starts at the bottle
    assert step_probe("shadow_hand_bottle_cap")(env)["success"].tolist() == [0.0, 1.0]


def test_partial_reset_leaves_other_simulations_untouched():
    env = ShadowHandScissorsEnv(num_envs=3, num_threads=2)
    td = env.reset()
    for _ in range(3):
        _, td = env.step_and_maybe_reset(td.set("action", torch.rand(3, 52) * 2 - 1))
    kept = [d.qpos.copy() for d in env.datas]
    td.set("_reset", torch.tensor([[False], [True], [False]]))
    env.reset(td)
    for i in (0, 2):
        np.testing.assert_array_equal(env.datas[i].qpos, kept[i])
    assert not np.array_equal(env.datas[1].qpos, kept[1])
    assert env.episode_steps.tolist() == [3, 0, 3]
    assert env.action[1].abs().sum() == 0 and env.action[0].abs().sum() > 0


@pytest.mark.parametrize("task", TASKS)
def test_same_seed_same_trajectory(task):
    cfg = load_task_settings(task)
    actions = torch.rand(8, 2, 52, generator=torch.Generator().manual_seed(0)) * 2 - 1

    def run(seed):
        env = make_env(cfg, num_envs=2, seed=seed)
        td, observations = env.reset(), []
        for a in actions:
            out, td = env.step_and_maybe_reset(td.set("action", a))
            observations.append(out["next", "observation"])
        return torch.stack(observations)

    first = run(3)
    torch.testing.assert_close(first, run(3), rtol=0, atol=0)
    assert not torch.equal(first, run(4))


@pytest.mark.slow
@pytest.mark.parametrize("task", TASKS)
def test_hdppo_trains_20k_frames_and_logs_every_component(tmp_path, task):
    overrides = [f"task={task}", "method=hdppo", "trainer.total_frames=20000", "trainer.progress_bar=false"]
    with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    train(cfg, tmp_path)
    iterations = -(-20000 // cfg.trainer.frames_per_batch)  # ceil: the collector finishes its last batch
    for name in [*cfg.task.components, "total"]:
        for kind in ("reward", "return"):
            values = read_scalar(tmp_path / "metrics" / "scalars" / f"{kind}/{name}.csv")[1].tolist()
            assert values and all(np.isfinite(values)), f"{kind}/{name}"
            if kind == "reward":
                assert len(values) == iterations, f"{kind}/{name} not logged every iteration"
    assert (tmp_path / "checkpoint.pt").exists()
