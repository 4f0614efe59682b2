"""Which auxiliary reward a run uses: the config's choice of file, its sandbox check on real transitions of
the task, and the transform factory that ``make_env`` appends (paper, section IV-D).

The transform itself (:class:`~torchrl_ahrs.rewards.auxiliary.AuxiliaryReward`) knows nothing of configs;
this module turns ``method.auxiliary`` / ``aux.path`` / ``aux.scale`` into it.
"""

from __future__ import annotations

import functools
import logging
import re
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import torch
from omegaconf import OmegaConf
from torchrl.envs.transforms import Transform

from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.settings import load_task_config, task_settings
from torchrl_ahrs.app.shared.settings import select as _select
from torchrl_ahrs.envs.registry import available_tasks, make_env
from torchrl_ahrs.rewards.auxiliary import (
    AUX,
    AUX_FUNCTION,
    TOTAL_AUX,
    AuxiliaryReward,
    aux_inputs,
    file_digest,
    flatten_inputs,
    shipped_aux_path,
)
from torchrl_ahrs.sandbox import Verdict, check_source, validate_in_child

log = logging.getLogger("torchrl_ahrs.aux")
TransformFactory = Callable[[], Transform]


AUX_MODES = (None, "branch", "total")


def auxiliary_components(
    method_components: Sequence[str] | None, task_components: Sequence[str], auxiliary: str | None
) -> list[str]:
    """The K axis of a method: its own list, else the task's (+ ``aux`` for ``branch``, ``[total_aux]`` for ``total``).

    Example:
        >>> auxiliary_components(None, ["a", "b"], "branch"), auxiliary_components(None, ["a", "b"], "total")
        (['a', 'b', 'aux'], ['total_aux'])
    """
    if auxiliary not in AUX_MODES:
        raise ValueError(f"method.auxiliary must be null, 'branch' or 'total', got {auxiliary!r}")
    if method_components is not None:
        return list(method_components)
    if auxiliary == "branch":
        return [*task_components, AUX]
    if auxiliary == "total":
        return [TOTAL_AUX]
    return list(task_components)


def aux_leaves(auxiliary: str | None) -> set[str]:
    """Reward leaves a method may name in addition to the task's components."""
    return {AUX, TOTAL_AUX} if auxiliary else set()


def resolve_aux_path(cfg: Any) -> Path:
    """``aux.path`` if given, else the task's shipped auxiliary reward."""
    path = _select(cfg, "aux.path")
    return Path(path) if path else shipped_aux_path(cfg.task.name)


def collect_aux_inputs(
    task_cfg: Mapping[str, Any], num_envs: int = 8, steps: int = 16, seed: int = 0
) -> dict[str, torch.Tensor]:
    """``obs`` dicts of ``num_envs · steps`` real transitions of the task (its config section) under uniformly
    random actions."""
    env = make_env(task_settings(task_cfg), num_envs, seed)
    try:
        with torch.no_grad():
            rollout = env.rollout(steps, break_when_any_done=False)  # [N, T]
    finally:
        env.close()
    inputs = aux_inputs(rollout.get("action"), rollout.get("next"))
    return flatten_inputs(inputs, rollout.batch_dims)


def validate_aux_file(
    path: str | Path,
    task_cfg: Mapping[str, Any],
    num_envs: int = 8,
    steps: int = 16,
    seed: int = 0,
    batch_size: int | None = None,
) -> Any:
    """All sandbox gates for an auxiliary reward file, the child run on real transitions of the task (and at
    ``batch_size``, the number of environments training steps at once: a fault that shows only there is
    refused here, not at the first training step).

    Returns the sandbox's ``Verdict`` (``ok``, ``reasons``).
    """
    path = Path(path)
    try:
        source = path.read_text()
    except (OSError, UnicodeDecodeError) as error:
        return Verdict(False, [f"cannot read {path}: {error}"])
    verdict = check_source(source, str(path))
    if not verdict.ok:
        return verdict
    if AUX_FUNCTION not in verdict.functions:
        return Verdict(False, [f"no function named {AUX_FUNCTION}(obs); found {verdict.functions}"])
    inputs = collect_aux_inputs(task_cfg, num_envs, steps, seed)
    with tempfile.TemporaryDirectory() as scratch:
        inputs_path = Path(scratch) / "inputs.pt"
        torch.save(inputs, inputs_path)
        return validate_in_child(path, "aux", inputs_path=inputs_path, batch_size=batch_size)


def infer_aux_task(path: str | Path) -> str | None:
    """The task an auxiliary reward file was written for: ``generate_aux``'s header ("... for task <name>.")
    or a shipped file's name; None when neither says."""
    path = Path(path)
    try:
        match = re.search(r"for task ([A-Za-z0-9_]+)\.", path.read_text()[:2000])
    except (OSError, UnicodeDecodeError):
        return None
    if match and match.group(1) in available_tasks():
        return match.group(1)
    return path.stem if path.stem in available_tasks() else None


def sandbox_aux_inputs(path: str, task: str | None = None) -> dict[str, torch.Tensor] | None:
    """Real transitions for ``python -m torchrl_ahrs.sandbox check FILE --kind aux`` (registered as the
    entry point ``torchrl_ahrs.sandbox.aux_inputs``, so the sandbox needs no import of the tasks): of
    ``task``, else of the task :func:`infer_aux_task` finds; None when neither names one (the sandbox
    then uses synthetic inputs)."""
    name = task or infer_aux_task(path)
    if not name:
        return None
    return collect_aux_inputs(cast(dict[str, Any], OmegaConf.to_container(load_task_config(name), resolve=True)))


def training_batch_size(cfg: Any) -> int | None:
    """How many environments one call of the auxiliary reward sees in training (per collector worker).

    Example:
        >>> training_batch_size({"trainer": {"num_envs": 64, "collector": "multi", "workers": 2}})
        32
    """
    num_envs = _select(cfg, "trainer.num_envs")
    if num_envs is None:
        return None
    workers = int(_select(cfg, "trainer.workers", 1)) if _select(cfg, "trainer.collector") == "multi" else 1
    return max(1, int(num_envs) // max(1, workers))


def auxiliary_transform(cfg: Any, check: bool = True) -> TransformFactory | None:
    """A picklable factory of the run's :class:`AuxiliaryReward`, or None when the method uses none.

    ``make_env(..., transforms=[factory])`` appends it (in this process or in collector workers). With
    ``check`` the file first goes through every sandbox gate on real transitions of the task, and the
    run logs which file and digest it uses.

    Raises:
        ConfigError: the file is missing or refused (every reason in the message).
    """
    mode = _select(cfg, "method.auxiliary")
    if not mode:
        return None
    try:
        path = resolve_aux_path(cfg)
    except FileNotFoundError as error:
        raise ConfigError(str(error)) from error
    if not path.is_file():
        raise ConfigError(f"aux.path: no file {path}")
    digest = file_digest(path)
    scale = float(_select(cfg, "aux.scale", 1.0))
    if check:
        task = cast(dict[str, Any], OmegaConf.to_container(cfg.task, resolve=True))
        verdict = validate_aux_file(path, task, seed=int(_select(cfg, "seed", 0)), batch_size=training_batch_size(cfg))
        if not verdict.ok:
            raise ConfigError(
                f"auxiliary reward {path} refused by the sandbox; training not started:\n  - "
                + "\n  - ".join(verdict.reasons)
            )
        log.info("auxiliary reward: %s (sha256 %s), mode %s, scale %s", path, digest, mode, scale)
    return functools.partial(AuxiliaryReward.from_file, str(path), scale, digest)
