"""Sweep report: table values against hand computation on a synthetic sweep, failed and missing seeds
listed, statistics on hand-checkable inputs, and the sweep presets load. (The smoke sweep end to end:
``tests/system/test_smoke_sweep.py``.)"""

import csv
import json
import math

import numpy as np
import pytest
import torch
import yaml
from conftest import make_cfg
from hydra.utils import get_class

from torchrl_ahrs.app.report.report import write_report
from torchrl_ahrs.reporting.intervals import improvement_probability, iqm_interval, mean_interval
from torchrl_ahrs.reporting.stats import change_percent, final_return

BUDGET = 1000


def make_run(root, method, seed, final=None, checkpoint_frames=BUDGET, components=(), rows=None, **files):
    """A run directory like train() writes: config.yaml, return/total.csv, reward/total.csv, checkpoint.pt.

    With ``final`` = f, return/total has rows (500, 999.0) outside the final window and (950, f - 1),
    (1000, f + 1) inside it, so the run's final return is f by hand: ((f - 1) + (f + 1)) / 2; reward/total
    the same shape around f / 100, the final reward per step.
    """
    run_dir = root / "point_reach" / method / f"seed_{seed}"
    scalars = run_dir / "metrics" / "scalars"
    (scalars / "return").mkdir(parents=True)
    config = {
        "seed": seed,
        "task": {"name": "point_reach", "components": ["distance", "arrival", "ctrl"]},
        "method": {"name": method, "selector": "random" if method == "ahrs_r" else "constant"},
        "llm": {"name": "offline"},
        "trainer": {"total_frames": BUDGET},
    }
    (run_dir / "config.yaml").write_text(yaml.safe_dump(config))
    if rows is None:
        rows = [(500, 999.0), (950, final - 1.0), (1000, final + 1.0)]
    (scalars / "return" / "total.csv").write_text("".join(f"{s},{v}\n" for s, v in rows))
    if final is not None:
        (scalars / "reward").mkdir()
        per_step = [(500, 9.0), (950, final / 100 - 0.01), (1000, final / 100 + 0.01)]
        (scalars / "reward" / "total.csv").write_text("".join(f"{s},{v}\n" for s, v in per_step))
    for component, value in components:
        (scalars / "return" / f"{component}.csv").write_text(f"960,{value}\n")
    if checkpoint_frames is not None:
        torch.save({"state": {"collected_frames": checkpoint_frames}}, run_dir / "checkpoint.pt")
    for name, lines in files.items():
        (run_dir / f"{name}.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    return run_dir


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory):
    """The report of a synthetic sweep with known numbers (written once for the tests below)."""
    root = tmp_path_factory.mktemp("report")
    sweep = root / "sweep"
    sweep.mkdir()
    (sweep / "multirun.yaml").write_text(yaml.safe_dump({"hydra": {"sweeper": {"params": {"seed": "0,1,2"}}}}))
    for seed, final in enumerate([10.0, 20.0, 30.0]):
        make_run(sweep, "ppo", seed, final)
    make_run(sweep, "hdppo", 0, 25.0)
    make_run(sweep, "hdppo", 1, 35.0)
    make_run(sweep, "hdppo", 2, 1000.0, checkpoint_frames=400)  # killed at 400 frames: incomplete
    decisions = [
        {"frames": 200, "selector": "random", "applied": True, "rule_id": 3, "rule": "r3", "weights": [1, 1, 1]},
        {"frames": 400, "selector": "random", "applied": True, "rule_id": 3, "rule": "r3", "weights": [1, 1, 1]},
        {"frames": 600, "selector": "random", "applied": False, "rule_id": None, "rule": None, "weights": [1, 1, 1]},
    ]
    calls = [
        {"latency": 1.0, "tokens": {"prompt_tokens": 100, "completion_tokens": 10}, "cost": 0.5, "error": None},
        {"latency": 2.0, "tokens": {"prompt_tokens": 200, "completion_tokens": 20}, "cost": 0.25, "error": None},
        {"latency": 6.0, "tokens": {}, "cost": None, "error": "timeout"},
    ]
    make_run(
        sweep,
        "ahrs_r",
        0,
        -4.0,
        components=[("distance", -7.0), ("arrival", 2.0), ("ctrl", 1.0)],
        scheduler_decisions=decisions,
        llm_calls=calls,
    )
    make_run(sweep, "ahrs_r", 1, rows=[(100, 5.0), (800, 6.0)])  # finished, but no row after 900 frames
    # ahrs_r seed 2: no directory at all
    write_report(sweep, root / "report")
    return root / "report"


def read_csv(path):
    with open(path) as handle:
        return list(csv.DictReader(handle))


def test_table_values_match_hand_computation(report_dir):
    out = report_dir
    summary = {row["method"]: row for row in read_csv(out / "summary.csv")}
    ppo, hdppo = summary["ppo"], summary["hdppo"]
    assert float(ppo["mean"]) == pytest.approx(20.0)  # (10 + 20 + 30) / 3
    assert float(ppo["std"]) == pytest.approx(10.0)  # sqrt((100 + 0 + 100) / 2)
    assert float(ppo["iqm"]) == pytest.approx(20.0)  # n = 3 < 4: nothing trimmed
    assert float(ppo["change_vs_ppo_pct"]) == pytest.approx(0.0)
    # the incomplete seed (final 1000) must not enter the statistics
    assert (int(hdppo["seeds_ok"]), int(hdppo["seeds_not_ok"])) == (2, 1)
    assert float(hdppo["mean"]) == pytest.approx(30.0)
    assert float(hdppo["std"]) == pytest.approx(math.sqrt(50.0))  # sqrt((25 + 25) / 1)
    assert float(hdppo["change_vs_ppo_pct"]) == pytest.approx(50.0)  # (30 - 20) / 20
    assert float(summary["ahrs_r"]["mean"]) == pytest.approx(-4.0)
    assert float(summary["ahrs_r"]["change_vs_ppo_pct"]) == pytest.approx(-120.0)  # (-4 - 20) / 20
    assert 20.0 <= float(ppo["ci95_high"]) <= 30.0 and 10.0 <= float(ppo["ci95_low"]) <= 20.0
    markdown = (out / "report.md").read_text()
    assert "| point_reach | 20.00 ± 10.00 | 30.00 ± 7.07 (+50.0 %) [2 seeds] | -4.00 ± – (-120.0 %) [1 seeds] |" in (
        markdown
    )
    # the final reward per step: the same statistics of f / 100
    assert float(ppo["reward_per_step_mean"]) == pytest.approx(0.2)  # (0.1 + 0.2 + 0.3) / 3
    assert float(hdppo["reward_per_step_change_vs_ppo_pct"]) == pytest.approx(50.0)  # (0.3 - 0.2) / 0.2
    row = "| point_reach | 0.2000 ± 0.1000 | 0.3000 ± 0.0707 (+50.0 %) [2 seeds] | -0.0400 ± – (-120.0 %) [1 seeds] |"
    assert row in markdown


def test_failed_and_missing_seeds_are_listed(report_dir):
    out = report_dir
    status = {(row["method"], row["seed"]): row["status"] for row in read_csv(out / "runs.csv")}
    assert status == {
        ("ppo", "0"): "ok",
        ("ppo", "1"): "ok",
        ("ppo", "2"): "ok",
        ("hdppo", "0"): "ok",
        ("hdppo", "1"): "ok",
        ("hdppo", "2"): "incomplete",
        ("ahrs_r", "0"): "ok",
        ("ahrs_r", "1"): "too few metric rows",
        ("ahrs_r", "2"): "missing",
    }
    markdown = (out / "report.md").read_text()
    not_ok_section = markdown.split("## Runs not ok")[1].split("##")[0]
    assert "checkpoint at 400 of 1000 frames" in not_ok_section
    assert not_ok_section.count("| point_reach |") == 3


def test_components_rules_and_llm_summary(report_dir):
    out = report_dir
    components = {row["component"]: float(row["mean"]) for row in read_csv(out / "components.csv")}
    assert components == {"distance": -7.0, "arrival": 2.0, "ctrl": 1.0}
    rules = {row["rule"]: int(row["decisions"]) for row in read_csv(out / "rules.csv")}
    assert rules == {"r3": 2, "(no change)": 1}  # PPO's constant weights are not a schedule
    (llm,) = read_csv(out / "llm.csv")
    assert (int(llm["calls"]), int(llm["failures"])) == (3, 1)
    assert float(llm["latency_mean_s"]) == pytest.approx(3.0)  # (1 + 2 + 6) / 3
    assert (int(llm["prompt_tokens"]), int(llm["completion_tokens"])) == (300, 30)
    assert float(llm["cost_usd"]) == pytest.approx(0.75)
    for name in ("curves_point_reach.png", "weights_point_reach.png", "components_point_reach.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"


def test_statistics_on_hand_checkable_inputs():
    # resampling [0, 0, 3]: the mean is k = number of 3s drawn, P(k=0) = 8/27 > 2.5 %, P(k=3) = 1/27 > 2.5 %
    assert mean_interval(np.array([0.0, 0.0, 3.0])) == (1.0, 0.0, 3.0)
    iqm, low, high = iqm_interval(np.array([5.0, 1.0, 4.0, 2.0, 3.0, 100.0, -50.0, 7.0]))
    assert iqm == pytest.approx(3.5) and low <= 3.5 <= high  # (2+3+4+5)/4
    # P(X > Y) by hand: 3 x 3 pairs, X wins 8 and ties 1 (5 vs 5): (8 + 0.5) / 9
    p, low, high = improvement_probability(np.array([5.0, 6.0, 7.0]), np.array([1.0, 2.0, 5.0]))
    assert p == pytest.approx(8.5 / 9) and low <= p <= high <= 1.0
    p, low, high = improvement_probability(np.array([1.0, 2.0]), np.array([1.0, 2.0]))
    assert p == pytest.approx(0.5)  # an arm against itself: a coin
    assert change_percent(-50.0, -100.0) == pytest.approx(50.0)  # less negative return = better
    assert math.isnan(change_percent(1.0, 0.0))
    assert final_return(np.array([100, 899, 901]), np.array([7.0, 7.0, 3.0]), 1000) == 3.0
    assert math.isnan(final_return(np.array([100]), np.array([7.0]), 1000))


def test_sweep_presets_load():
    local = make_cfg("+sweep=paper", "task=quadcopter", hydra=True)
    assert local.hydra.launcher._target_.endswith("JoblibLauncher") and local.hydra.launcher.n_jobs == 2
    assert (local.trainer.torch_threads, local.task.num_threads, local.llm.name) == (1, 1, "offline")
    assert set(local.hydra.sweeper.params.method.split(",")) >= {"ppo", "hdppo", "ahrs_wo_a", "ahrs_r"}
    get_class(local.hydra.launcher._target_)  # the joblib plugin is installed
    slurm = make_cfg("+sweep=paper", "hydra/launcher=slurm", hydra=True)
    assert slurm.hydra.launcher._target_.endswith("SlurmLauncher")
    assert slurm.hydra.launcher.cpus_per_task == 4 and slurm.hydra.launcher.gpus_per_node == 0
    get_class(slurm.hydra.launcher._target_)  # the submitit plugin is installed
    smoke = make_cfg("+sweep=smoke", hydra=True)
    assert len(smoke.hydra.sweeper.params.seed.split(",")) == 2


def test_pooled_sweeps_expect_the_union_of_their_seeds(tmp_path):
    first, extension = tmp_path / "first", tmp_path / "extension"
    for sweep, seeds in ((first, "0,1"), (extension, "2,3")):
        sweep.mkdir()
        (sweep / "multirun.yaml").write_text(yaml.safe_dump({"hydra": {"sweeper": {"params": {"seed": seeds}}}}))
    make_run(first, "ppo", 0, 1.0)
    make_run(first, "ppo", 1, 3.0)
    make_run(extension, "ppo", 3, 5.0)  # seed 2 of the extension never ran
    tables = write_report([first, extension], tmp_path / "report")
    assert [(row["seed"], row["status"]) for row in tables["runs"]] == [(0, "ok"), (1, "ok"), (2, "missing"), (3, "ok")]
    (summary,) = tables["summary"]
    assert (summary["seeds_ok"], summary["mean"]) == (3, pytest.approx(3.0))  # (1 + 3 + 5) / 3
