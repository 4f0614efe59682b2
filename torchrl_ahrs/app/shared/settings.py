"""The one translation from the Hydra tree to the library's typed settings: the library never reads config.

* :func:`scheduler_settings`: ``scheduler``, ``method``, ``seed``, ``llm``, ``task``, ``aux.path`` and the
  run's length → :class:`~torchrl_ahrs.scheduling.SchedulerSettings` (for ``build_scheduler``).
* :func:`llm_settings`: the ``llm`` group → :class:`~torchrl_ahrs.llm.client.LLMConfig`.
* :func:`llm_and_task`, :func:`generation_output_dir`: what the generator commands read.
* :func:`load_task_config`: ``conf/task/<name>.yaml`` composed from the installed package.
* :func:`select`: one optional value of a composed config or a plain nested dict.

A missing or null key takes the record's default, so a partial config (or a plain dict in a test) works.

Example:
    >>> from omegaconf import OmegaConf
    >>> cfg = OmegaConf.create({"seed": 3, "method": {"selector": "fixed", "rule": "hdpg"},
    ...                         "scheduler": {"interval": None, "clamp": [0.0, 3.0]},
    ...                         "trainer": {"total_frames": 1_000_000, "frames_per_batch": 2048}})
    >>> settings = scheduler_settings(cfg)
    >>> settings.selection.selector, settings.selection.seed, settings.schedule.clamp, settings.decision_interval()
    ('fixed', 3, (0.0, 3.0), 32)
    >>> scheduler_settings({}).selection.selector, llm_settings({}).name
    ('constant', 'offline')
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar, cast

from omegaconf import DictConfig, OmegaConf

from torchrl_ahrs.llm.client import LLMConfig
from torchrl_ahrs.llm.generation import generation_output_dir as _output_dir
from torchrl_ahrs.llm.generation import require_llm
from torchrl_ahrs.scheduling.settings import BanditSettings, SchedulerSettings, ScheduleSettings, SelectionSettings

__all__ = [
    "generation_output_dir",
    "llm_and_task",
    "llm_settings",
    "load_task_config",
    "schedule_settings",
    "scheduler_settings",
    "select",
    "selection_settings",
]

Record = TypeVar("Record")


def select(cfg: Any, key: str, default: Any = None) -> Any:
    """The value at dotted ``key``, or ``default`` when it, or a section on the way, is missing or null.

    ``cfg`` is an OmegaConf config (interpolations resolved) or a plain nested mapping (a config turned
    into a container); anything else has no settings and gives ``default``.

    Example:
        >>> cfg = OmegaConf.create({"aux": {"scale": 2.0, "path": None}})
        >>> select(cfg, "aux.scale", 1.0), select(cfg, "aux.path", "shipped"), select(cfg, "llm.model")
        (2.0, 'shipped', None)
        >>> select({"seed": 3}, "seed", 0), select(None, "seed", 0)
        (3, 0)
    """
    if OmegaConf.is_config(cfg):
        value = OmegaConf.select(cfg, key, default=None)
    else:
        value = cfg
        for part in key.split("."):
            value = value.get(part) if isinstance(value, Mapping) else None
    return default if value is None else value


def _container(cfg: Any, key: str) -> dict[str, Any]:
    """The section at ``key`` as a plain resolved dict ({} when missing or null)."""
    section = select(cfg, key)
    if section is None:
        return {}
    if OmegaConf.is_config(section):
        return cast(dict[str, Any], OmegaConf.to_container(section, resolve=True))
    return dict(section)


def _record(record_type: type[Record], section: Mapping[str, Any], **converters: Any) -> Record:
    """``record_type`` with each field taken from ``section`` when present and not null (else its default),
    passed through ``converters[field]`` when given."""
    values = {}
    for field in dataclasses.fields(record_type):  # type: ignore[arg-type]
        value = section.get(field.name)
        if value is not None:
            values[field.name] = converters[field.name](value) if field.name in converters else value
    return record_type(**values)


def schedule_settings(cfg: Any) -> ScheduleSettings:
    """The ``scheduler`` section as :class:`ScheduleSettings`."""
    return _record(ScheduleSettings, _container(cfg, "scheduler"), clamp=lambda c: (float(c[0]), float(c[1])))


def selection_settings(cfg: Any) -> SelectionSettings:
    """``method.selector`` / ``rule`` / ``repository`` / ``initial_weights``, ``seed`` and ``llm.bandit``."""
    method = _container(cfg, "method")
    bandit = _record(BanditSettings, _container(cfg, "llm.bandit"))
    initial = method.get("initial_weights")
    return _record(
        SelectionSettings,
        {
            **{key: method.get(key) for key in ("selector", "rule", "repository")},
            "initial_weights": tuple(float(w) for w in initial) if initial is not None else None,
            "seed": select(cfg, "seed"),
            "bandit": bandit,
        },
        seed=int,
    )


def llm_settings(cfg: Any) -> LLMConfig:
    """The ``llm`` group as :class:`LLMConfig` (``LLMConfig()``, i.e. offline, without one)."""
    return LLMConfig.from_cfg(_container(cfg, "llm"))


def scheduler_settings(cfg: Any) -> SchedulerSettings:
    """Everything ``build_scheduler`` reads, from a composed config or a plain nested dict."""
    total_frames = select(cfg, "trainer.total_frames")
    return SchedulerSettings(
        schedule=schedule_settings(cfg),
        selection=selection_settings(cfg),
        llm=llm_settings(cfg),
        task=_container(cfg, "task"),
        aux_path=select(cfg, "aux.path"),
        total_frames=int(total_frames) if total_frames is not None else None,
        frames_per_batch=int(select(cfg, "trainer.frames_per_batch", 1)),
    )


def llm_and_task(cfg: Any, command: str) -> tuple[LLMConfig, dict[str, Any]]:
    """The LLM settings and the resolved task section of a composed config; refuses a config without an
    LLM (``llm=offline``), naming ``command`` and how to give one."""
    return require_llm(llm_settings(cfg), command), _container(cfg, "task")


def generation_output_dir(cfg: Any, kind: str) -> Path:
    """``cfg.output`` if given, else ``outputs/<kind>/<task>-<model>-<time>``; created.

    Example:
        >>> import tempfile
        >>> out = Path(tempfile.mkdtemp()) / "here"
        >>> generation_output_dir(OmegaConf.create({"output": str(out)}), "rules") == out and out.is_dir()
        True
    """
    return _output_dir(select(cfg, "output"), kind, str(select(cfg, "task.name")), select(cfg, "llm.model"))


def load_task_config(name: str, overrides: Sequence[str] = ()) -> DictConfig:
    """Composes ``conf/task/<name>.yaml`` from the installed package (Hydra's compose API); ``overrides``
    as on the command line (``task.num_threads=1``).

    Example:
        >>> cfg = load_task_config("point_reach", ["task.max_episode_steps=50"])
        >>> cfg.name, cfg.max_episode_steps, list(cfg.components)
        ('point_reach', 50, ['distance', 'arrival', 'ctrl'])
    """
    from hydra import compose, initialize_config_module

    with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"task={name}", *overrides])
    return cast(DictConfig, cfg.task)
