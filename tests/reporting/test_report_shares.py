"""Report additions of issue 13: share movement against seed noise, early-learning speed (oracles by hand)."""

import math

import numpy as np
import pytest

from torchrl_ahrs.reporting.records import Run
from torchrl_ahrs.reporting.stats import final_return
from torchrl_ahrs.reporting.tables import share_rows, summary_rows


def run(method, seed, returns, shares=None, decisions=()):
    steps = np.arange(1.0, len(returns) + 1) * 100
    curves = {"return/total": (steps, np.asarray(returns, float))}
    for name, values in (shares or {}).items():
        curves[f"share/{name}"] = (steps, np.asarray(values, float))
    logged = [{"selector": "bandit", "applied": True, "frames": f, "rule_id": 1} for f in decisions]
    final = {"return/total": final_return(steps, np.asarray(returns, float), steps[-1])}
    return Run(None, "t", method, seed, "ok", total_frames=int(steps[-1]), curves=curves, final=final, decisions=logged)


def test_share_movement_beats_noise_only_when_decisions_move_it():
    moving = [run("ahrs_wo_a", s, [0] * 8, {"a": [0.2] * 4 + [0.6] * 4}, decisions=[400.0]) for s in (0, 1)]
    noisy = [run("ahrs_r", s, [0] * 8, {"a": [0.2 + 0.1 * s] * 8}, decisions=[400.0]) for s in (0, 1)]
    rows = {row["method"]: row for row in share_rows(moving + noisy)}
    assert rows["ahrs_wo_a"]["movement"] == pytest.approx(0.4) and rows["ahrs_wo_a"]["seed_noise"] == 0.0
    assert rows["ahrs_wo_a"]["moves_beyond_noise"] is True
    assert rows["ahrs_r"]["movement"] == pytest.approx(0.0) and rows["ahrs_r"]["seed_noise"] == pytest.approx(0.05)
    assert rows["ahrs_r"]["moves_beyond_noise"] is False


def test_auc_and_frames_to_90_percent_of_ppo():
    # PPO: 0 -> 10 over 10 rows, plateau (final window = last row) 10; threshold = 0 + 0.9 * 10 = 9
    ppo = run("ppo", 0, [0, 1, 2, 3, 4, 5, 6, 7, 10, 10])
    fast = run("ahrs", 0, [0, 10, 10, 10, 10, 10, 10, 10, 10, 10])
    never = run("hdppo", 0, [0, 1, 1, 1, 1, 1, 1, 1, 1, 1])
    rows = {row["method"]: row for row in summary_rows([ppo, fast, never])}
    # trapezoids with a constant step: (sum of values - (first + last) / 2) / (rows - 1)
    assert rows["ppo"]["auc_mean"] == pytest.approx((48 - 5) / 9)
    assert rows["ahrs"]["auc_mean"] == pytest.approx((90 - 5) / 9)
    # running mean of 5 rows >= 9: ahrs first at row 6 ([10] * 5), ppo never (its last 5 rows average 7.6)
    assert rows["ahrs"]["frames_to_90pct_ppo"] == 600.0 and rows["ahrs"]["reached_90pct_ppo"] == "1/1"
    assert math.isnan(rows["ppo"]["frames_to_90pct_ppo"]) and rows["hdppo"]["reached_90pct_ppo"] == "0/1"
