"""The smoke sweep end to end: python -m torchrl_ahrs.sweep +sweep=smoke, then python -m torchrl_ahrs.report on it
(8 runs ok, every task x method summarised with a finite mean, the weights figure written)."""

import csv
import math
import subprocess
import sys

import pytest


def read_csv(path):
    with open(path) as handle:
        return list(csv.DictReader(handle))


@pytest.mark.slow
def test_smoke_sweep_and_report_end_to_end(tmp_path):
    sweep = tmp_path / "smoke"
    subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.sweep", "+sweep=smoke", f"hydra.sweep.dir={sweep}"],
        check=True,
        capture_output=True,
        timeout=300,
    )
    subprocess.run([sys.executable, "-m", "torchrl_ahrs.report", str(sweep)], check=True, timeout=120)
    runs = read_csv(sweep / "report" / "runs.csv")
    assert len(runs) == 8 and {row["status"] for row in runs} == {"ok"}
    summary = read_csv(sweep / "report" / "summary.csv")
    assert {(row["task"], row["method"]) for row in summary} == {
        (task, method) for task in ("point_reach", "quadcopter") for method in ("ppo", "ahrs_r")
    }
    assert all(math.isfinite(float(row["mean"])) for row in summary)
    assert (sweep / "report" / "weights_quadcopter.png").is_file()
