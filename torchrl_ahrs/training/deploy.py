"""The trained policy as a plain ``nn.Module`` for deployment: raw observation in, deterministic action out.

:class:`DeterministicPolicy` takes the actor built by :func:`~torchrl_ahrs.training.models.build_actor` apart
into what acting needs and nothing else: the observation normaliser (its running statistics frozen as
buffers), the mean network, and the map from the mean into the action bounds. No TensorDict, no
distribution object: the module is a fixed chain of tensor operations (no branch on the data), so
:func:`torch.jit.trace` and :func:`torch.onnx.export` record it exactly, for any batch size, and the files they write load without TorchRL or this package.

The action is the one evaluation uses (``ExplorationType.DETERMINISTIC``):

* ``tanh_normal``: ``a = c + h * clamp(tanh(mu), -(1 - eps), 1 - eps)`` with ``c = (high + low) / 2``,
  ``h = (high - low) / 2`` and ``eps`` float32's resolution, as TorchRL's ``TanhNormal`` computes its
  deterministic sample;
* ``normal``: ``a = clamp(mu, low, high)``, what the environment receives after
  :class:`~torchrl_ahrs.envs.common.clip_actions.ClipActionToSpec` (the rollout keeps ``mu`` itself).
"""

from __future__ import annotations

import copy

import torch
from torch import nn
from torchrl.modules import ProbabilisticActor, TanhNormal

SQUASHES = ("tanh", "clip")


class DeterministicPolicy(nn.Module):
    """``observation [B, obs_dim]`` (raw, as the environment emits it) → ``action [B, act_dim]`` in the bounds.

    Args:
        obs_norm: the observation normaliser (a :class:`~torchrl_ahrs.training.models.RunningNorm`).
        loc_net: the mean network, normalised observation ``[B, obs_dim]`` → ``mu [B, act_dim]``.
        low, high: the action bounds ``[act_dim]``.
        squash: ``"tanh"`` (a ``tanh_normal`` policy) or ``"clip"`` (a ``normal`` policy).

    Example:
        >>> import torch
        >>> from torchrl.data import Bounded
        >>> from torchrl_ahrs.training.models import RunningNorm, build_actor
        >>> actor = build_actor(RunningNorm(3), 3, Bounded(-torch.ones(2), torch.ones(2), (2,)), [8])
        >>> policy = DeterministicPolicy.from_actor(actor)
        >>> policy(torch.zeros(4, 3)).shape
        torch.Size([4, 2])
        >>> traced = torch.jit.trace(policy, torch.zeros(1, 3))  # no TorchRL inside
        >>> torch.equal(traced(torch.ones(5, 3)), policy(torch.ones(5, 3)))
        True
    """

    low: torch.Tensor  # buffers, declared for the type checker
    high: torch.Tensor

    def __init__(self, obs_norm: nn.Module, loc_net: nn.Module, low: torch.Tensor, high: torch.Tensor, squash: str):
        super().__init__()
        if squash not in SQUASHES:
            raise ValueError(f"squash must be one of {', '.join(SQUASHES)}, got {squash!r}")
        self.obs_norm, self.loc_net = obs_norm, loc_net
        self.register_buffer("low", low.detach().reshape(-1).clone().float())  # [act_dim] (a spec may hold [1, A])
        self.register_buffer("high", high.detach().reshape(-1).clone().float())
        self.tanh = squash == "tanh"
        self.limit = 1.0 - torch.finfo(torch.float32).resolution  # TorchRL's SafeTanhTransform keeps |tanh| below

    @classmethod
    def from_actor(cls, actor: ProbabilisticActor) -> DeterministicPolicy:
        """A copy (on the CPU, in eval mode) of the acting part of ``actor``; training ``actor`` later leaves
        the copy unchanged.

        Raises:
            ValueError: ``actor`` is not laid out as :func:`~torchrl_ahrs.training.models.build_actor` builds it.
        """
        try:
            obs_norm, loc_net, _scale = actor.module[0].module  # Sequential(obs_norm, loc_net, scale)
            distribution = actor.module[-1]
        except (AttributeError, TypeError, ValueError, IndexError) as error:
            raise ValueError(f"not an actor of training.models.build_actor: {error}") from error
        tanh = issubclass(distribution.distribution_class, TanhNormal)
        if tanh:
            low, high = distribution.distribution_kwargs["low"], distribution.distribution_kwargs["high"]
        else:
            space = actor.spec["action"].space if "action" in actor.spec.keys() else actor.spec.space
            low, high = space.low, space.high
        policy = cls(copy.deepcopy(obs_norm), copy.deepcopy(loc_net), low, high, "tanh" if tanh else "clip")
        return policy.cpu().eval().requires_grad_(False)  # acting only: no autograd graph in the exported files

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        loc = self.loc_net(self.obs_norm(observation))
        if self.tanh:
            squashed = torch.tanh(loc).clamp(-self.limit, self.limit)
            return (self.high + self.low) / 2 + (self.high - self.low) / 2 * squashed  # c + h * tanh(mu)
        return torch.maximum(torch.minimum(loc, self.high), self.low)  # clamp(mu, low, high), per dimension
