"""Defaults written once: the Python API's and the shipped config's agree."""

import dataclasses

import torch
from conftest import make_cfg

from torchrl_ahrs.scheduling import DEFAULTS, ScheduleSettings, WeightMapping
from torchrl_ahrs.scheduling.scheduler import RuleScheduler


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
