"""The auxiliary reward: one extra reward leaf computed by sandbox-accepted code (paper, section IV-D).

An auxiliary reward file (written by an LLM with ``python -m torchrl_ahrs.generate_aux``, or one of the
shipped files in ``torchrl_ahrs/rewards/aux_rewards/``) defines one function::

    def compute_aux_reward(obs):   # obs: dict[str, Tensor [N, ...]]  ->  Tensor [N]

``obs`` holds everything the environment wrote for the step, flattened to string keys (see
:func:`aux_inputs`): ``"observation"`` [N, D] and any other observation entry by name (e.g.
``"height"``, ``"desired_goal"``), ``"action"`` [N, A] (the action that led to this state),
``"reward.<c>"`` [N] for every reward leaf including ``"reward.total"``, and ``"info.<key>"`` [N] for the
environment's info entries (e.g. ``"info.reward_forward"``). Booleans and integers arrive as float32;
trailing singleton dimensions are squeezed, so scalar-per-env entries are [N].

:class:`AuxiliaryReward` evaluates it on the whole batch at once and writes::

    ("next", "reward", "aux")        = scale * compute_aux_reward(obs)        [N, 1]
    ("next", "reward", "total_aux")  = ("next", "reward", "total") + aux      [N, 1]

With ``aux`` in the component list the task has K + 1 components (AHRS, HD-PPO-A); PPO-A trains one
head on ``total_aux``. ``total`` stays the native reward, so every method reports comparable returns.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite

from torchrl_ahrs.rewards.components import TOTAL, ComponentLeaves

AUX = "aux"
TOTAL_AUX = "total_aux"
AUX_FUNCTION = "compute_aux_reward"
SHIPPED_DIR = Path(__file__).with_name("aux_rewards")
_SKIPPED_ROOTS = ("episode_reward",)  # RewardSum accumulators: not part of one step

log = logging.getLogger("torchrl_ahrs.aux")

AuxFn = Callable[[dict[str, torch.Tensor]], torch.Tensor]
MAX_ERROR_CHARS = 500  # an error's text in logs and on the console


class AuxiliaryRewardError(RuntimeError):
    """The auxiliary reward failed on a step (one line naming the file); training stops with a checkpoint written.

    Example:
        >>> str(AuxiliaryRewardError("auxiliary reward a.py: compute_aux_reward: raised KeyError: 'x'"))[:25]
        'auxiliary reward a.py: co'
    """


def aux_inputs(
    action: torch.Tensor | None, next_tensordict: TensorDictBase, reward_key: str = "reward"
) -> dict[str, torch.Tensor]:
    """The ``obs`` argument of ``compute_aux_reward``: every leaf of one step as ``{name: [*B, ...]}``.

    Nested keys are joined with ``"."`` (``("info", "reward_ctrl")`` → ``"info.reward_ctrl"``); leaves are
    float32 with a trailing singleton dimension squeezed; ``episode_reward`` accumulators are left out.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> step = TensorDict({"observation": torch.zeros(2, 3), "reward": {"total": torch.ones(2, 1)},
        ...                    "done": torch.zeros(2, 1, dtype=torch.bool)}, [2])
        >>> {k: tuple(v.shape) for k, v in aux_inputs(torch.zeros(2, 1), step).items()}
        {'observation': (2, 3), 'reward.total': (2,), 'done': (2,), 'action': (2, 1)}
    """
    batch_ndim = next_tensordict.batch_dims
    inputs: dict[str, torch.Tensor] = {}
    for key, value in next_tensordict.items(include_nested=True, leaves_only=True):
        key = (key,) if isinstance(key, str) else tuple(key)
        if key[0] in _SKIPPED_ROOTS or not isinstance(value, torch.Tensor):
            continue
        if value.ndim == batch_ndim + 1 and value.shape[-1] == 1:
            value = value.squeeze(-1)  # [*B, 1] → [*B]
        inputs[".".join(key)] = value.to(torch.float32)
    if action is not None:
        inputs["action"] = action.to(torch.float32)
    return inputs


def flatten_inputs(inputs: Mapping[str, torch.Tensor], batch_ndim: int) -> dict[str, torch.Tensor]:
    """``{name: [*B, ...]}`` → ``{name: [prod(B), ...]}`` (a rollout [N, T] becomes one batch of N·T rows)."""
    return {name: value.reshape(-1, *value.shape[batch_ndim:]) for name, value in inputs.items()}


def check_aux_output(output: Any, batch_size: int) -> torch.Tensor:
    """The function's output as float32 ``[N]`` by the sandbox's output contract (the check applies the same:
    a tensor, array or list of ``N`` or ``[N, 1]`` finite numbers); raises ``ValueError`` otherwise.

    Example:
        >>> import numpy as np
        >>> check_aux_output(np.zeros((3, 1)), 3).tolist()
        [0.0, 0.0, 0.0]
    """
    from torchrl_ahrs.sandbox.cases import output_contract  # the sandbox imports numpy, RestrictedPython: lazy

    if isinstance(output, torch.Tensor) and output.device.type != "cpu":
        # the finiteness test reads a flag back from the device: per step on the CPU only; on an accelerator the
        # run's FiniteGuard stops training at the first batch holding a non-finite aux reward instead
        if output.shape == (batch_size, 1):
            output = output.squeeze(-1)
        if tuple(output.shape) != (batch_size,):
            raise ValueError(f"{AUX_FUNCTION}: output shape {tuple(output.shape)}, expected ({batch_size},)")
        return output.to(torch.float32)
    tensor, problem = output_contract(output, (batch_size,))
    if tensor is None:
        raise ValueError(f"{AUX_FUNCTION}: {problem}")
    return tensor


def file_digest(path: str | Path) -> str:
    """sha256 of the file's bytes (printed at start and checked when worker processes load it)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def shipped_aux_path(task_name: str) -> Path:
    """The project's auxiliary reward for ``task_name`` (``aux_rewards/<task>.py``)."""
    path = SHIPPED_DIR / f"{task_name}.py"
    if not path.is_file():
        shipped = sorted(p.stem for p in SHIPPED_DIR.glob("*.py") if p.stem != "__init__")
        raise FileNotFoundError(f"no shipped auxiliary reward for task {task_name!r} (shipped: {', '.join(shipped)})")
    return path


def load_aux_function(path: str | Path, expected_digest: str | None = None, isolated: bool | None = None) -> AuxFn:
    """Loads ``compute_aux_reward`` from ``path`` through the sandbox's static gate and restricted execution.

    ``isolated``: call it in a :class:`~torchrl_ahrs.sandbox.session.SandboxSession` (a key-free worker with
    the check's limits, inputs and outputs in shared memory) instead of in this process; None: every file but
    the shipped ones (``aux_rewards/``, hand-written, part of the package's reviewed code).

    Raises:
        ValueError: the sandbox refuses the code, the function is missing, or the file changed since it
            was validated (``expected_digest``).
    """
    from torchrl_ahrs.sandbox import load_functions  # the sandbox imports torch, numpy: keep it lazy

    path = Path(path)
    source = path.read_bytes()
    if expected_digest is not None and hashlib.sha256(source).hexdigest() != expected_digest:
        raise ValueError(f"{path} changed after it was validated (digest mismatch)")
    functions: Mapping[str, Callable] = load_functions(source.decode(), str(path))  # the static gate, here
    if isolated is None:
        isolated = path.resolve().parent != SHIPPED_DIR.resolve()
    if isolated:
        from torchrl_ahrs.sandbox.session import SandboxSession, isolated_functions

        functions = isolated_functions(SandboxSession(source.decode(), str(path)), "aux")
    if AUX_FUNCTION not in functions:
        raise ValueError(f"{path} defines no function {AUX_FUNCTION}(obs); it defines {sorted(functions)}")
    return functions[AUX_FUNCTION]


class AuxiliaryReward(ComponentLeaves):
    """Writes ``("reward", "aux")`` = ``scale * fn(obs)`` and ``("reward", "total_aux")`` = total + aux.

    Append it after :class:`~torchrl_ahrs.rewards.RewardComponents` (the reward must already be a tree)
    and before ``RewardSum``. ``fn`` gets the step as ``{name: [N, ...]}`` (:func:`aux_inputs`) and must
    return ``[N]`` (or ``[N, 1]``) finite values; anything else, or any error it raises, stops training with an
    :class:`AuxiliaryRewardError` (on an accelerator, a non-finite value is caught once per batch, by the
    trainer's ``FiniteGuard``).

    Args:
        fn: ``compute_aux_reward(obs: dict[str, Tensor [N, ...]]) -> Tensor [N]``.
        scale: factor applied to ``fn``'s output.
        source: where ``fn`` came from (file and digest), for logs.
        reward_key: the reward tree's root (default ``"reward"``).

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> aux = AuxiliaryReward(lambda obs: -obs["observation"].norm(dim=-1), scale=0.5)
        >>> step = TensorDict({"observation": torch.tensor([[3.0, 4.0], [0.0, 1.0]]),
        ...                    "reward": {"total": torch.ones(2, 1)}}, [2])
        >>> out = aux._step(TensorDict({"action": torch.zeros(2, 1)}, [2]), step)
        >>> out["reward", "aux"].squeeze(-1).tolist(), out["reward", "total_aux"].squeeze(-1).tolist()
        ([-2.5, -0.5], [-1.5, 0.5])
    """

    def __init__(self, fn: AuxFn, scale: float = 1.0, source: str = "<function>", reward_key: str = "reward"):
        self.leaf_names = [AUX, TOTAL_AUX]  # component leaves (observation spec), like RewardComponents'
        super().__init__(in_keys=[reward_key], out_keys=[(reward_key, AUX), (reward_key, TOTAL_AUX)])
        self.fn = fn
        self.scale = float(scale)
        self.source = source
        self.reward_key = reward_key

    @classmethod
    def from_file(
        cls, path: str | Path, scale: float = 1.0, expected_digest: str | None = None, isolated: bool | None = None
    ) -> AuxiliaryReward:
        """Loads ``compute_aux_reward`` from a sandbox-checked file (see :func:`load_aux_function`)."""
        fn = load_aux_function(path, expected_digest, isolated)
        return cls(fn, scale, source=f"{path} (sha256 {file_digest(path)[:12]})")

    def compute(self, action: torch.Tensor | None, next_tensordict: TensorDictBase) -> torch.Tensor:
        """``scale * fn(obs)`` for one step: ``[*B, 1]``."""
        batch_shape = next_tensordict.batch_size
        inputs = flatten_inputs(aux_inputs(action, next_tensordict, self.reward_key), len(batch_shape))
        with torch.no_grad():
            try:
                raw = check_aux_output(self.fn(inputs), batch_shape.numel())
            except Exception as error:  # noqa: BLE001 (whatever the file did, the run stops with one line naming it)
                text = " ".join(f"{type(error).__name__}: {error}".split())
                text = text if len(text) <= MAX_ERROR_CHARS else text[:MAX_ERROR_CHARS] + f"... ({len(text)} chars)"
                raise AuxiliaryRewardError(f"auxiliary reward {self.source}: {text}") from error
        return (self.scale * raw).reshape(*batch_shape, 1)  # r_aux = scale · f(obs)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        tree = next_tensordict.get(self.reward_key)
        if not isinstance(tree, TensorDictBase):
            raise KeyError(
                f"AuxiliaryReward needs the reward tree ({self.reward_key!r}, ...); append RewardComponents first"
            )
        action = tensordict.get("action", None)
        aux = self.compute(action, next_tensordict)
        tree.set(AUX, aux)
        tree.set(TOTAL_AUX, tree.get(TOTAL) + aux)  # r_total_aux = r_total + r_aux
        return next_tensordict

    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        # the leaves themselves are declared in the observation spec (ComponentLeaves); the total stays
        if not isinstance(reward_spec.get(self.reward_key, None), Composite):
            raise KeyError(
                f"AuxiliaryReward needs the reward tree ({self.reward_key!r}, ...); append RewardComponents first"
            )
        return reward_spec
