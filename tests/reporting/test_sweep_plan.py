"""Which runs a report calls missing: the sweep's ``plan.yaml`` when it has one, else Hydra's ``multirun.yaml``."""

import pytest
import yaml

from torchrl_ahrs.app.train.runs import load_sweep, planned_cells


def make_run(sweep, task, method, seed):
    run = sweep / task / method / f"seed_{seed}"
    run.mkdir(parents=True)
    config = {"task": {"name": task}, "method": {"name": method, "selector": "llm"}, "llm": {"name": "offline"}}
    config |= {"seed": seed, "trainer": {"total_frames": 100}}
    (run / "config.yaml").write_text(yaml.safe_dump(config))


def statuses(sweep):
    return {(run.task, run.method, run.seed): run.status for run in load_sweep(sweep)}


def test_the_plan_names_the_missing_runs_where_the_last_multirun_cannot(tmp_path):
    make_run(tmp_path, "ant", "ppo", 1)
    make_run(tmp_path, "quadcopter", "rule_a", 1)
    # the last invocation swept ant on seed 2 only; read alone, it would call quadcopter's rule seed 2 missing
    (tmp_path / "multirun.yaml").write_text(yaml.safe_dump({"hydra": {"overrides": {"task": ["seed=2"]}}}))
    assert ("quadcopter", "rule_a[bandit]", 2) in statuses(tmp_path)
    (tmp_path / "plan.yaml").write_text(
        "cells:\n  - {task: ant, methods: [ppo], seeds: 'range(1,3)'}\n  - {task: quadcopter, methods: [rule_a], seeds: [1]}\n"
    )
    assert statuses(tmp_path) == {
        ("ant", "ppo[bandit]", 1): "incomplete",  # the plan's "ppo" is this run: its label adds who chose
        ("ant", "ppo", 2): "missing",
        ("quadcopter", "rule_a[bandit]", 1): "incomplete",
    }


def test_a_malformed_plan_is_one_clear_error(tmp_path):
    (tmp_path / "plan.yaml").write_text("cells:\n  - {task: ant, methods: [ppo], seeds: some}\n")
    with pytest.raises(ValueError, match=r"plan.yaml: cell 0 needs task, methods and seeds"):
        planned_cells(tmp_path)
