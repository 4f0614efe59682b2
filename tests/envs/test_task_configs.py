"""The task configs: every task composes from its family's base (``conf/task/_envpool.yaml``, ``_mujoco.yaml``,
``_mjx.yaml``), declares a backend its builder accepts, and leaves no required slot (``???``) unfilled."""

import dataclasses
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.settings import NON_SIMULATION_KEYS, load_task_config, task_settings
from torchrl_ahrs.envs.registry import _BUILDERS, _MJX_BUILDERS, _SETTINGS, BACKENDS, settings_type

TASK_DIR = Path(__file__).resolve().parents[2] / "conf" / "task"
TASKS = sorted(p.stem for p in TASK_DIR.glob("*.yaml") if not p.stem.startswith("_"))
BASES = sorted(p.stem for p in TASK_DIR.glob("_*.yaml"))
ENVPOOL_FAMILY = {
    "ant_v5", "dmc_cheetah_run", "dmc_quadruped_run", "dmc_walker_walk", "go1_terrain", "humanoid", "leap_cube",
    "shadow_hand",
}  # fmt: skip


def base_of(task: str) -> str | None:
    """The base named in the task file's own defaults list (None: no base)."""
    defaults = OmegaConf.load(TASK_DIR / f"{task}.yaml").get("defaults") or []
    bases = [entry for entry in defaults if isinstance(entry, str) and entry.startswith("_") and entry != "_self_"]
    return bases[0] if bases else None


def test_every_task_file_is_a_registered_task_and_bases_are_not():
    assert set(TASKS) == set(_BUILDERS) == set(_SETTINGS) and BASES == ["_envpool", "_mjx", "_mujoco"]


@pytest.mark.parametrize("task", TASKS)
def test_every_task_declares_a_backend_and_fills_every_slot(task):
    own = OmegaConf.load(TASK_DIR / f"{task}.yaml")
    cfg = load_task_config(task)
    assert cfg.backend in BACKENDS and ("backend" in own or base_of(task) is not None), task
    assert OmegaConf.missing_keys(cfg) == set(), f"{task} leaves required slots unfilled"
    assert cfg.name == task
    if base_of(task) == "_mjx":
        assert task in _MJX_BUILDERS and load_task_config(task, ["task.backend=mjx"]).backend == "mjx"


def test_the_envpool_family_shares_one_base():
    assert {task for task in TASKS if base_of(task) == "_envpool"} == ENVPOOL_FAMILY
    for task in ENVPOOL_FAMILY:  # the slots the base fills are no longer repeated in the task file
        own = OmegaConf.load(TASK_DIR / f"{task}.yaml")
        assert "num_threads" not in own and "environment_code" not in own and "backend" not in own, task


def test_a_base_slot_left_unfilled_is_reported():
    base = OmegaConf.load(TASK_DIR / "_envpool.yaml")
    assert {"name", "env_id", "components", "description", "component_descriptions"} <= OmegaConf.missing_keys(base)


@pytest.mark.parametrize("task", TASKS)
def test_every_task_config_is_its_builders_settings_record(task):
    """Every key of the composed task is a field of its record (or a prompt/trainer key), and every field
    without a default is set by the YAML: the defaults live in conf/ only."""
    settings = task_settings(load_task_config(task))
    assert type(settings) is settings_type(task) and settings.name == task
    assert dataclasses.is_dataclass(settings) and type(settings).__dataclass_params__.frozen  # type: ignore[attr-defined]
    own = set(OmegaConf.to_container(load_task_config(task))) - set(NON_SIMULATION_KEYS)
    defaulted = {f.name for f in dataclasses.fields(settings) if f.default is not dataclasses.MISSING}
    assert own == {f.name for f in dataclasses.fields(settings)} - (defaulted - own), task
    for name in defaulted & own:  # an optional switch the task sets must differ from "absent"
        assert getattr(settings, name) is not None, (task, name)


def test_an_unknown_task_key_is_a_one_line_error_naming_the_key_and_the_task():
    with pytest.raises(ConfigError, match=r"^task 'point_reach': unknown key 'ctrl_weight'; its keys are ") as error:
        task_settings(load_task_config("point_reach", ["+task.ctrl_weight=0.1"]))
    assert "\n" not in str(error.value)
    with pytest.raises(ConfigError, match=r"^task 'cassie'\.commands: unknown key 'heading'"):
        task_settings(load_task_config("cassie", ["+task.commands.heading=1.0"]))
    with pytest.raises(ConfigError, match=r"^task 'quadcopter': missing key 'min_height'"):
        task_settings({k: v for k, v in load_task_config("quadcopter").items() if k != "min_height"})
    with pytest.raises(ConfigError, match=r"unknown task 'no_such_task'"):
        task_settings({"name": "no_such_task"})
