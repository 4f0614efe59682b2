"""The environment classes keep keyword defaults so they can be built by hand, without Hydra; ``conf/task/*.yaml``
documents the same values. This pins the two together: a default that drifts from its task file fails here,
naming the class, the parameter and both values (issue 25: every default written once, or checked against it)."""

import inspect
import math
from collections.abc import Mapping

import pytest

from torchrl_ahrs.app.shared.settings import load_task_settings
from torchrl_ahrs.envs.common.legged_rewards import CASSIE_REWARD_SCALES
from torchrl_ahrs.envs.tasks.ant import DEFAULT_SCALES, AntEnv
from torchrl_ahrs.envs.tasks.cassie import CassieEnv
from torchrl_ahrs.envs.tasks.point_reach import PointReachEnv
from torchrl_ahrs.envs.tasks.quadcopter import QuadcopterEnv
from torchrl_ahrs.envs.tasks.shadow_hand_bottle_cap import ShadowHandBottleCapEnv
from torchrl_ahrs.envs.tasks.shadow_hand_scissors import ShadowHandScissorsEnv

CLASSES = {
    "cassie": CassieEnv,
    "ant": AntEnv,
    "quadcopter": QuadcopterEnv,
    "point_reach": PointReachEnv,
    "shadow_hand_scissors": ShadowHandScissorsEnv,
    "shadow_hand_bottle_cap": ShadowHandBottleCapEnv,
}

# module-level tables a constructor falls back to when its argument is None: (task, field, table)
TABLES = [("ant", "scales", DEFAULT_SCALES), ("cassie", "reward_scales", CASSIE_REWARD_SCALES)]


def flat_settings(record) -> dict[str, object]:
    """The record's fields by name, nested records flattened into their fields (``commands.resampling_time_s``
    is also reachable as ``resampling_time_s``: the constructors take the nested fields flat)."""
    fields = {}
    for name, value in vars(record).items():
        if hasattr(value, "__dataclass_fields__"):
            fields.update(flat_settings(value))
        fields[name] = value
    return fields


def same(default, documented) -> bool:
    if isinstance(default, float) or isinstance(documented, float):
        return math.isclose(float(default), float(documented), rel_tol=1e-9, abs_tol=1e-12)
    if isinstance(default, Mapping) and isinstance(documented, Mapping):
        return dict(default) == dict(documented)
    if isinstance(default, (tuple, list)) and isinstance(documented, (tuple, list)):
        return list(default) == list(documented)
    return default == documented


def compared_defaults(task: str) -> list[tuple[str, object, object]]:
    """(parameter, constructor default, task file value) for every defaulted parameter the task file also sets
    (a ``null`` in the file means "absent": the builder then leaves the constructor's default in force)."""
    documented = flat_settings(load_task_settings(task))
    signature = inspect.signature(CLASSES[task].__init__)
    return [
        (name, parameter.default, documented[name])
        for name, parameter in signature.parameters.items()
        if parameter.default is not inspect.Parameter.empty
        and parameter.default is not None
        and documented.get(name) is not None
    ] + [(field, table, documented[field]) for table_task, field, table in TABLES if table_task == task]


@pytest.mark.parametrize("task", sorted(CLASSES))
def test_constructor_defaults_equal_the_task_file(task):
    pairs = compared_defaults(task)
    assert len(pairs) >= 2, f"{CLASSES[task].__name__}: only {len(pairs)} defaults matched {task}.yaml by name"
    drifted = [
        f"{name}: default {default!r}, {task}.yaml {value!r}"
        for name, default, value in pairs
        if not same(default, value)
    ]
    assert not drifted, f"{CLASSES[task].__name__} drifted from conf/task/{task}.yaml: " + "; ".join(drifted)


def test_a_drifted_default_is_found():
    assert not same(0.25, 0.5) and not same({"a": 1.0}, {"a": 2.0}) and same((1, 2), [1, 2]) and same(0.1, 0.1)
