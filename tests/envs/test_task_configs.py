"""The task configs: every task composes from its family's base (``conf/task/_envpool.yaml``, ``_mujoco.yaml``,
``_mjx.yaml``), declares a backend its builder accepts, and leaves no required slot (``???``) unfilled."""

from pathlib import Path

import pytest
from omegaconf import OmegaConf

from torchrl_ahrs.app.shared.settings import load_task_config
from torchrl_ahrs.envs.registry import _BUILDERS, _MJX_BUILDERS, BACKENDS

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
    assert set(TASKS) == set(_BUILDERS) and BASES == ["_envpool", "_mjx", "_mujoco"]


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
