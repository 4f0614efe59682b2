"""Checks on a composed Hydra config, derived values, and saving it without secrets."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, cast

import torch
from omegaconf import DictConfig, OmegaConf

from torchrl_ahrs.app.shared.auxiliary import aux_leaves, auxiliary_components
from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.redaction import is_secret_key
from torchrl_ahrs.app.shared.run_dir import REDACTED, RunDirectory
from torchrl_ahrs.app.shared.settings import override_task
from torchrl_ahrs.envs.registry import available_tasks
from torchrl_ahrs.training.loggers import BACKENDS
from torchrl_ahrs.training.models import DISTRIBUTIONS, OBSERVATION_NORMS, PRECISIONS
from torchrl_ahrs.training.run import ADVANTAGE_PASSES, KL_ADAPTS
from torchrl_ahrs.value.gae import MIXES

__all__ = [
    "check_device",
    "load_saved_config",
    "num_minibatches",
    "refuse_renamed",
    "resolve_components",
    "save_config",
    "validate_config",
]


def resolve_components(cfg: DictConfig) -> list[str]:
    """The reward leaves forming the K axis: the method's list, or the task's when it says null
    (+ ``aux`` when ``method.auxiliary: branch``; ``[total_aux]`` when ``method.auxiliary: total``)."""
    return auxiliary_components(cfg.method.get("components"), cfg.task.components, cfg.method.get("auxiliary"))


# Keys renamed to TorchRL's names: an old name is refused with a pointer to its successor.
RENAMED_KEYS = {
    "ppo.entropy_coef": "ppo.entropy_coeff",
    "ppo.critic_coef": "ppo.critic_coeff",
    "trainer.rollout_steps": "trainer.frames_per_batch (= num_envs x steps per environment)",
    "trainer.num_minibatches": "trainer.mini_batch_size (= frames_per_batch / minibatches)",
    "ppo.normalize_components": "ppo.component_scale (raw | standardize | value_norm)",
    "device": "trainer.device (null = the simulation's device)",
}


def refuse_renamed(keys: Iterable[str]) -> None:
    """Raises :class:`ConfigError` naming the new key when ``keys`` holds a renamed one.

    Example:
        >>> refuse_renamed(["trainer.lr", "ppo.entropy_coef"])
        Traceback (most recent call last):
        ...
        torchrl_ahrs.app.shared.errors.ConfigError: ppo.entropy_coef was renamed: use ppo.entropy_coeff
    """
    for key in keys:
        key = key.lstrip("+~")
        if key in RENAMED_KEYS:
            raise ConfigError(f"{key} was renamed: use {RENAMED_KEYS[key]}")


def num_minibatches(cfg: DictConfig) -> int:
    """Minibatches per PPO epoch: ``frames_per_batch / mini_batch_size``."""
    return cfg.trainer.frames_per_batch // cfg.trainer.mini_batch_size


def collection_threads(trainer: DictConfig) -> int:
    """Torch's intra-op threads while the collector steps: ``trainer.collection_threads``, or ``torch_threads``
    where it is null (or absent, in a run saved before the key)."""
    threads = trainer.get("collection_threads")
    return trainer.torch_threads if threads is None else threads


def validate_config(cfg: DictConfig) -> None:
    """Raises :class:`ConfigError` with one clear line for the first impossible value."""
    refuse_renamed(dotted_keys(OmegaConf.to_container(cfg, resolve=False)))
    if cfg.task.name not in available_tasks():
        raise ConfigError(f"unknown task {cfg.task.name!r}; available tasks: {', '.join(available_tasks())}")
    trainer = cfg.trainer
    override_task(cfg.task, trainer.get("task_overrides"))  # each one names a setting of the task, or a ConfigError
    positive = {
        "trainer.total_frames": trainer.total_frames,
        "trainer.num_envs": trainer.num_envs,
        "trainer.frames_per_batch": trainer.frames_per_batch,
        "trainer.num_epochs": trainer.num_epochs,
        "trainer.mini_batch_size": trainer.mini_batch_size,
        "trainer.workers": trainer.workers,
        "trainer.torch_threads": trainer.torch_threads,
        "trainer.collection_threads": collection_threads(trainer),
        "scheduler.interval": cfg.scheduler.interval if cfg.scheduler.get("interval") is not None else 1,
        "scheduler.decisions": cfg.scheduler.get("decisions", 1),
        "scheduler.history_length": cfg.scheduler.history_length,
    }
    if not isinstance(cfg.checkpoint.interval, int) or cfg.checkpoint.interval < 0:
        raise ConfigError(f"checkpoint.interval must be a non-negative integer, got {cfg.checkpoint.interval!r}")
    for name, value in positive.items():
        if not isinstance(value, int) or value < 1:
            raise ConfigError(f"{name} must be a positive integer, got {value!r}")
    unknown_backends = [name for name in cfg.logger.backends if name not in BACKENDS]
    if unknown_backends:
        raise ConfigError(f"unknown logger backend(s) {unknown_backends}; accepted: {', '.join(BACKENDS)}")
    if trainer.lr <= 0:
        raise ConfigError(f"trainer.lr must be positive, got {trainer.lr}")
    if trainer.collector not in ("sync", "multi", "async"):
        raise ConfigError(f"trainer.collector must be 'sync', 'multi' or 'async', got {trainer.collector!r}")
    check_device(trainer.get("device"), trainer.collector)
    if trainer.collector != "sync" and trainer.num_envs % trainer.workers:
        raise ConfigError(
            f"trainer.num_envs ({trainer.num_envs}) must be divisible by trainer.workers ({trainer.workers})"
        )
    if trainer.frames_per_batch % trainer.num_envs:
        raise ConfigError(
            f"trainer.frames_per_batch ({trainer.frames_per_batch}) must be a multiple of trainer.num_envs "
            f"({trainer.num_envs}): each environment steps frames_per_batch / num_envs times per iteration"
        )
    if trainer.frames_per_batch % trainer.mini_batch_size:
        raise ConfigError(
            f"trainer.frames_per_batch ({trainer.frames_per_batch}) must be a multiple of trainer.mini_batch_size "
            f"({trainer.mini_batch_size})"
        )
    if not 0 <= cfg.ppo.gamma <= 1 or not 0 <= cfg.ppo.lmbda <= 1:
        raise ConfigError(f"ppo.gamma and ppo.lmbda must lie in [0, 1], got {cfg.ppo.gamma}, {cfg.ppo.lmbda}")
    if cfg.model.get("distribution", "tanh_normal") not in DISTRIBUTIONS:
        raise ConfigError(
            f"model.distribution must be one of {', '.join(DISTRIBUTIONS)}, got {cfg.model.distribution!r}"
        )
    if cfg.model.get("observation_norm", "running") not in OBSERVATION_NORMS:
        raise ConfigError(
            f"model.observation_norm must be one of {', '.join(OBSERVATION_NORMS)}, got {cfg.model.observation_norm!r}"
        )
    if cfg.model.get("precision", "float32") not in PRECISIONS:  # float32 in a run saved before the key
        raise ConfigError(f"model.precision must be one of {', '.join(PRECISIONS)}, got {cfg.model.precision!r}")
    for key in ("actor_precision", "critic_precision"):  # null: the network follows model.precision
        if cfg.model.get(key) not in (*PRECISIONS, None):
            raise ConfigError(f"model.{key} must be one of {', '.join(PRECISIONS)} or null, got {cfg.model.get(key)!r}")
    ppo = cfg.ppo
    if ppo.get("value_norm") not in (None, False, True, "running", "popart"):
        raise ConfigError(f"ppo.value_norm must be running, popart or null, got {ppo.get('value_norm')!r}")
    if ppo.get("component_scale") == "value_norm" and not ppo.get("value_norm"):
        raise ConfigError(
            "ppo.component_scale=value_norm divides each component's advantage by its head's scale in "
            "ppo.value_norm, which is null: set ppo.value_norm=running (or popart)"
        )
    for name in ("clip_value", "kl_target"):
        value = ppo.get(name)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int | float) or value <= 0):
            raise ConfigError(f"ppo.{name} must be a positive number or null, got {value!r}")
    if ppo.get("kl_adapts", "all") not in KL_ADAPTS:
        raise ConfigError(f"ppo.kl_adapts must be one of {', '.join(KL_ADAPTS)}, got {ppo.kl_adapts!r}")
    if ppo.get("mix", "sum") not in MIXES:
        raise ConfigError(f"ppo.mix must be one of {', '.join(MIXES)}, got {ppo.mix!r}")
    if ppo.get("advantage_pass", "every_epoch") not in ADVANTAGE_PASSES:
        raise ConfigError(
            f"ppo.advantage_pass must be one of {', '.join(ADVANTAGE_PASSES)}, got {ppo.advantage_pass!r}"
        )
    if not isinstance(ppo.get("mirror", False), bool):
        raise ConfigError(f"ppo.mirror must be true or false, got {ppo.mirror!r}")
    if not isinstance(trainer.get("compile", False), bool):
        raise ConfigError(f"trainer.compile must be true or false, got {trainer.compile!r}")
    components = resolve_components(cfg)
    known = set(cfg.task.components) | {"total"} | aux_leaves(cfg.method.get("auxiliary"))
    unknown = [name for name in components if name not in known]
    if unknown:
        raise ConfigError(
            f"method {cfg.method.name!r} uses components {unknown} that task {cfg.task.name!r} does not have; "
            f"its components are {list(cfg.task.components)} (and 'total')"
        )
    weights = cfg.method.get("initial_weights")
    if weights is not None and len(weights) != len(components):
        raise ConfigError(
            f"method.initial_weights has {len(weights)} values but there are {len(components)} components {components}"
        )


def check_device(device: Any, collector: str = "sync") -> None:
    """Raises :class:`ConfigError` unless ``trainer.device`` is null, ``cpu`` or a CUDA device torch can see
    (with the in-process ``sync`` collector: worker processes keep their environments and policy on the CPU).

    Example:
        >>> check_device("cpu"); check_device(None)
        >>> check_device("gpu")
        Traceback (most recent call last):
        ...
        torchrl_ahrs.app.shared.errors.ConfigError: trainer.device must be null, cpu, cuda or cuda:<index>, got 'gpu'
    """
    if device is None:
        return
    try:
        parsed = torch.device(str(device))
    except (RuntimeError, ValueError):
        parsed = None
    if parsed is None or parsed.type not in ("cpu", "cuda"):
        raise ConfigError(f"trainer.device must be null, cpu, cuda or cuda:<index>, got {device!r}")
    if parsed.type == "cpu":
        return
    if not torch.cuda.is_available():
        raise ConfigError(
            f"trainer.device={device} but torch sees no CUDA device (torch.cuda.is_available() is False): "
            "use trainer.device=cpu, or null for the simulation's device"
        )
    if parsed.index is not None and parsed.index >= torch.cuda.device_count():
        raise ConfigError(f"trainer.device={device} but torch sees {torch.cuda.device_count()} CUDA device(s)")
    if collector != "sync":
        raise ConfigError(f"trainer.device={device} needs trainer.collector=sync (got {collector!r})")


def dotted_keys(container: Any, prefix: str = "") -> list[str]:
    """Every key of a nested dict as a dotted path, parents before children.

    Example:
        >>> dotted_keys({"a": {"b": 1}, "c": 2})
        ['a', 'a.b', 'c']
    """
    if not isinstance(container, dict):
        return []
    keys = []
    for key, value in container.items():
        dotted = f"{prefix}{key}"
        keys += [dotted, *dotted_keys(value, dotted + ".")]
    return keys


def redact(container: Any) -> Any:
    """A copy of a plain dict/list tree with every secret-looking field replaced by ``<redacted>``."""
    if isinstance(container, dict):
        return {
            key: (REDACTED if _is_secret(key) and value not in (None, "") else redact(value))
            for key, value in container.items()
        }
    if isinstance(container, list):
        return [redact(value) for value in container]
    return container


def _is_secret(key: Any) -> bool:
    return isinstance(key, str) and is_secret_key(key)


def load_saved_config(run_dir: Path, overrides: Sequence[str] = ()) -> DictConfig:
    """A run's saved config (:attr:`RunDirectory.config`) with redacted secrets emptied (they come from the environment
    again) and ``key=value`` command-line overrides applied (group choices such as ``task=`` are
    ignored: a resumed run keeps its task and method)."""
    path = RunDirectory(run_dir).config
    if not path.is_file():
        raise FileNotFoundError(f"no {path.name} in {run_dir}; is it a torchrl_ahrs run directory?")
    saved = OmegaConf.to_container(OmegaConf.load(path))
    cfg = OmegaConf.create(_unredact(saved))
    dotted = [item for item in overrides if "=" in item and "." in item.split("=", 1)[0]]
    cfg = cast(DictConfig, OmegaConf.merge(cfg, OmegaConf.from_dotlist(dotted)))  # saved from a DictConfig
    cfg.resume = str(run_dir)
    return cfg


def _unredact(container: Any) -> Any:
    if isinstance(container, dict):
        return {key: None if value == REDACTED else _unredact(value) for key, value in container.items()}
    if isinstance(container, list):
        return [_unredact(value) for value in container]
    return container


def save_config(cfg: DictConfig, path: Path) -> None:
    """Writes the resolved config as YAML, secrets redacted."""
    resolved = OmegaConf.to_container(cfg, resolve=True)
    path.write_text(OmegaConf.to_yaml(OmegaConf.create(redact(resolved))))


def network_precision(model: DictConfig, network: str) -> str:
    """The precision setting of ``network`` (``actor`` or ``critic``): ``model.<network>_precision``, or
    ``model.precision`` where that is unset (null), or float32 for a run saved before either key.

    Example:
        >>> from omegaconf import OmegaConf
        >>> model = OmegaConf.create({"precision": "auto", "actor_precision": "float32", "critic_precision": None})
        >>> network_precision(model, "actor"), network_precision(model, "critic")
        ('float32', 'auto')
    """
    return model.get(f"{network}_precision") or model.get("precision", "float32")
