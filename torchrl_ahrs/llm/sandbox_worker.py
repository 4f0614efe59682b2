"""Child-process half of the sandbox: loads a file under resource limits and calls its functions.

Run by :func:`torchrl_ahrs.llm.sandbox.validate_in_child` as
``python -m torchrl_ahrs.llm.sandbox_worker FILE KIND CPU_SECONDS MEMORY_BYTES [INPUTS.pt]``; prints one JSON line
``{"ok": bool, "reasons": [...], "functions": [...]}`` as its last line of output.

Limits are installed after ``torch`` is imported (its import alone needs more address space than the
budget), so they bound exactly the untrusted part: the CPU time of the calls (``RLIMIT_CPU``, soft
limit raises ``SIGXCPU``, hard limit kills) and the address space they may add (``RLIMIT_AS``).
"""

from __future__ import annotations

import inspect
import json
import os
import resource
import signal
import sys

import torch

from torchrl_ahrs.llm.sandbox import load_functions

RULE_ARITY = 4  # rule(mean_returns [K], var_returns [K], history [L, K], previous_weights [K]) -> [K]
AUX_FUNCTION = "compute_aux_reward"  # compute_aux_reward(obs: dict[str, Tensor [N, ...]]) -> [N]


class CpuLimitExceeded(Exception):
    """Raised from the SIGXCPU handler so the failing function is named in the report."""


def _on_cpu_limit(signum, frame):
    raise CpuLimitExceeded("CPU-time limit exceeded")


def _install_limits(cpu_seconds: int, memory_bytes: int) -> None:
    used = resource.getrusage(resource.RUSAGE_SELF)
    cpu_now = int(used.ru_utime + used.ru_stime) + 1
    resource.setrlimit(resource.RLIMIT_CPU, (cpu_now + cpu_seconds, cpu_now + cpu_seconds + 2))
    with open("/proc/self/statm") as statm:  # first field: total program size in pages
        virtual_now = int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    resource.setrlimit(resource.RLIMIT_AS, (virtual_now + memory_bytes, virtual_now + memory_bytes))
    signal.signal(signal.SIGXCPU, _on_cpu_limit)


def rule_cases(seed: int = 0) -> list[tuple[str, tuple[torch.Tensor, ...]]]:
    """Random and edge-case rule inputs: (label, (mean [K], var [K], history [L, K], weights [K]))."""
    generator = torch.Generator().manual_seed(seed)
    cases = []
    for num_components in (1, 4, 12):
        for label, scale in (("random", 1.0), ("large", 1e4)):
            mean = torch.randn(num_components, generator=generator) * scale
            var = torch.rand(num_components, generator=generator) * scale**2
            history = mean + torch.randn(5, num_components, generator=generator) * scale
            weights = 0.5 + torch.rand(num_components, generator=generator)
            cases.append((f"{label} K={num_components}", (mean, var, history, weights)))
        zeros = torch.zeros(num_components)
        cases.append((f"all zero K={num_components}", (zeros, zeros, torch.zeros(5, num_components), zeros + 0.5)))
        negative = -torch.arange(1.0, num_components + 1) * 100
        cases.append(
            (f"negative, no history K={num_components}", (negative, zeros, negative.expand(5, -1).clone(), zeros + 0.5))
        )
    return cases


def aux_cases(seed: int = 0, inputs: dict[str, torch.Tensor] | None = None) -> list[tuple[str, tuple]]:
    """Auxiliary-reward inputs: (label, (obs,)) with ``obs: dict[str, Tensor [N, ...]]``.

    ``inputs`` are real transitions of the task (see ``torchrl_ahrs.rewards.auxiliary.aux_inputs``); the
    cases are that batch, its first row alone (N = 1) and an all-zero batch of the same layout. Without
    ``inputs`` the cases are random ``{"observation": [N, D], "action": [N, A]}`` dicts.
    """
    if inputs is not None:
        first_row = {name: value[:1] for name, value in inputs.items()}
        zeros = {name: torch.zeros_like(value) for name, value in inputs.items()}
        return [("task batch", (inputs,)), ("task batch, N=1", (first_row,)), ("all-zero batch", (zeros,))]
    generator = torch.Generator().manual_seed(seed)
    cases = []
    for num_envs, obs_dim, act_dim in ((1, 3, 1), (8, 27, 8), (64, 13, 4)):
        observation = torch.randn(num_envs, obs_dim, generator=generator)
        action = torch.randn(num_envs, act_dim, generator=generator)
        cases.append((f"random N={num_envs}", ({"observation": observation, "action": action},)))
        cases.append(
            (
                f"zeros N={num_envs}",
                ({"observation": torch.zeros_like(observation), "action": torch.zeros_like(action)},),
            )
        )
    return cases


def _batch_size(inputs: tuple) -> int:
    first = inputs[0]
    return next(iter(first.values())).shape[0] if isinstance(first, dict) else first.shape[0]


def _fresh(value):
    """A copy the called code may mutate without touching the next case."""
    return {name: tensor.clone() for name, tensor in value.items()} if isinstance(value, dict) else value.clone()


def _check_output(output, expected_shape: tuple[int, ...]) -> str | None:
    try:
        tensor = torch.as_tensor(output, dtype=torch.float32)
    except Exception as error:  # noqa: BLE001 (any conversion failure is a verdict)
        return f"output is not a tensor of numbers ({type(error).__name__}: {error})"
    if tuple(tensor.shape) != expected_shape and not (
        len(expected_shape) == 1 and tuple(tensor.shape) == (*expected_shape, 1)
    ):
        return f"output shape {tuple(tensor.shape)}, expected {expected_shape}"
    if not torch.isfinite(tensor).all():
        return "output is not finite (NaN or inf)"
    return None


def validate(source: str, kind: str, inputs: dict[str, torch.Tensor] | None = None) -> dict:
    """Loads ``source`` and calls its functions on every case; returns the JSON-able report."""
    try:
        functions = load_functions(source)
    except Exception as error:  # noqa: BLE001
        return {"ok": False, "reasons": [f"could not load: {type(error).__name__}: {error}"], "functions": []}
    reasons: list[str] = []
    if kind == "rule":
        targets = {name: fn for name, fn in functions.items() if len(inspect.signature(fn).parameters) == RULE_ARITY}
        if not targets:
            reasons.append(
                f"no rule function with {RULE_ARITY} arguments (mean_returns, var_returns, history, previous_weights)"
            )
        cases = rule_cases()
    elif kind == "aux":
        targets = {name: fn for name, fn in functions.items() if name == AUX_FUNCTION}
        if not targets:
            reasons.append(f"no function named {AUX_FUNCTION}(obs)")
        cases = aux_cases(inputs=inputs)
    else:
        return {"ok": False, "reasons": [f"unknown kind {kind!r}"], "functions": []}
    for name, fn in targets.items():
        for label, inputs in cases:
            expected = (_batch_size(inputs),)
            try:
                problem = _check_output(fn(*[_fresh(value) for value in inputs]), expected)
            except CpuLimitExceeded:
                reasons.append(f"{name}: CPU-time limit exceeded on input '{label}'")
                return {"ok": False, "reasons": reasons, "functions": list(targets)}
            except MemoryError:
                problem = "memory limit exceeded"
            except Exception as error:  # noqa: BLE001
                problem = f"raised {type(error).__name__}: {str(error)[:200]}"
            if problem is not None:
                reasons.append(f"{name}: {problem} on input '{label}'")
                break  # one reason per function is enough to refuse it
    return {"ok": not reasons, "reasons": reasons, "functions": list(targets)}


def main(argv: list[str]) -> int:
    path, kind, cpu_seconds, memory_bytes = argv[0], argv[1], int(argv[2]), int(argv[3])
    with open(path) as handle:
        source = handle.read()
    # aux: real transitions of the task (a dict of tensors saved by the parent), loaded before the limits
    inputs = torch.load(argv[4], weights_only=True) if len(argv) > 4 else None
    torch.set_num_threads(1)
    _install_limits(cpu_seconds, memory_bytes)
    report = validate(source, kind, inputs)
    print(json.dumps(report), flush=True)
    return 0 if report["ok"] else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
