"""MirrorAugmentation (``ppo.mirror``): the minibatch and its mirror image; for a mirror-equivariant policy the
PPO objective and the KL on the doubled minibatch are the original's (the mirrored half is the same data seen in
the mirror), and the loop hands the loss the doubled minibatch."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded

from torchrl_ahrs.envs.common.mirror import MirrorAugmentation, SignedPermutation
from torchrl_ahrs.training.loss import HybridClipPPOLoss
from torchrl_ahrs.training.models import RunningNorm, build_actor, build_critic

OBSERVATION = SignedPermutation((0, 2, 1, 3), (1.0, 1.0, 1.0, -1.0))  # swap two legs, flip a sideways speed
ACTION = SignedPermutation((1, 0, 2), (1.0, 1.0, -1.0))  # swap two joints, flip a yaw joint


def matrix(mirror: SignedPermutation) -> torch.Tensor:
    """P with (P x)_i = s_i x_{idx_i}."""
    return torch.eye(mirror.size)[list(mirror.indices)] * torch.tensor(mirror.signs)[:, None]


def linear_actor(equivariant: bool, seed: int):
    """A linear tanh-Gaussian policy; equivariant: loc(P_o x) = P_a loc(x) and a σ the mirror leaves alone."""
    torch.manual_seed(seed)
    spec = Bounded(-torch.ones(3), torch.ones(3), (3,))
    actor = build_actor(RunningNorm(4), 4, spec, [], distribution="tanh_normal")
    linear = actor.module[0].module[1][-1]
    scale = actor.module[0].module[2]
    with torch.no_grad():
        linear.weight.copy_(torch.randn(3, 4))
        linear.bias.copy_(torch.randn(3) * 0.3)
        scale.state_independent_scale.copy_(
            torch.tensor([-0.4, -0.4, -0.6]) + (0 if equivariant else torch.tensor([0.0, 0.3, 0.0]))
        )
        if equivariant:
            p_a, p_o = matrix(ACTION), matrix(OBSERVATION)
            linear.weight.copy_((linear.weight + p_a @ linear.weight @ p_o) / 2)  # W = P_a W P_o
            linear.bias.copy_((linear.bias + p_a @ linear.bias) / 2)  # b = P_a b
    return actor


def collected_batch(actor) -> TensorDict:
    with torch.no_grad():
        batch = actor(TensorDict({"observation": torch.randn(64, 4)}, [64]))
    batch["advantage"], batch["value_target"] = torch.randn(64, 1), torch.randn(64, 1)
    return batch


def test_the_mirror_half_holds_mirrored_states_actions_and_gaussians_and_repeats_everything_else():
    augment = MirrorAugmentation.for_policy(OBSERVATION, ACTION)
    batch = collected_batch(linear_actor(equivariant=False, seed=0))
    out = augment(batch)
    assert out.batch_size == torch.Size([128])
    assert torch.equal(out[:64]["observation"], batch["observation"])
    assert torch.equal(out[64:]["observation"], OBSERVATION(batch["observation"]))
    assert torch.equal(out[64:]["action"], ACTION(batch["action"]))
    assert torch.equal(out[64:]["loc"], ACTION(batch["loc"]))
    assert torch.equal(out[64:]["scale"], batch["scale"][:, [1, 0, 2]])  # σ permuted, never negated
    for key in ("advantage", "value_target", "action_log_prob"):
        assert torch.equal(out[64:][key], batch[key]), key


@pytest.mark.parametrize("equivariant", [True, False])
def test_for_an_equivariant_policy_the_doubled_minibatch_gives_the_originals_objective_and_kl(equivariant):
    """Oracle: with loc(P_o x) = P_a loc(x) and a mirror-invariant σ, the mirrored action's probability under
    the mirrored state is the original's, so every ratio, clip and KL is repeated: the means do not move. A policy
    that is not equivariant must move them (the test can fail)."""
    collecting = linear_actor(equivariant, seed=1)
    batch = collected_batch(collecting)
    current = linear_actor(equivariant, seed=2)  # another policy of the same kind: ratios are not 1
    critic = build_critic(RunningNorm(4), 4, 1, [8])
    loss = HybridClipPPOLoss(current, critic, functional=False, kl=True, entropy_bonus=False)
    original = loss(batch.clone())
    doubled = loss(MirrorAugmentation.for_policy(OBSERVATION, ACTION)(batch.clone()))
    for key in ("loss_objective", "kl"):
        same = torch.allclose(doubled[key], original[key], rtol=1e-5, atol=1e-6)
        assert same == equivariant, (key, doubled[key].item(), original[key].item())


def test_an_empty_set_of_maps_is_refused():
    with pytest.raises(ValueError, match="at least one key"):
        MirrorAugmentation({})
