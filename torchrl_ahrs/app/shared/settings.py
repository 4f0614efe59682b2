"""The one translation from the Hydra tree to the library's typed settings: the library never reads config.

* :func:`scheduler_settings`: ``scheduler``, ``method``, ``seed``, ``llm``, ``task``, ``aux.path`` and the
  run's length → :class:`~torchrl_ahrs.scheduling.SchedulerSettings` (for ``build_scheduler``).
* :func:`llm_settings`: the ``llm`` group → :class:`~torchrl_ahrs.llm.client.LLMConfig`.
* :func:`llm_and_task`, :func:`generation_output_dir`: what the generator commands read.
* :func:`load_task_config`: ``conf/task/<name>.yaml`` composed from the installed package.
* :func:`override_task`: a ``task`` section with some of its settings changed (``trainer.task_overrides`` for the
  training environments, ``evaluate task=`` for one evaluation); a key the task does not have is refused.
* :func:`task_settings`, :func:`load_task_settings`: the ``task`` section → the frozen record its builder
  reads (:mod:`torchrl_ahrs.envs.settings`); a key no field takes is refused, naming it and the task.
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
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar, cast

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.envs.registry import settings_type
from torchrl_ahrs.envs.settings import TaskSettings
from torchrl_ahrs.llm.client import LLMConfig
from torchrl_ahrs.llm.generation import generation_output_dir as _output_dir
from torchrl_ahrs.llm.generation import require_llm
from torchrl_ahrs.scheduling.settings import BanditSettings, SchedulerSettings, ScheduleSettings, SelectionSettings

__all__ = [
    "generation_output_dir",
    "llm_and_task",
    "llm_settings",
    "load_task_config",
    "load_task_settings",
    "schedule_settings",
    "scheduler_settings",
    "select",
    "selection_settings",
    "task_settings",
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


def override_task(task: DictConfig, overrides: Mapping[str, Any] | None) -> DictConfig:
    """``task`` with ``overrides`` merged in, as a copy; every overridden key must already be a setting of ``task``.

    Example:
        >>> task = OmegaConf.create({"name": "cassie", "commands": {"resampling_time_s": 10.0}})
        >>> override_task(task, {"commands": {"resampling_time_s": 5.0}}).commands.resampling_time_s
        5.0
        >>> task.commands.resampling_time_s  # the caller's section is not changed
        10.0
        >>> override_task(task, {"commands": {"resampling_s": 5.0}})
        Traceback (most recent call last):
        ...
        torchrl_ahrs.app.shared.errors.ConfigError: task.commands.resampling_s is not a setting of task 'cassie'
    """
    base = OmegaConf.create(OmegaConf.to_container(task, resolve=True))  # a copy: the caller's config is not changed
    if not overrides:
        return cast(DictConfig, base)
    OmegaConf.set_struct(base, True)  # struct: a misspelt key raises instead of adding a setting nothing reads
    try:
        merged = cast(DictConfig, OmegaConf.merge(base, OmegaConf.create(dict(overrides))))  # a mapping into a mapping
    except OmegaConfBaseException as error:
        key = getattr(error, "full_key", None) or " ".join(str(error).split())[:300]
        raise ConfigError(f"task.{key} is not a setting of task {task.get('name')!r}") from None
    OmegaConf.set_struct(merged, False)  # from here on the same open config as a task that was not overridden
    return merged


# task keys that are not simulation settings: the prompts' text, and what the trainer reads from cfg.task
NON_SIMULATION_KEYS = (
    "description",
    "component_descriptions",
    "reward_code",
    "environment_code",
    "critic_observation",
    "components_sum_to_native",
)


def _typed_record(record_type: type[Record], section: Mapping[str, Any], where: str) -> Record:
    """``record_type`` from the keys of ``section``: a nested record field is converted key by key, a list
    becomes a tuple where the field is a tuple; an unknown or missing key raises a one-line ConfigError."""
    hints = typing.get_type_hints(record_type)
    fields = {f.name: f for f in dataclasses.fields(record_type)}  # type: ignore[arg-type]
    for key in section:
        if key not in fields:
            raise ConfigError(f"{where}: unknown key {key!r}; its keys are {', '.join(sorted(fields))}")
    values = {}
    for name, value in section.items():
        hint = hints[name]
        if dataclasses.is_dataclass(hint) and isinstance(value, Mapping):
            value = _typed_record(cast(type, hint), value, f"{where}.{name}")
        elif isinstance(value, list) and tuple in (
            typing.get_origin(hint),
            *map(typing.get_origin, typing.get_args(hint)),
        ):
            value = tuple(value)
        values[name] = value
    absent = [f.name for f in fields.values() if f.name not in values and f.default is dataclasses.MISSING]
    if absent:
        raise ConfigError(f"{where}: missing key {absent[0]!r} (every key without a default must be set)")
    return record_type(**values)


def task_settings(task: Any) -> TaskSettings:
    """The ``task`` section (a composed config, e.g. :func:`load_task_config`'s, or a plain mapping) as the
    settings record its builder reads (:func:`~torchrl_ahrs.envs.registry.settings_type`).

    Raises:
        ConfigError: the task is unknown, or a key is not a setting of the task (one line naming both).

    Example:
        >>> settings = task_settings(load_task_config("point_reach", ["task.ctrl_cost=0.1"]))
        >>> type(settings).__name__, settings.ctrl_cost, settings.components
        ('PointReachSettings', 0.1, ('distance', 'arrival', 'ctrl'))
        >>> try:
        ...     task_settings({**load_task_config("point_reach"), "ctrl_weight": 1.0})
        ... except ConfigError as error:
        ...     print(str(error).split(";")[0])
        task 'point_reach': unknown key 'ctrl_weight'
    """
    # a plain mapping may hold config nodes (``{**cfg, ...}``): one round trip makes every value plain
    container = OmegaConf.to_container(
        task if OmegaConf.is_config(task) else OmegaConf.create(dict(task)), resolve=True
    )
    section = {str(key): value for key, value in cast(dict, container).items() if key not in NON_SIMULATION_KEYS}
    name = section.get("name")
    try:
        record_type = settings_type(str(name))
    except KeyError as error:
        raise ConfigError(str(error.args[0])) from None
    return _typed_record(record_type, section, f"task {name!r}")


def load_task_settings(name: str, overrides: Sequence[str] = ()) -> TaskSettings:
    """:func:`task_settings` of :func:`load_task_config`: what building task ``name`` by hand takes.

    Example:
        >>> from torchrl_ahrs.envs import make_env
        >>> env = make_env(load_task_settings("point_reach", ["task.max_episode_steps=10"]), num_envs=2)
        >>> env.rollout(3)["next", "reward", "total"].shape
        torch.Size([2, 3, 1])
    """
    return task_settings(load_task_config(name, overrides))
