"""Defaults written once: the Python API's typed settings and the shipped config agree."""

import dataclasses
from pathlib import Path

import pytest
import torch
from conftest import make_cfg
from omegaconf import OmegaConf

from torchrl_ahrs.app.shared.settings import scheduler_settings
from torchrl_ahrs.llm.client import LLMConfig
from torchrl_ahrs.scheduling import (
    DEFAULTS,
    BanditSettings,
    SchedulerSettings,
    ScheduleSettings,
    SelectionSettings,
    WeightMapping,
)
from torchrl_ahrs.scheduling.scheduler import RuleScheduler

CONF = Path(__file__).resolve().parents[2] / "conf"


def test_the_config_scheduler_section_equals_the_python_defaults():
    cfg = make_cfg()
    for field in dataclasses.fields(ScheduleSettings):
        shipped = cfg.scheduler[field.name]
        shipped = tuple(shipped) if field.name == "clamp" else shipped
        assert shipped == getattr(DEFAULTS, field.name), field.name


def test_the_python_scheduler_and_mapping_take_the_same_defaults():
    assert WeightMapping().kind == DEFAULTS.weight_mapping == "minshift_sum"
    assert WeightMapping().base_weight == DEFAULTS.base_weight == 0.5

    class Estimator:
        components = ["a", "b"]
        weights = torch.ones(2)

        def set_weights(self, w):
            self.weights = w

    scheduler = RuleScheduler(Estimator())
    assert scheduler.interval is None and scheduler.decisions == DEFAULTS.decisions
    assert scheduler.mapping == WeightMapping()
    assert scheduler.derive_interval(total_frames=1_000_000, frames_per_batch=2048) == 1_000_000 // 2048 // 15


def test_the_faithful_mix_is_the_default_on_every_task():
    for task in ("quadcopter", "ant", "ant_v5", "cassie", "point_reach"):
        cfg = make_cfg(f"task={task}", "method=mcppo")
        assert cfg.ppo.component_scale == "raw", task
        assert cfg.ppo.value_norm == "running", task
        assert cfg.scheduler.weight_mapping == "minshift_sum", task


def test_the_translated_default_config_is_the_python_default_schedule():
    settings = scheduler_settings(make_cfg())
    assert settings.schedule == ScheduleSettings() == DEFAULTS
    assert settings.selection.seed == make_cfg().seed == SelectionSettings().seed
    assert settings.selection.bandit == BanditSettings()
    assert settings.llm == LLMConfig() and settings.llm_is_offline()  # the default llm group is offline
    assert settings.aux_path is SchedulerSettings().aux_path is None  # aux.path: null


def test_the_offline_llm_group_equals_the_python_llm_defaults():
    offline = OmegaConf.to_container(OmegaConf.load(CONF / "llm" / "offline.yaml"))
    fields = {field.name for field in dataclasses.fields(LLMConfig)}
    assert set(offline) - fields == {"bandit"}  # every other key is an LLMConfig field
    for key in fields & set(offline):
        assert offline[key] == getattr(LLMConfig(), key), key


@pytest.mark.parametrize("group", sorted(p.stem for p in (CONF / "llm").glob("*.yaml")))
def test_every_llm_group_has_the_python_bandit_defaults(group):
    bandit = OmegaConf.load(CONF / "llm" / f"{group}.yaml").bandit
    assert BanditSettings(**bandit) == BanditSettings(), group


@pytest.mark.parametrize("method", sorted(p.stem for p in (CONF / "method").glob("*.yaml")))
def test_every_method_translates_to_selection_settings(method):
    """The method's selector keys are SelectionSettings fields, each translated unchanged."""
    cfg = make_cfg(f"method={method}", "method.rule=2" if method == "fixed_rule" else "seed=0")
    selector_keys = set(cfg.method) - {"name", "components", "auxiliary"}
    assert selector_keys <= {field.name for field in dataclasses.fields(SelectionSettings)}, method
    selection = scheduler_settings(cfg).selection
    for key in selector_keys:
        expected = cfg.method[key]
        expected = tuple(expected) if key == "initial_weights" and expected is not None else expected
        assert getattr(selection, key) == expected, (method, key)
