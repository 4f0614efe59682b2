"""Per-component GAE in one vectorized pass, mixed by replaceable weights."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torchrl.modules.value_norm import ValueNorm
from torchrl.objectives.value import GAE

from torchrl_ahrs.value.functional import (
    anchored_coefficients,
    effective_shares,
    mix_advantages,
    normalize_components,
    scale_by,
    stack_components,
)

COMPONENT_SCALES = ("raw", "standardize", "value_norm")
MIXES = ("sum", "anchored")  # Σ_k w_k A_k (the paper's), or around the summed reward's own advantage (ppo.mix)
# rows per block of the CPU's matrix kernels, as measured on x86 (a partial last block is summed in another order):
# the state-value pass pads its input to whole blocks (WeightedMultiGAE._call_value_nets); the values are right
# either way, the padding only keeps them bit for bit those of the two-call pass
GEMM_ROW_BLOCK = 8
ANCHOR = "anchor"  # the name of the anchored mix's extra column (the summed reward), in `columns` and share/<c>


class WeightedMultiGAE(GAE):
    """GAE over K reward components at once, mixed into one advantage for the policy.

    Keys follow TorchRL's meaning: ``reward`` names the *reward tree* whose leaves
    ``("next", reward, c)`` ``[*B, T, 1]`` are read in ``components`` order (the layout written by
    :class:`~torchrl_ahrs.rewards.RewardComponents`). Nothing is written into the tree. TorchRL's GAE
    recursion runs once on the stack ``[*B, T, K]`` with a K-column value network (done/terminated are
    expanded to K). Writes:

    - ``"advantage_components"`` ``[*B, T, K]``: each component's GAE advantage ``A_k``;
    - ``"value_target"`` ``[*B, T, K]``: each head's regression target;
    - ``"advantage"`` ``[*B, T, 1]``: ``Σ_k w_k A_k`` — the signal the policy is trained on.

    ``anchored=True`` adds a column, the summed reward ``Σ_k r_k`` (named :data:`ANCHOR`), which the value network
    answers with a value of its own (``MultiHeadCritic(..., anchor_head=True)``: a separate MLP), so every output
    above has K + 1 columns, and mixes ``A = w̄ A_Σ + Σ_k (w_k - w̄) A_k``
    (:func:`~torchrl_ahrs.value.functional.anchored_coefficients`). Equal weights then train the policy on PPO's
    advantage from PPO's kind of critic, one network on the summed reward, and only a schedule's deviations from
    equal weights read the K heads: a method at equal weights is PPO, so it cannot lose to PPO through the K-head
    critic alone. When every critic is exact the two mixes agree (GAE is linear).

    ``component_scale`` says how each ``A_k`` is scaled before mixing (the unscaled ``A_k`` stay in
    ``"advantage_components"``):

    - ``"raw"``: as GAE gives it, so the reward scales, not the weights, decide each component's share;
    - ``"standardize"``: ``(A_k - mean) / std`` over the batch, so the weights alone decide the shares;
    - ``"value_norm"``: ``A_k / sigma_k`` with ``sigma_k`` head ``k``'s scale in the critic's value
      normaliser ``value_norm`` (TorchRL's :meth:`~torchrl.modules.value_norm.ValueNorm.scale`, the running
      std of the value targets of the batches so far): steadier than one batch's std, without centring,
      and one set of statistics for the critic and the mix. Before the normaliser has seen a batch (its
      buffers are all zero) the batch's own population std stands in: what it holds once it folds that
      batch in.

    After every call ``shares`` ``[C]`` holds each column's effective share of the mixed advantage,
    ``|c_j| std(A'_j) / sum_i |c_i| std(A'_i)`` with ``A'`` the scaled advantages and ``c`` the mixing coefficients
    (``w``, or the anchored ones); ``columns`` names them (the components, then :data:`ANCHOR` when anchored) and
    they are logged as ``share/<column>``.

    ``weights`` is a registered buffer ``[K]`` (checkpointed with the module); replace it any time with
    :meth:`set_weights`. Keys are configurable with ``set_keys`` (``reward``, ``advantage``,
    ``advantage_components``, ``value_target``, ``value``, ``done``, ``terminated``). A PPO loss uses it
    through ``loss.make_value_estimator(gae)`` (or :class:`~torchrl_ahrs.training.HybridClipPPOLoss`
    with ``components=``).

    Args:
        components: reward component names; their order is the K axis.
        gamma, lmbda: GAE discount and lambda.
        value_network: a module writing ``"state_value"`` ``[*B, T, K]``.
        weights: initial ``[K]`` weights (default all ones).
        component_scale: ``"raw"`` | ``"standardize"`` | ``"value_norm"`` (see above).
        value_norm: the critic's per-head value normaliser (a TorchRL ``ValueNorm`` with ``shape=C``, e.g.
            from :func:`~torchrl_ahrs.training.value_norm.make_value_norm`), or ``None``; required by
            ``component_scale="value_norm"``, only read here (its owner updates it).
        anchored: mix around the summed reward's own advantage (above); the value network returns K + 1 values.
        **kwargs: forwarded to :class:`torchrl.objectives.value.GAE`.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from tensordict.nn import TensorDictModule
        >>> critic = TensorDictModule(torch.nn.Linear(3, 2), in_keys=["observation"], out_keys=["state_value"])
        >>> gae = WeightedMultiGAE(["a", "b"], gamma=0.99, lmbda=0.95, value_network=critic,
        ...                        weights=torch.tensor([0.5, 1.5]))
        >>> B, T = 4, 8
        >>> td = TensorDict({
        ...     "observation": torch.randn(B, T, 3),
        ...     "next": {"observation": torch.randn(B, T, 3),
        ...              "reward": {"total": torch.randn(B, T, 1), "a": torch.randn(B, T, 1), "b": torch.randn(B, T, 1)},
        ...              "done": torch.zeros(B, T, 1, dtype=torch.bool),
        ...              "terminated": torch.zeros(B, T, 1, dtype=torch.bool)}}, [B, T])
        >>> td = gae(td)
        >>> td["advantage_components"].shape, td["advantage"].shape, td["next", "reward", "total"].shape
        (torch.Size([4, 8, 2]), torch.Size([4, 8, 1]), torch.Size([4, 8, 1]))
        >>> gae.out_keys
        ['advantage', 'advantage_components', 'value_target']
        >>> round(gae.shares.sum().item(), 4)
        1.0

        The anchored mix with equal weights is the anchor's advantage alone (PPO's, from its own critic):

        >>> critic3 = TensorDictModule(torch.nn.Linear(3, 3), in_keys=["observation"], out_keys=["state_value"])
        >>> anchored = WeightedMultiGAE(["a", "b"], gamma=0.99, lmbda=0.95, value_network=critic3, anchored=True)
        >>> td = anchored(td)
        >>> anchored.columns, td["advantage_components"].shape
        (['a', 'b', 'anchor'], torch.Size([4, 8, 3]))
        >>> torch.equal(td["advantage"], td["advantage_components"][..., 2:])
        True
    """

    @dataclass
    class _AcceptedKeys:
        # every field is restated: TorchRL's set_keys only accepts names defined on this class itself
        advantage: NestedKey = "advantage"
        advantage_components: NestedKey = "advantage_components"
        value_target: NestedKey = "value_target"
        value: NestedKey = "state_value"
        reward: NestedKey = "reward"  # the reward tree's root: components are ("next", reward, c)
        done: NestedKey = "done"
        terminated: NestedKey = "terminated"
        steps_to_next_obs: NestedKey = "steps_to_next_obs"
        sample_log_prob: NestedKey | None = None

    default_keys = _AcceptedKeys

    def __init__(
        self,
        components: Sequence[str],
        *,
        gamma: float,
        lmbda: float,
        value_network: TensorDictModule | None,
        weights: torch.Tensor | None = None,
        component_scale: str = "raw",
        value_norm: ValueNorm | None = None,
        anchored: bool = False,
        **kwargs,
    ):
        super().__init__(gamma=gamma, lmbda=lmbda, value_network=value_network, **kwargs)
        self.components = list(components)
        if not self.components:
            raise ValueError("WeightedMultiGAE needs at least one component")
        if component_scale not in COMPONENT_SCALES:
            raise ValueError(f"component_scale must be one of {', '.join(COMPONENT_SCALES)}, got {component_scale!r}")
        if component_scale == "value_norm" and value_norm is None:
            raise ValueError(
                "component_scale='value_norm' divides each A_k by its head's scale in the critic's value "
                "normaliser: pass value_norm= (in a run: ppo.value_norm=running or popart)"
            )
        if anchored and ANCHOR in self.components:
            raise ValueError(f"the anchored mix names its extra column {ANCHOR!r}: rename that reward component")
        self.component_scale = component_scale
        self.value_norm = value_norm
        self.anchored = bool(anchored)
        self.columns = self.components + ([ANCHOR] if self.anchored else [])  # the GAE columns, C = K (+ 1)
        self.register_buffer("weights", torch.ones(len(self.components)))
        self.register_buffer("shares", torch.full((len(self.columns),), 1.0 / len(self.columns)))
        if weights is not None:
            self.set_weights(weights)

    @property
    def num_components(self) -> int:
        return len(self.components)

    @property
    def in_keys(self) -> list[NestedKey]:
        """The value network's inputs (now and next), every component leaf, done and terminated."""
        value_in = list(getattr(self.value_network, "in_keys", []))
        return [
            *value_in,
            *self.component_reward_keys(),
            ("next", self.tensor_keys.done),
            ("next", self.tensor_keys.terminated),
            *[("next", *((key,) if isinstance(key, str) else key)) for key in value_in],
        ]

    @property
    def out_keys(self) -> list[NestedKey]:
        return [self.tensor_keys.advantage, self.tensor_keys.advantage_components, self.tensor_keys.value_target]

    def set_weights(self, weights: torch.Tensor | Sequence[float]) -> None:
        """Replaces the mixing weights in place; they must be K finite numbers."""
        weights = torch.as_tensor(weights, dtype=self.weights.dtype, device=self.weights.device)
        if weights.shape != self.weights.shape:
            raise ValueError(
                f"weights must have shape [K]=[{self.num_components}] for components {self.components}, "
                f"got {tuple(weights.shape)}"
            )
        if not torch.isfinite(weights).all():
            raise ValueError(f"weights must be finite, got {weights.tolist()}")
        self.weights.copy_(weights)

    def mixing_coefficients(self) -> torch.Tensor:
        """``[C]``: the weights ``w`` or, anchored, ``[w_1 - w̄, ..., w_K - w̄, w̄]``."""
        return anchored_coefficients(self.weights) if self.anchored else self.weights

    def component_reward_keys(self) -> list[tuple]:
        """``[("next", *reward, c) for c in components]``: the leaves read, in K order."""
        tree = self.tensor_keys.reward
        tree = tree if isinstance(tree, tuple) else (tree,)
        return [("next", *tree, name) for name in self.components]

    def forward(self, tensordict: TensorDictBase, **kwargs) -> TensorDictBase:
        """Writes the K component advantages, the K value targets and the mixed advantage.

        Args:
            tensordict: ``[*B, T]`` data with the value network's inputs (now and ``"next"``), the
                component leaves ``("next", reward, c)`` ``[*B, T, 1]``, ``("next", "done")`` and
                ``("next", "terminated")``.
            **kwargs: ``params``/``target_params``/``time_dim``, as for TorchRL's GAE (a loss passes them).

        Returns:
            ``tensordict`` with ``advantage_components`` ``[*B, T, K]``, ``value_target`` ``[*B, T, K]`` and
            ``advantage`` ``[*B, T, 1]`` = ``Σ_k w_k A_k`` (each ``A_k`` scaled by ``component_scale``
            first); ``shares`` ``[K]`` is updated.
        """
        reward = tensordict.get(("next", self.tensor_keys.reward), None)
        if not isinstance(reward, TensorDictBase):
            found = "nothing" if reward is None else f"a tensor of shape {tuple(reward.shape)}"
            raise KeyError(
                f"WeightedMultiGAE reads the reward tree ('next', {self.tensor_keys.reward!r}) with leaves "
                f"{self.components}, found {found}; set_keys(reward=...) names the tree's root (e.g. 'reward'), "
                "not the total"
            )
        missing = [name for name in self.components if name not in reward.keys()]
        if missing:
            raise KeyError(f"the reward tree has no leaves {missing} (it has {sorted(reward.keys())})")
        with torch.no_grad():
            # GAE reads the tree and hands it to _prepare_signals, which stacks it to [*B, T, K]
            super().forward(tensordict, **kwargs)
            component_advantages = tensordict.get(self.tensor_keys.advantage)  # [*B, T, K]
            tensordict.set(self.tensor_keys.advantage_components, component_advantages)
            to_mix = self.scale_components(component_advantages, tensordict.get(self.tensor_keys.value_target))
            coefficients = self.mixing_coefficients()  # [C]
            self.shares.copy_(effective_shares(to_mix, coefficients))  # [C]
            tensordict.set(self.tensor_keys.advantage, mix_advantages(to_mix, coefficients))  # [*B, T, 1]
        return tensordict

    def scale_components(self, advantages: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        """``advantages [*B, T, K]`` scaled by ``component_scale``; ``targets [*B, T, K]`` (reward units) give
        ``value_norm``'s first scale."""
        if self.component_scale == "standardize":
            return normalize_components(advantages)
        if self.component_scale == "raw":
            return advantages
        value_norm = self.value_norm
        assert value_norm is not None  # checked in __init__
        if any(buffer.any() for buffer in value_norm.buffers()):
            scale = value_norm.scale()  # sigma_k of the targets seen so far
        else:  # a fresh normaliser (all buffers zero) would give its epsilon floor
            scale = targets.reshape(-1, targets.shape[-1]).std(0, unbiased=False)  # sigma_k = std over the batch
        return scale_by(advantages, scale)  # A_k / sigma_k

    def _call_value_nets(
        self,
        data: TensorDictBase,
        params: TensorDictBase | None,
        next_params: TensorDictBase | None,
        single_call: bool,
        value_key: NestedKey,
        detach_next: bool,
        vmap_randomness: str = "error",
        *,
        value_net: TensorDictModule | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """``V(s_t)`` and ``V(s'_t)`` ``[*B, T, C]``, evaluating each distinct state once when the batch chains.

        In a collector's batch the next state of step ``t`` *is* the state of step ``t + 1`` unless the episode
        ended at ``t`` (the collector reset it). TorchRL's default pass evaluates the critic on both ``[*B, T]``
        halves; here it runs once on the ``B T`` states plus the ``M`` next states nothing else gives (each row's
        last step and every step that ended an episode), and ``V(s'_t) = V(s_{t+1})`` elsewhere: about half the
        rows (Cassie 128 x 12: 1 536 + ~130 rows instead of 3 072). The critic is row-wise, so the values are the
        two-call pass's (tests/value/test_value.py compares them bit for bit). The shortcut is taken only after
        checking that the batch chains (``s'_t == s_{t+1}`` wherever no episode ended); otherwise, and for what it
        does not cover (functional ``params``, TorchRL's ``shifted`` / chunked options, recurrent ``is_init``,
        time not the last batch dimension), TorchRL's own pass runs. (TorchRL's ``shifted=True`` also calls the
        critic once, but on a fixed budget of extra slots: a row with more resets than the budget loses samples.) This overrides TorchRL's (private) value
        pass of torchrl 0.14, which ``GAE.forward`` calls; tests/value/test_value.py fails if that call goes elsewhere.
        """
        net = self.value_network if value_net is None else value_net
        time_dim = self._get_time_dim(None, data)
        chained = (
            params is None
            and next_params is None
            and not single_call
            and self.value_chunk_size is None
            and self.num_chunks is None
            and time_dim == data.ndim - 1
            and "is_init" not in data.keys()
        )
        in_keys = list(net.in_keys)
        states = data.select(*in_keys, strict=False)
        next_states = data.get("next").select(*in_keys, strict=False)
        ended = data.get(("next", self.tensor_keys.done)).squeeze(-1)  # [*B, T]: the collector reset after these
        if chained:
            chained = len(states.keys(True, True)) == len(in_keys) == len(next_states.keys(True, True))
        if chained:  # s'_t == s_{t+1} wherever the episode went on: then only the other next states need the critic
            went_on = ~ended[..., :-1]  # [*B, T - 1]
            followers, successors = states[..., 1:][went_on], next_states[..., :-1][went_on]  # batch-dim indexing
            chained = all(torch.equal(successors.get(key), followers.get(key)) for key in in_keys)
        if not chained:
            return super()._call_value_nets(
                data, params, next_params, single_call, value_key, detach_next, vmap_randomness, value_net=value_net
            )
        evaluated_apart = ended.clone()  # [*B, T]: the next states to evaluate, each row's last step included
        evaluated_apart[..., -1] = True
        count = states.numel()
        apart = int(evaluated_apart.sum())  # M
        inputs = torch.cat([states.reshape(-1), next_states[evaluated_apart]], 0)  # [B T + M]
        # padded to whole blocks of GEMM_ROW_BLOCK rows: the matrix kernels sum a partial last block in another
        # order, and whole blocks made every value checked bit for bit the two-call pass's
        padding = -inputs.shape[0] % GEMM_ROW_BLOCK
        if padding:
            inputs = torch.cat([inputs, inputs[:padding]], 0)
        values = net(inputs).get(value_key)  # [B T + M (+ padding), C]
        value = values[:count].reshape(*data.shape, -1)  # V(s_t) [*B, T, C]
        next_value = torch.empty_like(value)
        next_value[..., :-1, :] = value[..., 1:, :]  # V(s'_t) = V(s_{t+1}) where the episode went on
        next_value[evaluated_apart] = values[count : count + apart]  # and evaluated where it ended or the window does
        data.set(value_key, value)
        data.set(("next", value_key), next_value)
        return value, next_value.detach() if detach_next else next_value, None

    def _prepare_signals(self, reward, done, terminated, value):
        rewards = stack_components([reward.get(name) for name in self.components])  # [*B, T, K]
        if self.anchored:  # the anchor's column: the summed reward, r_Σ = Σ_k r_k
            rewards = torch.cat([rewards, rewards.sum(-1, keepdim=True)], dim=-1)  # [*B, T, K + 1]
        # TorchRL's recursion broadcasts silently; a critic with the wrong number of heads must fail loudly.
        if value.shape[-1] != rewards.shape[-1]:
            raise ValueError(
                f"the value network returned {value.shape[-1]} value(s) per state but there are "
                f"{rewards.shape[-1]} GAE columns {self.columns}; build the critic with one head per column"
                + (" (MultiHeadCritic(..., anchor_head=True) for the anchor)" if self.anchored else "")
            )
        return rewards, done.expand_as(rewards), terminated.expand_as(rewards)
