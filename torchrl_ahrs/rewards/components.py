"""Reward components as a TensorDict key tree next to the environment's own reward.

The key layout (the only place it is defined; every other module reads it from here)::

    ("next", "reward", "total")      # the environment's own reward, untouched; env.reward_key   [*B, 1]
    ("next", "reward", <component>)  # one leaf per named component                                [*B, 1]
    ("next", "episode_reward", c)    # ComponentRewardSum: running episode return of c (and total) [*B, 1]

``("reward", "total")`` is the environment's only reward leaf (its ``reward_spec``), so
``env.reward_key == ("reward", "total")`` and TorchRL's defaults keep working: ``RewardSum()`` sums the
total into ``("reward", "episode_total")``, ``check_env_specs`` passes, and a loss reads the total with
``loss.set_keys(reward=env.reward_key)``. The component leaves are declared in the observation spec under
the same ``"reward"`` root (the layout TorchRL's multi-agent envs use for ``("agents", "reward")``), so
they are not rewards to TorchRL: after ``step_mdp`` the root holds the previous step's components
(zeros after a reset). Their episode returns come from :class:`ComponentRewardSum`, a ``RewardSum`` that
also accepts these leaves.

The order of ``components`` is the K axis everywhere downstream (critic heads, GAE, weights).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import Composite, TensorSpec, Unbounded
from torchrl.envs.transforms import RewardSum, Transform

TOTAL = "total"
EPISODE_REWARD = "episode_reward"

ComponentFn = Callable[[TensorDictBase], Mapping[str, torch.Tensor]]


class TermMissing(LookupError):
    """A component's ``term_keys`` entry is not in the environment's step output (the message names both)."""


class ComponentLeaves(Transform):
    """Base of the transforms that write component leaves ``(reward_key, name)`` next to the total.

    It declares each leaf in the observation spec (float32 ``[*B, 1]``) and writes zeros for them at
    reset, so ``check_env_specs`` holds and the reward spec keeps its single leaf ``(reward_key, "total")``.
    Subclasses set ``self.leaf_names`` and write the leaves in ``_step``.
    """

    leaf_names: list[str]
    reward_key: str

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        # the root holds the previous step's components (step_mdp carries them); none before the first step
        for name in self.leaf_names:
            shape = (*tensordict_reset.batch_size, 1)
            tensordict_reset.set((self.reward_key, name), torch.zeros(shape, device=tensordict_reset.device))
        return tensordict_reset

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        shape, device = observation_spec.shape, observation_spec.device
        if self.reward_key not in observation_spec.keys():
            observation_spec[self.reward_key] = Composite(shape=shape, device=device)
        tree = observation_spec[self.reward_key]
        for name in self.leaf_names:
            tree[name] = Unbounded(shape=(*shape, 1), dtype=torch.float32, device=device)
        return observation_spec


class RewardComponents(ComponentLeaves):
    """Writes one reward leaf per named component next to the environment's own reward.

    Components come from entries the environment already writes (``term_keys``, e.g. EnvPool's
    ``("info", "reward_forward")``), optionally multiplied by ``scales``, or from a function of the
    step's ``next`` tensordict (``component_fn``) that returns ``{name: tensor [*B] or [*B, 1]}``.
    The environment's reward moves to ``(reward_key, "total")`` and stays the env's only reward
    (``env.reward_key``); the components are ``(reward_key, c)`` ``[*B, 1]`` float32 (see the module
    docstring for the whole layout).

    Args:
        components: component names, in the order that defines the K axis (``"total"`` may be one).
        term_keys: ``{component: key in the next tensordict}``.
        scales: ``{component: factor}`` applied to ``term_keys`` entries (default 1).
        component_fn: alternative source, called on the next tensordict.
        reward_key: the environment's reward entry (default ``"reward"``).

    Example:
        >>> from torchrl.envs import RewardSum, TransformedEnv
        >>> from torchrl.envs.utils import check_env_specs
        >>> from torchrl_ahrs.envs.tasks.point_reach import PointReachEnv
        >>> names = ["distance", "arrival", "ctrl"]
        >>> env = TransformedEnv(PointReachEnv(num_envs=2),
        ...                      RewardComponents(names, term_keys={c: ("info", f"reward_{c}") for c in names}))
        >>> env.reward_key
        ('reward', 'total')
        >>> check_env_specs(env)
        >>> env.append_transform(RewardSum())  # TorchRL's default: the env's reward key
        TransformedEnv(...)
        >>> td = env.rollout(3)
        >>> td["next", "reward", "distance"].shape, td["next", "reward", "episode_total"].shape
        (torch.Size([2, 3, 1]), torch.Size([2, 3, 1]))
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
        self.leaf_names = [c for c in components if c != TOTAL]
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
            raw = {name: self._term(next_tensordict, name) * self.scales.get(name, 1.0) for name in self.leaf_names}
        batch_shape = next_tensordict.batch_size
        terms = {}
        for name in self.leaf_names:
            if name not in raw:
                raise KeyError(f"component function returned no entry for {name!r} (got {sorted(raw)}).")
            value = torch.as_tensor(raw[name]).to(torch.float32)
            if value.shape == batch_shape:
                value = value.unsqueeze(-1)
            if value.shape != (*batch_shape, 1):
                raise ValueError(f"component {name!r} has shape {tuple(value.shape)}, expected {(*batch_shape, 1)}.")
            terms[name] = value
        return terms

    def _term(self, next_tensordict: TensorDictBase, name: str) -> torch.Tensor:
        key = self.term_keys[name]
        value = next_tensordict.get(key, None)
        if value is None:  # a misspelt term would otherwise be a component that is zero (or a TypeError) forever
            path = (key,) if isinstance(key, str) else tuple(key)
            parent = next_tensordict.get(path[:-1], None) if len(path) > 1 else next_tensordict
            present = sorted(str(k) for k in parent.keys()) if isinstance(parent, TensorDictBase) else []
            where = ".".join(path[:-1]) or "the step's output"
            raise TermMissing(
                f"component {name!r} reads {'.'.join(path)}, which the environment never writes; "
                f"{where} has: {', '.join(present) or 'nothing'}"
            )
        return value

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        native = next_tensordict.get(self.reward_key)
        if isinstance(native, TensorDictBase):  # already split (e.g. a second transform upstream)
            native = native.get(TOTAL)
        terms = self.component_terms(next_tensordict)
        tree = TensorDict({TOTAL: native.to(torch.float32), **terms}, batch_size=next_tensordict.batch_size)
        next_tensordict.del_(self.reward_key)
        next_tensordict.set(self.reward_key, tree)
        return next_tensordict

    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        native = reward_spec[self.reward_key]
        if isinstance(native, Composite):
            return reward_spec  # already a tree with its total
        leaf = Unbounded(shape=native.shape, dtype=torch.float32, device=native.device)
        del reward_spec[self.reward_key]
        reward_spec[self.reward_key] = Composite({TOTAL: leaf}, shape=native.shape[:-1], device=native.device)
        return reward_spec


class ComponentRewardSum(RewardSum):
    """``RewardSum`` over component leaves: ``("episode_reward", c)`` accumulates ``("reward", c)``.

    TorchRL's ``RewardSum`` only sums entries of the reward spec; the component leaves are declared in
    the observation spec (so that ``env.reward_key`` stays the single total), so this subclass looks
    each ``in_key`` up in both. Everything else — the per-episode reset, the ``[*B, 1]`` accumulators in
    the observation spec — is ``RewardSum``'s.

    Args:
        components: names whose returns are tracked (``"total"`` may be one).
        reward_key: the reward tree's root (default ``"reward"``).
        episode_key: the accumulators' root (default ``"episode_reward"``).

    Example:
        >>> from torchrl.envs import TransformedEnv
        >>> from torchrl_ahrs.envs.tasks.point_reach import PointReachEnv
        >>> names = ["distance", "ctrl"]
        >>> env = TransformedEnv(PointReachEnv(num_envs=2),
        ...                      RewardComponents(names, term_keys={c: ("info", f"reward_{c}") for c in names}))
        >>> env.append_transform(ComponentRewardSum(["distance", "ctrl", "total"]))
        TransformedEnv(...)
        >>> td = env.rollout(4)
        >>> ret = td["next", "episode_reward", "ctrl"][:, -1]
        >>> torch.allclose(ret, td["next", "reward", "ctrl"].sum(1))  # the return is the sum of rewards
        True
    """

    def __init__(self, components: Sequence[str], reward_key: str = "reward", episode_key: str = EPISODE_REWARD):
        components = list(components)
        super().__init__(
            in_keys=component_reward_keys(components, reward_key),
            out_keys=episode_return_keys(components, episode_key),
        )

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        # RewardSum's own reset reads the zero from the reward spec, where component leaves are not
        for out_key, reset_key in zip(self.out_keys, self.reset_keys, strict=True):
            value = tensordict.get(out_key, None)
            if value is None:
                value = torch.zeros((*tensordict_reset.batch_size, 1), device=tensordict_reset.device)
            else:
                reset = tensordict.get(reset_key, None)  # [*B] or [*B, 1]; absent = every env resets
                if reset is None:
                    value = torch.zeros_like(value)
                else:
                    reset = reset.reshape(*reset.shape, *[1] * (value.ndim - reset.ndim))
                    value = torch.where(reset.expand_as(value), 0.0, value)  # R_ep <- 0 where reset
            tensordict_reset.set(out_key, value)
        return tensordict_reset

    def _generate_episode_reward_spec(self) -> Composite:
        parent = self.parent
        sources = [parent.full_reward_spec, parent.full_observation_spec]
        spec = Composite(shape=parent.batch_size, device=parent.device)
        for in_key, out_key in zip(self.in_keys, self.out_keys, strict=True):
            leaf = _find_leaf(sources, in_key)
            if leaf is None:
                raise ValueError(
                    f"ComponentRewardSum: {in_key} is neither a reward nor a component leaf of the env; "
                    f"append RewardComponents first (reward keys {parent.reward_keys})"
                )
            *root, name = (out_key,) if isinstance(out_key, str) else out_key
            node = spec
            for part in root:  # create the intermediate composites, e.g. "episode_reward"
                if part not in node.keys():
                    node[part] = Composite(shape=parent.batch_size, device=parent.device)
                node = node[part]
            node[name] = leaf.clone()
        return spec


def _find_leaf(specs: Sequence[Composite], key: NestedKey) -> TensorSpec | None:
    for spec in specs:
        if key in spec.keys(True, True):
            return spec[key]
    return None


def component_reward_keys(components: Sequence[str], reward_key: str = "reward") -> list[tuple[str, str]]:
    """Reward leaves in K order, e.g. ``[("reward", "forward"), ("reward", "ctrl")]``."""
    return [(reward_key, name) for name in components]


def episode_return_keys(components: Sequence[str], episode_key: NestedKey = EPISODE_REWARD) -> list[tuple[str, ...]]:
    """Where :class:`ComponentRewardSum` accumulates each component's episode return."""
    root = (episode_key,) if isinstance(episode_key, str) else tuple(episode_key)
    return [(*root, name) for name in components]


def finished_episode_returns(
    batch: TensorDictBase, components: Sequence[str], episode_key: NestedKey = EPISODE_REWARD
) -> torch.Tensor:
    """Returns of every episode that ended in ``batch``, one column per component: ``[M, K]``.

    Reads the accumulators at ``("next", *episode_key, c)`` where ``("next", "done")`` is set; a
    missing accumulator raises a ``KeyError`` that names it.

    Example:
        >>> td = TensorDict({"next": {"done": torch.tensor([[True], [False]]),
        ...                           "episode_reward": {"a": torch.tensor([[2.0], [5.0]])}}}, [2])
        >>> finished_episode_returns(td, ["a"]).tolist()
        [[2.0]]
    """
    done = batch.get(("next", "done")).squeeze(-1)
    columns = []
    for key in episode_return_keys(components, episode_key):
        value = batch.get(("next", *key), None)
        if value is None:
            raise KeyError(
                f"no episode returns at {('next', *key)}; track them with "
                f"ComponentRewardSum({list(components)}, episode_key={episode_key!r}) or set the key to where "
                "your RewardSum writes them"
            )
        columns.append(value[done].reshape(-1))
    return torch.stack(columns, dim=-1)
