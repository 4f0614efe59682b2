"""``benchmarks/learning/learning.py`` (return per minute, side by side with peers): its bookkeeping against hand-computed
values, the rsl_rl adapter against the env it wraps, and one tiny end-to-end run."""

from __future__ import annotations

import csv
import importlib.util
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch

LEARNING = Path(__file__).resolve().parents[2] / "benchmarks" / "learning"


@pytest.fixture(scope="module")
def learning():
    sys.path.insert(0, str(LEARNING))
    try:
        import learning as module
    finally:
        sys.path.remove(str(LEARNING))
    return module


def test_smoothed_return_is_the_episode_weighted_mean_over_the_window(learning):
    curve = [(1.0, 100, 10.0, 1), (2.0, 200, math.nan, 0), (3.0, 300, 40.0, 3), (4.0, 400, 0.0, 1)]
    values = learning.smoothed(curve, window_frames=250)
    # rows 1-2: only the first episode; row 3: (10 + 3 * 40) / 4; row 4 drops frame 100: (3 * 40 + 0) / 4
    assert values[:1] == [10.0] and values[1] == 10.0
    assert values[2] == pytest.approx(32.5) and values[3] == pytest.approx(30.0)
    assert math.isnan(learning.smoothed([(1.0, 100, math.nan, 0)], 250)[0])


def test_time_to_threshold_is_the_first_row_reaching_it(learning):
    curve = [(1.0, 100, 0.0, 1), (2.0, 200, 0.0, 1), (3.0, 300, 0.0, 1)]
    assert learning.time_to(curve, [5.0, 12.0, 8.0], 10.0) == (2.0, 200)
    assert learning.time_to(curve, [5.0, 12.0, 8.0], 12.5) is None


def test_contrasts_give_means_with_intervals_the_probability_of_improvement_and_the_frame_rate_ratio(learning):
    def run(peer, seed, ret, error, frames):
        evaluation = {"return": {"total": {"mean": ret, "std": 0.0}}, "metrics": {"lin_vel_error": {"mean": error}}}
        return learning.Run(peer, seed, evaluation=evaluation, trained_frames=frames, wall_s=100.0)

    # ours scores above rsl_rl on every seed and has the lower error on every seed: P = 1 with interval [1, 1]
    runs = [run("ours", s, 20.0 + s, 0.2, 200_000) for s in (1, 2, 3)]
    runs += [run("rsl_rl", s, 5.0 + s, 0.9, 100_000) for s in (1, 2, 3)]
    args = learning.argparse.Namespace(peers=["ours", "rsl_rl"])
    text = learning.contrasts(runs, ["lin_vel_error"], args, reps=500)  # 500 resamples: 4 s, not 13
    # the bootstrap interval's ends on 3 seeds sit at a percentile edge (each extreme has 1/27 of the resamples),
    # so they are checked for what a percentile interval of the mean guarantees, not for rliable's exact draw
    line = next(line for line in text.splitlines() if line.startswith("- return:"))
    assert line.endswith("; P(ours above rsl_rl) = 1 [1, 1]"), text
    ours_part, peer_part = line.removeprefix("- return: ours ").split("; P(")[0].split(", rsl_rl ")
    for part, (low_bound, mean, high_bound) in ((ours_part, (21, 22, 23)), (peer_part, (6, 7, 8))):
        point, low, high = (float(x) for x in part.replace("[", "").replace("]", "").replace(",", "").split())
        assert point == mean and low_bound <= low < mean < high <= high_bound, line
    assert "- lin_vel_error: ours 0.2 [0.2, 0.2], rsl_rl 0.9 [0.9, 0.9]; P(ours below rsl_rl) = 1 [1, 1]" in text
    assert "ours 2 000, rsl_rl 1 000 (ratio 2.00)" in text  # 200 000 / 100 s against 100 000 / 100 s
    assert learning.contrasts(runs[3:], ["lin_vel_error"], learning.argparse.Namespace(peers=["rsl_rl"])) == ""


def test_read_table_refuses_a_row_of_the_wrong_width(learning, tmp_path):
    path = tmp_path / "table.md"
    path.write_text("| peer | seeds |\n|---|---|\n| ours | 1 of 1 |\n")
    assert learning.read_table(path) == [{"peer": "ours", "seeds": "1 of 1"}]
    path.write_text("| peer | seeds |\n|---|---|\n| ours | 1 of 1 | extra |\n")
    with pytest.raises(ValueError, match="3 cells, header 2"):
        learning.read_table(path)


def test_rsl_rl_adapter_reports_auto_reset_observations_time_outs_and_episode_returns():
    pytest.importorskip("rsl_rl")
    sys.path.insert(0, str(LEARNING))
    try:
        from rsl_rl_adapter import RslRlVecEnv, StopTraining
    finally:
        sys.path.remove(str(LEARNING))
    from torchrl_ahrs.app.shared.settings import load_task_settings
    from torchrl_ahrs.envs.registry import make_env

    rollouts = []
    env = make_env(load_task_settings("point_reach"), 3, seed=0, components=["total"])
    vec = RslRlVecEnv(env, steps_per_rollout=50, on_rollout=lambda wall, frames, r: rollouts.append((frames, r)))
    # the oracle: the same env stepped by hand, with the same actions
    oracle = make_env(load_task_settings("point_reach"), 3, seed=0, components=["total"])
    td = oracle.reset()
    torch.testing.assert_close(vec.get_observations()["policy"], td["observation"].float())
    generator = torch.Generator().manual_seed(0)
    total = torch.zeros(3)
    for step in range(vec.max_episode_length):
        action = torch.rand(3, vec.num_actions, generator=generator) * 2 - 1
        obs, reward, dones, extras = vec.step(action)
        stepped, td = oracle.step_and_maybe_reset(td.set("action", action))
        total += stepped["next", "reward", "total"].reshape(3)
        torch.testing.assert_close(obs["policy"], td["observation"].float())  # after the reset of ended envs
        torch.testing.assert_close(reward, stepped["next", "reward", "total"].reshape(3).float())
        last = step == vec.max_episode_length - 1
        assert dones.tolist() == [int(last)] * 3  # point_reach only ends by its time limit
        assert extras["time_outs"].tolist() == [float(last)] * 3
    assert [frames for frames, _ in rollouts] == [150 * (i + 1) for i in range(vec.max_episode_length // 50)]
    torch.testing.assert_close(torch.tensor(rollouts[-1][1]), total)  # the returns of the episodes that ended
    assert vec.episode_length_buf.tolist() == [0, 0, 0]
    vec.should_stop = lambda: True
    with pytest.raises(StopTraining):
        vec.step(torch.zeros(3, vec.num_actions))


@pytest.mark.slow
def test_learning_runs_ours_and_sb3_end_to_end_writes_a_table_that_parses_and_reuses_finished_runs(learning, tmp_path):
    # one 2 048-frame iteration per peer (frame cap), 30 s budget each, two at once; sb3 is skipped when not installed.
    # The preset's compile (10-40 s at the first minibatch, by the load) would spend the budget before that iteration
    command = [sys.executable, str(LEARNING / "learning.py"), "--task", "ant_v5", "--minutes", "0.5", "--seeds", "1"]
    command += ["--peers", "ours", "sb3", "--frames", "2048", "--out", str(tmp_path), "--lanes", "2"]
    overrides = ["--ours-overrides", "trainer.lr=0.0005", "trainer.compile=false"]
    result = subprocess.run(command + overrides, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "trainer.lr=0.0005" in (tmp_path / "runs" / "ours_seed1" / ".hydra" / "overrides.yaml").read_text()
    assert "ours with `trainer.lr=0.0005 trainer.compile=false`" in (tmp_path / "table.md").read_text()
    table = (tmp_path / "table.md").read_text()
    again = subprocess.run(command + overrides, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0 and "ours seed 1: reused" in again.stdout, again.stdout + again.stderr
    assert (tmp_path / "table.md").read_text() == table  # the same runs, read back from run.json
    changed = subprocess.run(command, capture_output=True, text=True, timeout=120)  # without the override
    assert changed.returncode != 0 and "use another --out" in changed.stderr, changed.stdout + changed.stderr
    for name in ("curves.csv", "summary.csv", "table.md", "return_vs_time.png", "return_vs_frames.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert (tmp_path / "return_vs_time.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = {row["peer"]: row for row in learning.read_table(tmp_path / "table.md")}
    assert list(rows) == ["ours", "sb3"]
    assert rows["ours"]["seeds"] == "1 of 1" and rows["ours"]["frames trained"] == "2 048"
    float(rows["ours"]["evaluated return"].split(" ± ")[0].replace(" ", ""))
    if importlib.util.find_spec("stable_baselines3") is None:
        assert rows["sb3"]["seeds"] == "skipped: stable_baselines3 not installed"
    else:
        assert rows["sb3"]["seeds"] == "1 of 1" and rows["sb3"]["frames trained"] == "2 048"
    with (tmp_path / "summary.csv").open() as handle:
        summary = list(csv.DictReader(handle))
    assert {row["peer"] for row in summary} <= {"ours", "sb3"} and all(row["status"] == "ok" for row in summary)
    for row in summary:
        assert len(row["load_start"].split()) == 3 and len(row["load_end"].split()) == 3  # os.getloadavg()
        assert math.isfinite(float(row["eval_return"])) and row["stop"] == "frames"


def test_the_torchrl_peer_observes_what_our_ant_env_observes_and_a_mismatch_is_refused_before_training():
    pytest.importorskip("gymnasium")
    sys.path.insert(0, str(LEARNING))
    try:
        from learning_peers import require_our_observation
        from reference_ppo import make_gym_env, ours_gymnasium_kwargs
    finally:
        sys.path.remove(str(LEARNING))
    ours_kind, default = make_gym_env("Ant-v5", ours_gymnasium_kwargs("ant_v5")), make_gym_env("Ant-v5")
    sizes = [env.observation_spec["observation"].shape[-1] for env in (ours_kind, default)]
    assert sizes == [27, 105]  # gymnasium Ant-v5 without and with the contact forces
    require_our_observation("ant_v5", sizes[0])  # our preset's 27 entries: accepted
    with pytest.raises(SystemExit, match="observes 105 entries, our ant_v5 env 27"):
        require_our_observation("ant_v5", sizes[1])
    with pytest.raises(ValueError, match="mirrors task ant_v5, not 'cassie'"):
        ours_gymnasium_kwargs("cassie")


def test_the_rsl_rl_mirror_peer_trains_every_minibatch_with_its_mirror_image_in_bfloat16(tmp_path, monkeypatch):
    """One rsl-rl-lib iteration of the context peer on Cassie: rsl_rl's own symmetry extension is fed our task's
    mirror maps (oracle: applying the map's image again gives back the minibatch), every minibatch of 384 rows comes
    back as 768, and the runner's PPO runs under its bfloat16 autocast."""
    pytest.importorskip("rsl_rl")
    sys.path.insert(0, str(LEARNING))
    try:
        import learning_peers
        import rsl_rl_adapter
    finally:
        sys.path.remove(str(LEARNING))
    from rsl_rl.algorithms import PPO

    from torchrl_ahrs.app.shared.settings import load_task_settings
    from torchrl_ahrs.envs.registry import task_mirror

    maps = task_mirror(load_task_settings("cassie"))
    rows: list[tuple[int, int]] = []
    built = rsl_rl_adapter.mirror_augmentation

    def checked(task_maps):
        augment = built(task_maps)

        def run(env=None, obs=None, actions=None):
            out_obs, out_actions = augment(env=env, obs=obs, actions=actions)
            if obs is not None:
                originals, images = out_obs["policy"].split(obs.batch_size[0])
                assert torch.equal(originals, obs["policy"])
                assert torch.equal(maps["observation"](images), obs["policy"])  # a mirror is its own inverse
                rows.append((obs.batch_size[0], out_obs.batch_size[0]))
            return out_obs, out_actions

        return run

    monkeypatch.setattr(rsl_rl_adapter, "mirror_augmentation", checked)
    precisions = []
    update = PPO.update

    def recorded(self):
        precisions.append(self.use_mixed_precision)
        return update(self)

    monkeypatch.setattr(PPO, "update", recorded)
    budget = learning_peers.Budget(t0=learning_peers.time.time(), seconds=600.0, frames=64 * 24)
    curve = learning_peers.CurveWriter(tmp_path / "curve.csv")
    _, info = learning_peers.PEERS["rsl_rl_mirror"]("cassie", 0, budget, curve)
    assert info["trained_frames"] == 64 * 24 and info["settings"]["algorithm"]["use_mixed_precision"] is True
    assert rows == [(384, 768)] * (5 * 4)  # 5 epochs x 4 minibatches, each followed by its image
    assert precisions == [True]
