"""Reward components as a TensorDict key tree.

The environment's scalar reward becomes a nested entry::

    ("next", "reward", "total")      # the environment's own reward, untouched   [*B, 1]
    ("next", "reward", <component>)  # one leaf per named component               [*B, 1]

The order of ``components`` is the K axis everywhere downstream (critic heads, GAE, weights).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import Composite, Unbounded
from torchrl.envs.transforms import Transform

TOTAL = "total"

ComponentFn = Callable[[TensorDictBase], Mapping[str, torch.Tensor]]


class RewardComponents(Transform):
    """Writes one reward leaf per named component next to the environment's own reward.

    Components come from entries the environment already writes (``term_keys``, e.g. EnvPool's
    ``("info", "reward_forward")``), optionally multiplied by ``scales``, or from a function of the
    step's ``next`` tensordict (``component_fn``) that returns ``{name: tensor [*B] or [*B, 1]}``.
    The environment's reward is kept at ``(reward_key, "total")``.

    Args:
        components: component names, in the order that defines the K axis.
        term_keys: ``{component: key in the next tensordict}``.
        scales: ``{component: factor}`` applied to ``term_keys`` entries (default 1).
        component_fn: alternative source, called on the next tensordict.
        reward_key: the environment's reward entry (default ``"reward"``).

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> rc = RewardComponents(["a", "b"], term_keys={"a": ("info", "a"), "b": ("info", "b")})
        >>> step = TensorDict({"reward": torch.ones(2, 1),
        ...                    "info": {"a": torch.tensor([0.25, 0.5]), "b": torch.tensor([0.75, 0.5])}}, [2])
        >>> out = rc._step(TensorDict({}, [2]), step)
        >>> out["reward", "a"].squeeze(-1).tolist(), out["reward", "total"].shape
        ([0.25, 0.5], torch.Size([2, 1]))
    """

    def __init__(
        self,
        components: Sequence[str],
        term_keys: Mapping[str, NestedKey] | None = None,
        scales: Mapping[str, float] | None = None,
        component_fn: ComponentFn | None = None,
        reward_key: str = "reward",
    ):
        components = list(components)
        if not components:
            raise ValueError("RewardComponents needs at least one component name.")
        if len(set(components)) != len(components):
            raise ValueError(f"Component names must be unique, got {components}.")
        if (term_keys is None) == (component_fn is None):
            raise ValueError("Give exactly one source of components: term_keys or component_fn.")
        if term_keys is not None:
            missing = [name for name in components if name not in term_keys and name != TOTAL]
            if missing:
                raise ValueError(f"No term key for components {missing}; term_keys has {sorted(term_keys)}.")
        super().__init__(in_keys=[reward_key], out_keys=[(reward_key, TOTAL)] + [(reward_key, c) for c in components])
        self.components = components
        self.term_keys = dict(term_keys or {})
        self.scales = {name: float(value) for name, value in (scales or {}).items()}
        self.component_fn = component_fn
        self.reward_key = reward_key

    def component_terms(self, next_tensordict: TensorDictBase) -> dict[str, torch.Tensor]:
        """Returns ``{component: tensor [*B, 1]}`` for one step (``total`` excluded)."""
        if self.component_fn is not None:
            raw = dict(self.component_fn(next_tensordict))
        else:
            raw = {
                name: next_tensordict.get(self.term_keys[name]) * self.scales.get(name, 1.0)
                for name in self.components
                if name != TOTAL
            }
        batch_shape = next_tensordict.batch_size
        terms = {}
        for name in self.components:
            if name == TOTAL:
                continue
            if name not in raw:
                raise KeyError(f"component function returned no entry for {name!r} (got {sorted(raw)}).")
            value = raw[name].to(torch.float32)
            if value.shape == batch_shape:
                value = value.unsqueeze(-1)
            if value.shape != (*batch_shape, 1):
                raise ValueError(f"component {name!r} has shape {tuple(value.shape)}, expected {(*batch_shape, 1)}.")
            terms[name] = value
        return terms

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        native = next_tensordict.get(self.reward_key)
        if isinstance(native, TensorDictBase):  # already split (e.g. a second transform upstream)
            native = native.get(TOTAL)
        terms = self.component_terms(next_tensordict)
        tree = TensorDict({TOTAL: native.to(torch.float32), **terms}, batch_size=next_tensordict.batch_size)
        next_tensordict.del_(self.reward_key)
        next_tensordict.set(self.reward_key, tree)
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset

    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        native = reward_spec[self.reward_key]
        if isinstance(native, Composite):
            native = native[TOTAL]
        leaf = Unbounded(shape=native.shape, dtype=torch.float32, device=native.device)
        tree = Composite(
            {name: leaf.clone() for name in [TOTAL, *[c for c in self.components if c != TOTAL]]},
            shape=native.shape[:-1],
            device=native.device,
        )
        del reward_spec[self.reward_key]
        reward_spec[self.reward_key] = tree
        return reward_spec


def component_reward_keys(components: Sequence[str], reward_key: str = "reward") -> list[tuple[str, str]]:
    """Reward leaves in K order, e.g. ``[("reward", "forward"), ("reward", "ctrl")]``."""
    return [(reward_key, name) for name in components]


def episode_return_keys(components: Sequence[str]) -> list[tuple[str, str]]:
    """Where :class:`torchrl.envs.RewardSum` accumulates each component's episode return."""
    return [("episode_reward", name) for name in components]


def finished_episode_returns(batch: TensorDictBase, components: Sequence[str]) -> torch.Tensor:
    """Returns of every episode that ended in ``batch``, one column per component: ``[M, K]``.

    Reads the ``RewardSum`` accumulators at ``("next", "episode_reward", c)`` where
    ``("next", "done")`` is set.
    """
    done = batch.get(("next", "done")).squeeze(-1)
    columns = [batch.get(("next", *key))[done].reshape(-1) for key in episode_return_keys(components)]
    return torch.stack(columns, dim=-1)
