"""Start-up checks: a mistake that would otherwise train a whole run on a wrong setting fails first, in one line.

They run before any environment is built (:func:`check_command_line` on the raw overrides, before Hydra
composes; :func:`check_config` on the composed config), except :func:`check_reward_terms`, which needs a few
real steps of the task and runs right after its environment is built. Each raises :class:`PreflightError`
(a :class:`~torchrl_ahrs.app.shared.errors.ConfigError`), which the entry points print as ``error: <message>`` with
exit status 2. What each catches, and what happened without it:

* a key that is not in the shipped config, with or without ``+`` (Hydra's own hint for a misspelt key is
  ``+key=...``, which it then accepts and stores in ``config.yaml``, and the run ignores it);
* a value that is not a finite number (``seed=1e400``, ``trainer.lr=nan``) or an interpolation that cannot be
  resolved (``${oc.env:NOPE}``): tracebacks deep inside the run otherwise;
* ``model.hidden_sizes=[]``: a linear policy and critic, trained without a word;
* a logger backend whose package is missing: the run wrote no metrics for it and exited 0;
* a missing API key for the LLM provider: every decision failed, fell back, and the weights never moved;
* a reward component whose environment term never appears, or components that do not add up to the native
  reward: a component that is silently zero (or wrong) at every step.

:func:`inductor_failure` is a check of the machine, not of the config: ``trainer.compile=true`` on a machine where
inductor cannot build (no C++ compiler) would otherwise stop the run at its first minibatch; the caller warns
and trains eagerly instead.
"""

from __future__ import annotations

import difflib
import importlib.resources
import importlib.util
import math
import random
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from torchrl_ahrs.app.shared.config import dotted_keys
from torchrl_ahrs.app.shared.errors import ConfigError

__all__ = [
    "PreflightError",
    "check_command_line",
    "check_config",
    "check_llm_credentials",
    "check_reward_terms",
    "check_task_rewards",
    "inductor_failure",
    "shipped_keys",
]

# logger backend -> (the package it imports, the extra that installs it)
LOGGER_PACKAGES = {"tensorboard": ("tensorboard", None), "wandb": ("wandb", "wandb"), "mlflow": ("mlflow", "mlflow")}
# the selectors that call an LLM (scheduling/__init__.py's LLM_SELECTORS)
LLM_SELECTORS = ("llm", "direct")


class PreflightError(ConfigError):
    """A start-up check failed; the message is one line naming the key (and what to do)."""


# ---------------------------------------------------------------------------------------------- the keys
def shipped_keys(config_package: str = "torchrl_ahrs.conf") -> tuple[set[str], set[str]]:
    """``(keys, groups)``: every dotted key that ``conf/config.yaml`` or any option of any config group
    defines (``task.terms.survive``, ``llm.api_key``, ...), and the group names (``task``, ``preset``, ...).

    An option's keys count for every option of its group (``+task.num_threads=1`` is fine on any task:
    several tasks ship it), so only a key no shipped file has is refused.

    Example:
        >>> keys, groups = shipped_keys()
        >>> "trainer.total_frames" in keys, "trainer.total_frame" in keys, "task" in groups
        (True, False, True)
    """
    root = importlib.resources.files(config_package)
    keys = set(dotted_keys(_load_options(root.joinpath("config.yaml"))))
    groups = set()
    for group in root.iterdir():
        if not group.is_dir() or group.name.startswith(("_", ".")) or group.name == "hydra":
            continue
        groups.add(group.name)
        for option in group.iterdir():
            if option.name.endswith(".yaml"):
                text = option.read_text()
                prefix = "" if "@package _global_" in text.split("\n", 1)[0] else f"{group.name}."
                keys.update(dotted_keys(_load_options(option), prefix))
    return keys, groups


def _load_options(path: Any) -> dict[str, Any]:
    container = OmegaConf.to_container(OmegaConf.create(path.read_text()), resolve=False)
    assert isinstance(container, dict)
    container.pop("defaults", None)
    container.pop("hydra", None)  # Hydra's own tree: Hydra checks it
    return {str(key): value for key, value in container.items()}


def override_key(argument: str) -> tuple[str, str] | None:
    """``(prefix, dotted key)`` of one command-line override (``+``, ``++``, ``~`` or ``''``), or None for
    a flag, a Hydra key and a group choice spelt with ``/`` (``hydra/launcher=slurm``).

    Example:
        >>> override_key("+trainer.total_frame=1000"), override_key("~aux.path"), override_key("--multirun")
        (('+', 'trainer.total_frame'), ('~', 'aux.path'), None)
    """
    if argument.startswith("-") or ("=" not in argument and not argument.startswith("~")):
        return None
    key = argument.split("=", 1)[0]
    prefix = next((p for p in ("++", "+", "~") if key.startswith(p)), "")
    key = key[len(prefix) :].split("@", 1)[0]  # +preset@_global_=x: the group, not the package
    if not key or "/" in key or key == "hydra" or key.startswith("hydra."):
        return None
    return prefix, key


# sections whose keys are those of another section: trainer.task_overrides holds settings of the task
MIRRORED_SECTIONS = {"trainer.task_overrides.": "task."}


def check_command_line(arguments: Iterable[str], config_package: str = "torchrl_ahrs.conf") -> None:
    """Raises :class:`PreflightError` for the first override whose key no shipped config file has.

    Example:
        >>> check_command_line(["task=point_reach", "trainer.lr=1e-3", "+task.num_threads=1", "-m"])
        >>> check_command_line(["+trainer.task_overrides.commands.resampling_time_s=5.0"])
        >>> check_command_line(["+trainer.total_frame=1000"])
        Traceback (most recent call last):
        ...
        torchrl_ahrs.app.train.preflight.PreflightError: +trainer.total_frame is not a key of the shipped config (did you mean trainer.total_frames?); a run would ignore it
    """
    parsed = [item for item in map(override_key, arguments) if item is not None]
    if not parsed:
        return
    try:
        keys, groups = shipped_keys(config_package)
    except ModuleNotFoundError:  # conf/ not installed as a package (a bare checkout on sys.path): Hydra judges
        return
    for prefix, key in parsed:
        if key in keys or key in groups:
            continue
        mirrors = (
            mirrored + key[len(section) :] for section, mirrored in MIRRORED_SECTIONS.items() if key.startswith(section)
        )
        if any(mirror in keys for mirror in mirrors):  # trainer.task_overrides.x is known when task.x is
            continue
        close = difflib.get_close_matches(key, sorted(keys), n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise PreflightError(f"{prefix}{key} is not a key of the shipped config{hint}; a run would ignore it")


# ---------------------------------------------------------------------------------------------- the values
def check_config(cfg: DictConfig) -> None:
    """The composed config's start-up checks (before any environment is built): interpolations resolve,
    numbers are finite, the networks have a hidden layer, every logger backend's package is installed and
    the LLM provider's key is set when the method asks an LLM.

    Example:
        >>> from omegaconf import OmegaConf
        >>> check_config(OmegaConf.create({"seed": 0, "model": {"hidden_sizes": [64]}}))
        >>> check_config(OmegaConf.create({"seed": 0, "trainer": {"lr": float("nan")}}))
        Traceback (most recent call last):
        ...
        torchrl_ahrs.app.train.preflight.PreflightError: trainer.lr must be a finite number, got nan
    """
    try:
        resolved = OmegaConf.to_container(cfg, resolve=True)
    except OmegaConfBaseException as error:  # ${oc.env:NOPE}, ${no.such.key}
        key = getattr(error, "full_key", None) or "a value"
        reason = str(error).splitlines()[0].replace("KeyError raised while resolving interpolation: ", "")
        raise PreflightError(f"{key} cannot be resolved: {reason}") from None
    for key, value in _leaves(resolved):
        if isinstance(value, float) and not math.isfinite(value):
            raise PreflightError(f"{key} must be a finite number, got {value}")
    seed = cfg.get("seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
        raise PreflightError(f"seed must be an integer, got {seed!r}")
    model = cfg.get("model") or {}
    for name in ("hidden_sizes", "component_hidden_sizes"):
        if name not in model or (name == "component_hidden_sizes" and model[name] is None):  # null: hidden_sizes'
            continue
        sizes = model[name]
        if not sizes or not all(isinstance(size, int) and not isinstance(size, bool) and size > 0 for size in sizes):
            raise PreflightError(
                f"model.{name} must list at least one positive width (e.g. [64,64]), got {list(sizes or [])}"
            )
    logger = cfg.get("logger")
    if logger is not None:
        check_logger_packages(logger.get("backends") or ())
    method = cfg.get("method")
    llm = cfg.get("llm")
    if (
        llm is not None
        and llm.get("name") != "offline"
        and method is not None
        and method.get("selector") in LLM_SELECTORS
    ):
        check_llm_credentials(cfg.llm)


def _leaves(container: Any, prefix: str = "") -> Iterable[tuple[str, Any]]:
    if isinstance(container, dict):
        for key, value in container.items():
            yield from _leaves(value, f"{prefix}{key}.")
    elif isinstance(container, list):
        for index, value in enumerate(container):
            yield from _leaves(value, f"{prefix}{index}.")
    else:
        yield prefix.rstrip("."), container


def check_logger_packages(backends: Sequence[str]) -> None:
    """Raises :class:`PreflightError` naming the extra to install when a backend's package is missing.

    Example:
        >>> check_logger_packages(["csv"])
    """
    for name in backends:
        package, extra = LOGGER_PACKAGES.get(name, (None, None))
        if package is not None and importlib.util.find_spec(package) is None:
            install = f"pip install 'torchrl-ahrs[{extra}]'" if extra else f"pip install {package}"
            raise PreflightError(
                f"logger.backends has {name} but the {package} package is not installed: {install}, "
                f"or drop {name} from logger.backends"
            )


def check_llm_credentials(llm: Any) -> None:
    """Raises :class:`PreflightError` naming the environment variable when the provider of ``llm.model``
    needs a key that is not set (:func:`~torchrl_ahrs.llm.client.credential_problem`; no request is sent).

    Example:
        >>> check_llm_credentials({"name": "offline", "model": None})
    """
    from torchrl_ahrs.llm.client import LLMConfig, credential_problem  # deferred: it imports litellm

    container = OmegaConf.to_container(llm, resolve=True) if OmegaConf.is_config(llm) else dict(llm)
    problem = credential_problem(LLMConfig.from_cfg(container))
    if problem:
        raise PreflightError(problem)


# ---------------------------------------------------------------------------------------------- the machine
def inductor_failure() -> str | None:
    """``None`` when ``torch.compile`` (inductor) can build a forward and a backward on this machine, else the
    first line of why not (``"InvalidCxxCompiler: No working C++ compiler found ..."``).

    A two-element function is compiled and differentiated, so the check costs a few seconds, and only a run with
    ``trainer.compile=true`` makes it. It catches what fails before the first kernel runs
    (``BackendCompilerFailed``: no compiler, a broken toolchain); it draws no random numbers, so a run that then
    trains eagerly draws the numbers of a run with ``trainer.compile=false``. The backward is built at the first
    ``backward()``, so both are exercised.

    Example:
        >>> why = inductor_failure()  # None where a C++ compiler works; the reason's first line where none does
        >>> why is None or isinstance(why, str)
        True
    """
    from torch._dynamo.exc import BackendCompilerFailed  # deferred: importing dynamo costs a second

    probe = torch.ones(2, requires_grad=True)
    try:
        torch.compile(lambda x: (x.sin() * 2.0).sum())(probe).backward()  # d/dx 2 sin x = 2 cos x: one kernel each way
    except BackendCompilerFailed as error:
        return str(error).strip().splitlines()[0]
    return None


# ---------------------------------------------------------------------------------------------- the rewards
def check_reward_terms(env: Any, steps: int = 8, atol: float = 1e-4, sums_to_native: bool = True) -> None:
    """Steps ``env`` (a task env with :class:`~torchrl_ahrs.rewards.components.RewardComponents`) ``steps`` times
    under random actions and raises :class:`PreflightError` when a component's term is not in the environment's
    output (naming the key and the keys that exist), or when ``sums_to_native`` and the components do not add
    up to the native reward ``("reward", "total")`` (within ``atol + 1e-4 |total|``).

    Example:
        >>> from torchrl.envs import TransformedEnv
        >>> from torchrl_ahrs.envs.tasks.point_reach import PointReachEnv
        >>> from torchrl_ahrs.rewards.components import RewardComponents
        >>> env = TransformedEnv(PointReachEnv(num_envs=2),
        ...     RewardComponents(["distance", "arrival"], term_keys={c: ("info", f"reward_{c}") for c in ["distance", "arrival"]}))
        >>> try:
        ...     check_reward_terms(env)  # ctrl is missing: the two do not make the native reward
        ... except PreflightError as error:
        ...     print(str(error).split(" on the")[0])
        the components distance + arrival do not add up to the native reward
    """
    from torchrl_ahrs.rewards.components import RewardComponents, TermMissing

    transform = getattr(env, "transform", None)
    transforms = [transform] if isinstance(transform, RewardComponents) else list(transform or [])  # one or a Compose
    found = [t for t in transforms if isinstance(t, RewardComponents)]
    if not found:
        return
    leaves = list(found[0].leaf_names)
    try:
        rollout = env.rollout(steps, break_when_any_done=False)
    except TermMissing as error:
        raise PreflightError(str(error)) from None
    if not sums_to_native or not leaves:
        return
    reward = rollout.get(("next", "reward"))
    total = reward.get("total").float()
    summed = torch.stack([reward.get(name).float() for name in leaves]).sum(0)
    gap = (summed - total).abs()
    if (gap > atol + 1e-4 * total.abs()).any():
        raise PreflightError(
            f"the components {' + '.join(leaves)} do not add up to the native reward on the first steps (largest gap "
            f"{gap.max().item():.3g}); check task.components / task.terms"
        )


def check_task_rewards(make_envs: Any, seed: int, sums_to_native: bool = True, steps: int = 8) -> None:
    """:func:`check_reward_terms` on a 2-environment probe built by ``make_envs(num_envs, seed)``, closed after;
    the global random generators (the probe's random actions draw from torch's) are left as they were, so a
    seed trains the same run with or without the check."""
    with torch.random.fork_rng(devices=[]):
        numpy_state, python_state = np.random.get_state(), random.getstate()
        probe = make_envs(2, seed)
        try:
            check_reward_terms(probe, steps=steps, sums_to_native=sums_to_native)
        finally:
            probe.close()
            np.random.set_state(numpy_state)
            random.setstate(python_state)
