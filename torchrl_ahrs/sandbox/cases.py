"""Validation cases: calls a file's functions on the inputs they will see and checks the outputs.

:func:`validate` runs in the isolated child (see :mod:`torchrl_ahrs.sandbox.isolation`) but is plain
Python, so tests can call it in-process. The inputs come from the caller: the task's own number of
reward components ``K`` for rules (a rule may divide by ``K - 1``; it only has to work for the K it
will be used with), real transitions of the task for auxiliary rewards.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy
import numpy.ma
import torch

from torchrl_ahrs.sandbox.guards import SandboxRefusal
from torchrl_ahrs.sandbox.runtime import load_functions

RULE_ARITY = 4  # rule(mean_returns [K], var_returns [K], history [L, K], previous_weights [K]) -> [K]
AUX_FUNCTION = "compute_aux_reward"  # compute_aux_reward(obs: dict[str, Tensor [N, ...]]) -> [N]
KINDS = ("rule", "aux")
DEFAULT_NUM_COMPONENTS = (1, 4, 12)  # when the caller does not say which K the rules are for
HISTORY_LENGTH = 5


class CpuLimitExceeded(Exception):
    """Raised from the child's SIGXCPU handler so the failing function is named in the report.

    Example:
        >>> isinstance(CpuLimitExceeded("CPU-time limit exceeded"), Exception)
        True
    """


def rule_cases(num_components: int | Sequence[int] | None = None, seed: int = 0) -> list[tuple[str, tuple]]:
    """Random and edge-case rule inputs ``(label, (mean [K], var [K], history [L, K], weights [K]))``.

    ``num_components``: the task's K (or several); None tests K = 1, 4 and 12.

    Example:
        >>> [label for label, _ in rule_cases(3)]
        ['random K=3', 'large K=3', 'all zero K=3', 'negative, no history K=3']
    """
    if num_components is None:
        sizes: Sequence[int] = DEFAULT_NUM_COMPONENTS
    elif isinstance(num_components, int):
        sizes = (num_components,)
    else:
        sizes = tuple(num_components)
    generator = torch.Generator().manual_seed(seed)
    cases = []
    for k in sizes:
        for label, scale in (("random", 1.0), ("large", 1e4)):
            mean = torch.randn(k, generator=generator) * scale
            var = torch.rand(k, generator=generator) * scale**2
            history = mean + torch.randn(HISTORY_LENGTH, k, generator=generator) * scale
            weights = 0.5 + torch.rand(k, generator=generator)
            cases.append((f"{label} K={k}", (mean, var, history, weights)))
        zeros = torch.zeros(k)
        cases.append((f"all zero K={k}", (zeros, zeros, torch.zeros(HISTORY_LENGTH, k), zeros + 0.5)))
        negative = -torch.arange(1.0, k + 1) * 100
        cases.append(
            (f"negative, no history K={k}", (negative, zeros, negative.expand(HISTORY_LENGTH, -1), zeros + 0.5))
        )
    return cases


def aux_cases(
    inputs: Mapping[str, torch.Tensor] | None = None, seed: int = 0, batch_size: int | None = None
) -> list[tuple[str, tuple]]:
    """Auxiliary-reward inputs ``(label, (obs,))`` with ``obs: dict[str, Tensor [N, ...]]``.

    ``inputs``: real transitions of the task (the caller collects them); the cases are that batch, its
    first row alone (N = 1), the batch at the training batch size ``batch_size`` (the number of environments
    stepped at once; rows repeated when the batch has fewer) and an all-zero batch of the same layout.
    Without ``inputs``, random ``{"observation": [N, D], "action": [N, A]}`` dicts (and, with ``batch_size``,
    one at that N).

    Example:
        >>> [label for label, _ in aux_cases({"observation": torch.zeros(4, 3)})]
        ['task batch', 'task batch, N=1', 'all-zero batch']
    """
    if inputs is not None:
        batch = dict(inputs)
        first_row = {name: value[:1] for name, value in batch.items()}
        zeros = {name: torch.zeros_like(value) for name, value in batch.items()}
        cases = [("task batch", (batch,)), ("task batch, N=1", (first_row,))]
        if batch_size is not None:
            rows = torch.arange(batch_size) % next(iter(batch.values())).shape[0]
            cases.append((f"training batch, N={batch_size}", ({name: value[rows] for name, value in batch.items()},)))
        return [*cases, ("all-zero batch", (zeros,))]
    generator = torch.Generator().manual_seed(seed)
    cases = []
    sizes = ((1, 3, 1), (8, 27, 8), (64, 13, 4)) + (((batch_size, 13, 4),) if batch_size is not None else ())
    for num_envs, obs_dim, act_dim in sizes:
        observation = torch.randn(num_envs, obs_dim, generator=generator)
        action = torch.randn(num_envs, act_dim, generator=generator)
        cases.append((f"random N={num_envs}", ({"observation": observation, "action": action},)))
        zeros = {"observation": torch.zeros_like(observation), "action": torch.zeros_like(action)}
        cases.append((f"zeros N={num_envs}", (zeros,)))
    return cases


def _batch_size(inputs: tuple) -> int:
    first = inputs[0]
    return next(iter(first.values())).shape[0] if isinstance(first, dict) else first.shape[0]


def _fresh(value: Any) -> Any:
    """A copy the called code may mutate without touching the next case."""
    return {name: tensor.clone() for name, tensor in value.items()} if isinstance(value, dict) else value.clone()


def output_contract(output: Any, expected_shape: tuple[int, ...]) -> tuple[torch.Tensor | None, str | None]:
    """The one output contract, applied alike by the check and in training: ``(float32 tensor, None)`` or
    ``(None, why)``.

    The output may be a tensor, a numpy array or a list of numbers (converted with ``torch.as_tensor``); its
    shape must be ``expected_shape`` (``[N, 1]`` for an expected ``[N]`` is squeezed); every value finite.

    Example:
        >>> import numpy as np
        >>> output_contract(np.ones(3), (3,))[0].dtype, output_contract(torch.ones(3, 1), (3,))[0].shape
        (torch.float32, torch.Size([3]))
        >>> output_contract(torch.ones(2), (3,))
        (None, 'output shape (2,), expected (3,)')
    """
    try:
        tensor = torch.as_tensor(output, dtype=torch.float32)
    except Exception as error:  # noqa: BLE001 (any conversion failure is a verdict)
        message = " ".join(str(error).split())[:200]
        return None, f"output is not a tensor of numbers ({type(output).__name__}: {type(error).__name__}: {message})"
    if len(expected_shape) == 1 and tuple(tensor.shape) == (*expected_shape, 1):
        tensor = tensor.squeeze(-1)
    if tuple(tensor.shape) != tuple(expected_shape):
        return None, f"output shape {tuple(tensor.shape)}, expected {tuple(expected_shape)}"
    if not torch.isfinite(tensor).all():
        bad = int((~torch.isfinite(tensor)).sum())
        return None, f"output is not finite ({bad} NaN or inf value(s))"
    return tensor.contiguous(), None


def check_output(output: Any, expected_shape: tuple[int, ...]) -> str | None:
    """Why ``output`` breaks :func:`output_contract`, or None.

    Example:
        >>> check_output(torch.ones(3), (3,)) is None, check_output(torch.ones(2), (3,))
        (True, 'output shape (2,), expected (3,)')
    """
    return output_contract(output, expected_shape)[1]


def warm_up_lazy_imports() -> None:
    """Calls what numpy and torch import on first use, so it is imported before the audit hook is installed.

    ``np.median``, ``np.percentile``, ``np.quantile`` and ``np.unique`` import ``numpy.ma`` lazily, which
    lists a directory (``os.listdir``, refused by the hook): ordinary statistics would be refused.

    Example:
        >>> warm_up_lazy_imports()
    """
    values = numpy.arange(5.0)
    numpy.median(values), numpy.percentile(values, 50), numpy.quantile(values, 0.5), numpy.unique(values)
    (
        numpy.nanmedian(values),
        numpy.nanpercentile(values, 50),
        numpy.nanquantile(values, 0.5),
        numpy.ma.masked_invalid(values),
    )
    tensor = torch.arange(5.0)
    torch.median(tensor), torch.quantile(tensor, 0.5), torch.unique(tensor), torch.tensor([1.0]).numpy()


def _is_memory_error(error: BaseException) -> bool:
    text = str(error).lower()
    return isinstance(error, MemoryError) or "can't allocate memory" in text or "not enough memory" in text


def validate(
    source: str,
    kind: str,
    inputs: Mapping[str, torch.Tensor] | None = None,
    num_components: int | Sequence[int] | None = None,
    loader: Callable[[str], Mapping[str, Callable]] | None = None,
    batch_size: int | None = None,
) -> dict:
    """Loads ``source`` and calls its functions on every case; returns the JSON-able report.

    ``{"ok": bool, "reasons": [one line per failing function], "functions": [names checked]}``. Rules
    are the functions with four arguments, checked at ``num_components``; ``aux`` checks
    ``compute_aux_reward`` on ``inputs`` (and at the training ``batch_size``). One reason per function: its first failing case. ``loader``
    replaces :func:`~torchrl_ahrs.sandbox.runtime.load_functions` (tests of the isolation alone).

    Example:
        >>> validate("def rule(m, v, h, w):\\n    return m / (m.shape[0] - 1)\\n", "rule", num_components=11)["ok"]
        True
        >>> validate("def rule(m, v, h, w):\\n    return m / (m.shape[0] - 1)\\n", "rule")["reasons"]
        ["rule: output is not finite (1 NaN or inf value(s)) on input 'random K=1'"]
    """
    try:
        functions = (loader or load_functions)(source)
    except Exception as error:  # noqa: BLE001
        message = " ".join(f"could not load: {type(error).__name__}: {error}".split())
        return {"ok": False, "reasons": [message], "functions": []}
    reasons: list[str] = []
    if kind == "rule":
        targets = {name: fn for name, fn in functions.items() if len(inspect.signature(fn).parameters) == RULE_ARITY}
        if not targets:
            reasons.append(
                f"no rule function with {RULE_ARITY} arguments (mean_returns, var_returns, history, previous_weights)"
            )
        cases = rule_cases(num_components)
    elif kind == "aux":
        targets = {name: fn for name, fn in functions.items() if name == AUX_FUNCTION}
        if not targets:
            reasons.append(f"no function named {AUX_FUNCTION}(obs)")
        cases = aux_cases(inputs, batch_size=batch_size)
    else:
        return {"ok": False, "reasons": [f"unknown kind {kind!r} (expected one of {KINDS})"], "functions": []}
    for name, fn in targets.items():
        for label, arguments in cases:
            try:
                problem = check_output(fn(*[_fresh(value) for value in arguments]), (_batch_size(arguments),))
            except CpuLimitExceeded:
                reasons.append(f"{name}: CPU-time limit exceeded on input '{label}'")
                return {"ok": False, "reasons": reasons, "functions": list(targets)}
            except SandboxRefusal as error:
                problem = f"refused while running: {error}"
            except Exception as error:  # noqa: BLE001
                if _is_memory_error(error):
                    problem = "memory limit exceeded"
                else:
                    problem = f"raised {type(error).__name__}: {str(error)[:200]}"
            if problem is not None:
                problem = " ".join(problem.split())  # one line, whatever the exception's message looked like
                reasons.append(f"{name}: {problem} on input '{label}'")
                break  # one reason per function is enough to refuse it
    return {"ok": not reasons, "reasons": reasons, "functions": list(targets)}
