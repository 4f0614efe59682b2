"""PPO loss on the mixed advantage, critic loss over all K heads."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from tensordict import NestedKey, TensorDictBase
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.utils import ValueEstimators, default_value_kwargs
from torchrl.objectives.value import ValueEstimatorBase

from torchrl_ahrs.value.gae import WeightedMultiGAE


def gaussian_kl(loc_old: torch.Tensor, scale_old: torch.Tensor, loc_new: torch.Tensor, scale_new: torch.Tensor):
    """``KL(N(loc_old, scale_old) || N(loc_new, scale_new))`` summed over the last (action) dim: ``[*B, A] -> [*B]``.

    Example:
        >>> import torch
        >>> gaussian_kl(torch.zeros(1, 2), torch.ones(1, 2), torch.ones(1, 2), torch.ones(1, 2))
        tensor([1.])
    """
    log_ratio = torch.log(scale_new / scale_old)  # log(sigma_1 / sigma_0)
    spread = (scale_old**2 + (loc_old - loc_new) ** 2) / (2.0 * scale_new**2)  # (s0^2 + (m0 - m1)^2) / (2 s1^2)
    return (log_ratio + spread - 0.5).sum(-1)  # KL = sum_a [log(s1/s0) + spread - 1/2]


class HybridClipPPOLoss(ClipPPOLoss):
    """``ClipPPOLoss`` on the mixed advantage of a :class:`~torchrl_ahrs.value.WeightedMultiGAE`.

    ``ClipPPOLoss`` silently broadcasts an advantage with K columns against the ``[*B, 1]`` log-ratio,
    which trains on the *equally weighted* sum and ignores the schedule. Here the advantage must be the
    ``[*B, 1]`` output of :class:`~torchrl_ahrs.value.WeightedMultiGAE`; the critic is regressed on all
    K columns of ``"value_target"`` ``[*B, K]``.

    Without a precomputed ``"advantage"`` the loss runs its value estimator, as TorchRL's losses do:
    either one given with ``make_value_estimator(WeightedMultiGAE(...))``, or, with ``components=``, a
    ``WeightedMultiGAE`` built on the loss's critic by ``make_value_estimator()`` (TorchRL's GAE defaults
    ``gamma=0.99, lmbda=0.95`` unless given). ``set_keys(reward=...)`` names the reward *tree*
    (``"reward"`` by default), whose leaves ``("next", "reward", c)`` are the components.

    With ``kl=True`` it also writes ``"kl"``: the closed-form KL from the collecting policy's Gaussian (the
    ``loc`` / ``scale`` ``[*B, A]`` stored in the batch, keys set with ``set_keys(loc=, scale=)``) to the current
    one, before any tanh squash (KL is invariant under a bijection of both), averaged over the minibatch and
    detached. rsl_rl's adaptive learning rate reads this from its loss forward pass, and so does
    :func:`~torchrl_ahrs.training.loop.adaptive_kl_lr`: no second actor pass per minibatch. Off by default:
    it costs ~0.1 ms per minibatch (6 % of a [64, 64] loss forward at minibatch 64) that only that rule uses.

    Args:
        actor_network, critic_network: as for ``ClipPPOLoss``; the critic writes ``[*B, K]`` values.
        components: the K reward components, so the loss can build its own ``WeightedMultiGAE``.
        kl: also write ``"kl"`` (above), for an adaptive-KL learning rate.
        weights: initial ``[K]`` weights of that estimator (default ones).
        **kwargs: forwarded to ``ClipPPOLoss`` (``clip_epsilon``, ``entropy_coeff``, ``critic_coeff``, ...).

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from tensordict.nn import NormalParamExtractor, TensorDictModule
        >>> from torchrl.modules import ProbabilisticActor, TanhNormal
        >>> from torchrl_ahrs.value import MultiHeadCritic
        >>> net = torch.nn.Sequential(torch.nn.Linear(3, 2), NormalParamExtractor())
        >>> actor = ProbabilisticActor(TensorDictModule(net, ["observation"], ["loc", "scale"]),
        ...                            in_keys=["loc", "scale"], distribution_class=TanhNormal, return_log_prob=True)
        >>> critic = TensorDictModule(MultiHeadCritic(3, 2, hidden_sizes=[8]), ["observation"], ["state_value"])
        >>> loss = HybridClipPPOLoss(actor, critic, components=["a", "b"], weights=[1.0, 0.5])
        >>> td = TensorDict({"observation": torch.randn(4, 5, 3), "next": {
        ...     "observation": torch.randn(4, 5, 3), "reward": {"a": torch.randn(4, 5, 1), "b": torch.randn(4, 5, 1)},
        ...     "done": torch.zeros(4, 5, 1, dtype=torch.bool), "terminated": torch.zeros(4, 5, 1, dtype=torch.bool)}},
        ...     [4, 5])
        >>> with torch.no_grad():
        ...     td = actor(td)
        >>> sorted(k for k in loss(td).keys() if k.startswith("loss"))  # no advantage given: the loss computed it
        ['loss_critic', 'loss_entropy', 'loss_objective']
        >>> loss.value_estimator.weights.tolist(), loss.value_estimator(td)["advantage"].shape
        ([1.0, 0.5], torch.Size([4, 5, 1]))
        >>> HybridClipPPOLoss.check_advantage(TensorDict({"advantage": torch.zeros(4, 2)}, [4]), "advantage")
        Traceback (most recent call last):
        ...
        ValueError: the advantage has shape (4, 2) ...
    """

    @dataclass
    class _AcceptedKeys(ClipPPOLoss._AcceptedKeys):
        """``ClipPPOLoss``'s keys, plus where the actor writes its Gaussian's parameters: the batch holds the
        collecting policy's there, and the loss's actor pass writes the current policy's."""

        loc: NestedKey = "loc"
        scale: NestedKey = "scale"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys

    def __init__(
        self,
        actor_network,
        critic_network,
        *,
        components: Sequence[str] | None = None,
        weights: Sequence[float] | torch.Tensor | None = None,
        kl: bool = False,
        **kwargs,
    ):
        super().__init__(actor_network, critic_network, **kwargs)
        self.components = list(components) if components is not None else None
        self._initial_weights = weights
        self.kl = kl
        self._kl: torch.Tensor | None = None  # handed from _log_weight to forward within one forward pass

    @staticmethod
    def check_advantage(tensordict: TensorDictBase, key) -> None:
        """Refuses an advantage with more than one column (``[*B, K]``): it must be mixed first."""
        advantage = tensordict.get(key, None)
        if advantage is not None and advantage.shape[-1] != 1:
            raise ValueError(
                f"the advantage has shape {tuple(advantage.shape)} ... ClipPPOLoss would broadcast its "
                f"{advantage.shape[-1]} columns as equal weights; pass the mixed [*B, 1] advantage of "
                "WeightedMultiGAE (per-component advantages belong in 'advantage_components')"
            )

    def make_value_estimator(self, value_type=None, **hyperparams):
        """Installs a :class:`WeightedMultiGAE` (given, or built from ``components``); returns ``self``.

        ``value_type`` may be a ``WeightedMultiGAE`` instance, or ``None`` / ``ValueEstimators.GAE`` /
        ``WeightedMultiGAE`` to build one on the loss's critic with ``hyperparams`` (``gamma``, ``lmbda``,
        ``component_scale``, ...). Any other estimator would read the reward tree as one reward, so
        it is refused.
        """
        if isinstance(value_type, ValueEstimatorBase):
            if not isinstance(value_type, WeightedMultiGAE):
                raise TypeError(
                    f"HybridClipPPOLoss needs a WeightedMultiGAE (K components mixed by weights), got "
                    f"{type(value_type).__name__}"
                )
            return super().make_value_estimator(value_type)
        if value_type not in (None, ValueEstimators.GAE, WeightedMultiGAE):
            raise NotImplementedError(f"HybridClipPPOLoss supports WeightedMultiGAE only, got {value_type}")
        if self.components is None:
            raise ValueError(
                "HybridClipPPOLoss has no value estimator: pass components=[...] to the loss or call "
                "loss.make_value_estimator(WeightedMultiGAE(components, gamma=..., lmbda=..., value_network=critic))"
            )
        hp = {**default_value_kwargs(ValueEstimators.GAE), **hyperparams}
        hp.pop("device", None)
        hp.setdefault("weights", self._initial_weights)
        estimator = WeightedMultiGAE(self.components, value_network=self.critic_network, **hp)
        keys = self.tensor_keys
        estimator.set_keys(
            advantage=keys.advantage,
            value_target=keys.value_target,
            value=keys.value,
            reward=keys.reward,
            done=keys.done,
            terminated=keys.terminated,
        )
        self._value_estimator = estimator
        self.value_type = WeightedMultiGAE
        return self

    def _log_weight(self, tensordict: TensorDictBase, adv_shape: torch.Size):
        """``ClipPPOLoss._log_weight``, keeping the KL between the collecting and the current policy.

        ``tensordict`` is ``forward``'s shallow copy of the minibatch: the actor pass inside overwrites its
        ``loc`` / ``scale`` with the current policy's, so the collecting policy's are read first."""
        if not self.kl:
            return super()._log_weight(tensordict, adv_shape)
        keys = self.tensor_keys
        loc_old, scale_old = tensordict.get(keys.loc), tensordict.get(keys.scale)
        weights = super()._log_weight(tensordict, adv_shape)
        with torch.no_grad():
            self._kl = gaussian_kl(loc_old, scale_old, tensordict.get(keys.loc), tensordict.get(keys.scale)).mean()
        return weights

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        self.check_advantage(tensordict, self.tensor_keys.advantage)
        losses = super().forward(tensordict)
        if self._kl is not None:
            losses.set("kl", self._kl)
            self._kl = None
        return losses
