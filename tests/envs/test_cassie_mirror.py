"""Cassie's left-right mirror (``ppo.mirror``) against the physics: a mirrored state driven by mirrored actions
must observe the mirror image and collect the same reward, step after step, in real MuJoCo."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchrl_ahrs.app.shared.settings import load_task_settings
from torchrl_ahrs.envs.common.mirror import SignedPermutation
from torchrl_ahrs.envs.registry import task_mirror
from torchrl_ahrs.envs.tasks.cassie import CassieEnv
from torchrl_ahrs.envs.tasks.cassie_model import load_cassie_model


def mirror_state(model, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The MuJoCo state reflected in the pelvis's x-z plane, built from the model's joint names and axes (every
    hinge, the passive tarsus included), independently of the map under test: a rotation by θ about axis a
    reflects to one by θ about -M a, M = diag(1, -1, 1), which is θ' = -(M a)·a' about the partner's axis a'
    (the model's body frames are the world's at zero angles)."""
    qpos_m, qvel_m = qpos.copy(), qvel.copy()
    qpos_m[1] = -qpos[1]  # free joint position: (x, -y, z)
    qpos_m[3:7] = qpos[3:7] * np.array([1.0, -1.0, 1.0, -1.0])  # rotation about (-n_x, n_y, -n_z): (w, -x, y, -z)
    qvel_m[0:6] = qvel[0:6] * np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])  # world v: (x, -y, z); body ω: (-x, y, -z)
    for joint in range(1, model.njnt):  # joint 0 is the free joint
        name = model.joint(joint).name
        partner = model.joint(("r_" if name.startswith("l_") else "l_") + name[2:])
        reflected = -model.jnt_axis[joint] * np.array([1.0, -1.0, 1.0])  # -M a
        sign = float(reflected @ model.jnt_axis[partner.id])  # θ' = (-M a)·a'
        assert abs(sign) == 1.0, f"{name}: the partner's axis is not the reflected one"
        qpos_m[model.jnt_qposadr[partner.id]] = sign * qpos[model.jnt_qposadr[joint]]
        qvel_m[model.jnt_dofadr[partner.id]] = sign * qvel[model.jnt_dofadr[joint]]
    return qpos_m, qvel_m


class MirroredPairEnv(CassieEnv):
    """Two Cassies, the second starting in the mirror image of the first's random reset state."""

    def reset_state(self, env_ids, rng):
        qpos, qvel = super().reset_state(env_ids, rng)
        qpos[1], qvel[1] = mirror_state(self.model, qpos[0], qvel[0])
        return qpos, qvel


def test_a_mirrored_cassie_under_mirrored_actions_observes_the_mirror_image_and_the_same_reward():
    maps = task_mirror(load_task_settings("cassie"))
    observation_map, action_map = maps["observation"], maps["action"]
    model, layout = load_cassie_model()
    env = MirroredPairEnv(model, layout, num_envs=2, seed=3)
    td = env.reset()
    env.commands[1] = env.commands[0] * torch.tensor([1.0, -1.0, -1.0], dtype=env.commands.dtype)
    generator = torch.Generator().manual_seed(0)
    for _ in range(40):  # 0.8 s, long enough for the feet to touch down and leave the home pose
        action = torch.rand(1, 10, generator=generator) * 2 - 1
        td.set("action", torch.cat([action, action_map(action)]))
        td = env.step(td)["next"].clone()
        observation = td.get("observation")
        torch.testing.assert_close(observation[1], observation_map(observation[:1])[0], atol=1e-6, rtol=1e-6)
        for name, term in env.reward_terms().items():
            torch.testing.assert_close(term[1], term[0], atol=1e-9, rtol=1e-6, msg=f"reward term {name}")
    assert env.episode_steps.min() == 40  # neither fell: the pair was compared over the whole stretch


def test_the_mirror_maps_are_involutions_of_the_observation_and_action():
    maps = task_mirror(load_task_settings("cassie"))
    observation = torch.randn(5, 42, dtype=torch.float64)
    torch.testing.assert_close(maps["observation"](maps["observation"](observation)), observation)
    assert maps["action"].size == 10


@pytest.mark.parametrize(
    ("indices", "signs", "message"),
    [
        ((0, 0), (1, 1), "permutation"),
        ((1, 0), (1, -1), "not a mirror"),
        ((0, 1), (1, 2), r"\+1 or -1"),
        ((0, 1), (1,), "one sign per index"),
    ],
)
def test_a_map_that_is_not_a_signed_mirror_is_refused_in_one_line(indices, signs, message):
    with pytest.raises(ValueError, match=message):
        SignedPermutation(indices, signs)


def test_a_task_without_a_mirror_and_another_cassie_model_are_refused():
    with pytest.raises(ValueError, match="defines no left-right mirror"):
        task_mirror(load_task_settings("quadcopter"))
    other = load_task_settings("cassie", ["task.model_path=/elsewhere/scene.xml"])
    with pytest.raises(ValueError, match="shipped model"):
        task_mirror(other)
