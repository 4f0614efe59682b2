"""The benchmark scripts still run end to end (tiny arguments, no timing assertions)."""

import itertools
import json
import re
import runpy
import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def run_script(name: str, argv: list[str], monkeypatch, capsys) -> str:
    """Runs ``benchmarks/<name>`` (``<kind>/<script>.py``) as ``__main__`` in this process with ``argv``, its
    folder first on ``sys.path`` as when run as a script; returns its stdout."""
    script = BENCHMARKS / name
    monkeypatch.setattr(sys, "argv", [script.name, *argv])
    monkeypatch.syspath_prepend(str(script.parent))
    runpy.run_path(str(script), run_name="__main__")
    return capsys.readouterr().out


def test_bench_gae_prints_both_times_and_the_ratio(monkeypatch, capsys):
    out = run_script(
        "throughput/bench_gae.py",
        ["--sizes", "4x8", "--components", "3", "--hidden", "8", "--repeat", "2"],
        monkeypatch,
        capsys,
    )
    rows = [line for line in out.splitlines() if line.strip().startswith("4x8")]
    assert [row.split()[1] for row in rows] == ["with", "precomputed"]
    assert all(row.endswith("x") for row in rows)


def test_bench_gae_precomputed_values_give_the_same_advantage():
    sys.path.insert(0, str(BENCHMARKS / "throughput"))
    try:
        from bench_gae import make_batches
    finally:
        sys.path.remove(str(BENCHMARKS / "throughput"))
    import torch
    from tensordict.nn import TensorDictModule

    from torchrl_ahrs.value import MultiHeadCritic, WeightedMultiGAE

    multi, single, components = make_batches(3, 7, 4, 5)
    # the one-reward batch carries the sum of the component rewards (what TorchRL's GAE would see)
    stacked = torch.cat([multi["next", "reward", name] for name in components], -1)
    torch.testing.assert_close(single["next", "reward"], stacked.sum(-1, keepdim=True))
    critic = TensorDictModule(MultiHeadCritic(5, 4, [8]), in_keys=["observation"], out_keys=["state_value"])
    with_critic = WeightedMultiGAE(components, gamma=0.9, lmbda=0.8, value_network=critic)(multi)["advantage"].clone()
    precomputed = WeightedMultiGAE(components, gamma=0.9, lmbda=0.8, value_network=None)(multi)["advantage"]
    torch.testing.assert_close(precomputed, with_critic)


def test_frames_per_second_counts_whole_iterations_after_warmup():
    sys.path.insert(0, str(BENCHMARKS / "throughput"))
    try:
        from bench_pipeline import frames_per_second
    finally:
        sys.path.remove(str(BENCHMARKS / "throughput"))
    # batches delivered at t = 0, 10 (slow warm-up), 11, 12, 13: three 1 s iterations of 50 frames
    assert frames_per_second([0.0, 10.0, 11.0, 12.0, 13.0], frames_per_batch=50, warmup=1) == 50.0
    with pytest.raises(ValueError):
        frames_per_second([0.0, 1.0], frames_per_batch=50, warmup=1)


@pytest.mark.slow
def test_bench_pipeline_runs_ours_and_the_reference(monkeypatch, capsys):
    pytest.importorskip("gymnasium.envs.mujoco")
    argv = ["--frames", "16", "--num-envs", "2", "--rollout-steps", "8", "--hidden", "8", "--epochs", "1"]
    argv += ["--minibatches", "2", "--ref-workers", "2", "--methods", "ppo", "--threads", "1"]
    out = run_script("throughput/bench_pipeline.py", argv, monkeypatch, capsys)
    assert "reference (TorchRL sota PPO" in out
    assert "ratio ours/reference" in out


def table_rows(table: str) -> dict[str, float]:
    """A bench_floor table's rows as {part: ms per batch}."""
    lines = table.splitlines()
    rows = lines[lines.index(next(line for line in lines if line.strip().startswith("part (median"))) + 1 :]
    rows = rows[: next(i for i, line in enumerate(rows) if "end-to-end CPU time" in line)]
    return {line[:44].strip(): float(line[44:].split()[0]) for line in rows}


def run_tiny_bench_floor(task: str, overrides: list[str], monkeypatch, capsys) -> tuple[dict[str, float], str]:
    """bench_floor on three timed batches of 2 envs x 8 steps, 2 minibatches, an [8] network: its rows as
    {part: ms}, and its output."""
    argv = ["--task", task, "--batches", "3", "--warmup", "1", "trainer.num_envs=2"]
    argv += [
        "trainer.frames_per_batch=16",
        "trainer.mini_batch_size=8",
        "trainer.num_epochs=1",
        "model.hidden_sizes=[8]",
    ]
    out = run_script("throughput/bench_floor.py", [*argv, *overrides], monkeypatch, capsys)
    return table_rows(out), out


def test_bench_floor_splits_end_to_end_into_its_measured_parts(monkeypatch, capsys):
    ms, out = run_tiny_bench_floor("ant_v5", [], monkeypatch, capsys)
    parts = ["collection (Collector, policy acting)", "advantages (x 1 epochs)", "loss steps (x 2)"]
    # the rows add up: end to end = collection + advantages + loss steps + rest
    total = sum(ms[name] for name in parts) + ms["rest (hooks, minibatches, logging)"]
    assert ms["end to end (train)"] == pytest.approx(total, abs=0.3)
    assert all(value > 0 for name, value in ms.items() if not name.startswith("rest"))
    # the floor is timed beside each of the three timed iterations: one share each, and their mean with its interval
    shares = [float(share.rstrip("%")) for share in out.split("each timed iteration:")[1].splitlines()[0].split()]
    assert len(shares) == 3
    mean, low, high = (float(x) for x in re.findall(r"(\d+)%", out.split("of floor over the iterations:")[1]))
    assert mean == pytest.approx(sum(shares) / 3, abs=1.0) and min(shares) - 1 <= low <= mean <= high <= max(shares) + 1


def test_timed_collector_keeps_the_work_beside_it_off_the_clock():
    sys.path.insert(0, str(BENCHMARKS / "throughput"))
    try:
        from bench_pipeline import TimedCollector
    finally:
        sys.path.remove(str(BENCHMARKS / "throughput"))
    import time

    seen = []

    def beside(batch):  # 0.3 s beside each batch, which the stamps must leave out
        seen.append(batch)
        time.sleep(0.3)

    timed = TimedCollector(range(4), beside)
    assert list(timed) == [0, 1, 2, 3] and seen == [0, 1, 2, 3]  # every batch passes through, beside saw each
    walls = [wall for wall, _ in timed.stamps]
    # with the 0.3 s counted, consecutive stamps would lie at least 0.3 s apart; nothing else here takes time
    assert all(later - earlier < 0.3 for earlier, later in itertools.pairwise(walls))


def test_bench_floor_times_the_mirrored_minibatch_when_the_run_mirrors(monkeypatch, capsys):
    ms, _ = run_tiny_bench_floor("cassie", ["ppo.mirror=true"], monkeypatch, capsys)
    # the loss floor is what the run's loss trains on: each minibatch and its mirror image
    assert "loss steps (x 2, mirrored)" in ms


def test_bench_floor_measures_variants_side_by_side_in_one_process(monkeypatch, capsys):
    argv = ["--task", "ant_v5", "--batches", "1", "--warmup", "1", "--variants", "default,once"]
    argv += ["trainer.num_envs=2", "trainer.frames_per_batch=16", "trainer.mini_batch_size=8", "trainer.num_epochs=2"]
    argv += ["ppo.advantage_pass=every_epoch"]  # ant_v5's preset passes once per batch; the variant's override wins
    out = run_script("throughput/bench_floor.py", [*argv, "model.hidden_sizes=[8]"], monkeypatch, capsys)
    headers = [line for line in out.splitlines() if line.startswith("task ant_v5")]
    assert [header.split(":")[0] for header in headers] == [
        "task ant_v5, method ppo, variant default (no overrides)",
        "task ant_v5, method ppo, variant once (ppo.advantage_pass=once_per_batch)",
    ]
    tables = out.split("task ant_v5")[1:]
    assert "advantages (x 2 epochs)" in tables[0] and "advantages (x 1 pass)" in tables[1]  # the estimator's passes
    summary = out.split("variants side by side")[1].splitlines()[2:]
    assert [row.split()[0] for row in summary] == ["default", "once"]
    assert all(row.endswith("%") for row in summary)
    # speed against the first, each paced by its own metronome: the first against itself is 1
    assert summary[0].split()[6] == "1.00x" and summary[1].split()[6].endswith("x")


def test_bench_floor_runs_a_variant_several_times_and_summarises_the_medians(monkeypatch, capsys):
    argv = ["--task", "ant_v5", "--batches", "1", "--warmup", "1", "--runs", "3"]
    argv += ["trainer.num_envs=2", "trainer.frames_per_batch=16", "trainer.mini_batch_size=8", "trainer.num_epochs=1"]
    out = run_script("throughput/bench_floor.py", [*argv, "model.hidden_sizes=[8]"], monkeypatch, capsys)
    tables = out.split("task ant_v5")[1:]
    assert len(tables) == 3  # one table per run
    # each run's share: the mean of its iterations' (one timed iteration here)
    means = [float(table.split("of floor over the iterations: mean ")[1].split("%")[0]) for table in tables]
    row, interval = out.split("variants side by side")[1].splitlines()[2:]
    shares = [float(share.rstrip("%")) for share in row.split()[-3:]]
    assert shares == pytest.approx(means, abs=1.0)  # the runs' own shares, rounded
    assert float(row.split()[4].rstrip("%")) == pytest.approx(sorted(shares)[1], abs=1.0)  # their median
    mean, low, high = (float(x) for x in re.findall(r"(\d+)%", interval))  # from three runs: the mean and its interval
    assert interval.startswith("  default: of floor, mean over runs")
    assert mean == pytest.approx(sum(means) / 3, abs=1.0) and min(shares) - 1 <= low <= mean <= high <= max(shares) + 1


def test_bench_precision_times_every_split_of_actor_and_critic_precision(monkeypatch, capsys):
    argv = ["--task", "cassie", "--method", "ahrs", "--rounds", "1", "trainer.num_envs=2"]
    argv += ["trainer.frames_per_batch=16"]
    argv += ["trainer.mini_batch_size=8", "trainer.num_epochs=1", "model.hidden_sizes=[8]", "ppo.mirror=true"]
    out = run_script("throughput/bench_precision.py", argv, monkeypatch, capsys)
    rows = {line[:18].strip(): line[18:].split() for line in out.splitlines()[2:]}
    assert list(rows) == ["float32", "critic bf16", "actor bf16", "both bf16"]
    assert rows["float32"][1::2] == ["1.00"] * 4  # float32 against itself: loss steps, advantages, acting, sum
    for cells in rows.values():  # the sum column is the sum of the three parts
        assert float(cells[6]) == pytest.approx(sum(float(ms) for ms in cells[0:6:2]), abs=0.2)
    assert "2 minibatches of 8 mirrored" in out.splitlines()[0]


def test_bench_floor_refuses_an_unknown_variant_before_measuring(monkeypatch, capsys):
    with pytest.raises(SystemExit) as stop:
        run_script(
            "throughput/bench_floor.py", ["--task", "ant_v5", "--variants", "default,turbo"], monkeypatch, capsys
        )
    assert stop.value.code == 2
    assert "unknown variant 'turbo'; known: default, once, compile, threads1, threads2" in capsys.readouterr().err


def test_bench_env_throughput_runs(monkeypatch, capsys):
    argv = ["--num-envs", "2", "--steps", "4", "--threads", "1", "--rounds", "1", "--tasks", "ant"]
    out = run_script("throughput/bench_env_throughput.py", argv, monkeypatch, capsys)
    assert "ratio ours / EnvPool" in out and "task ant" in out


def test_bench_envpool_tasks_runs(monkeypatch, capsys):
    out = run_script(
        "throughput/bench_envpool_tasks.py",
        ["--tasks", "ant_v5", "--num-envs", "2", "--steps", "8"],
        monkeypatch,
        capsys,
    )
    assert out.splitlines()[-1].split()[0] == "ant_v5"


def test_bench_minibatch_overhead_prints_every_measurement(monkeypatch, capsys):
    out = run_script(
        "throughput/bench_minibatch_overhead.py", ["--minibatch", "512", "--steps", "2"], monkeypatch, capsys
    )
    for name in ("loss_step functional=True", "loss_step functional=False", "serve_all_keys", "serve_loss_keys"):
        assert name in out


def test_record_learning_run_writes_curve_evaluation_and_config(tmp_path, monkeypatch):
    sys.path.insert(0, str(BENCHMARKS / "learning"))
    try:
        import record_learning_run
    finally:
        sys.path.remove(str(BENCHMARKS / "learning"))
    run = tmp_path / "run"
    scalars = run / "metrics" / "scalars"
    (scalars / "return").mkdir(parents=True)
    (scalars / "reward").mkdir()
    (scalars / "return" / "total.csv").write_text("2048,-5.0\n6144,12.5\n")  # no episode ended at 4096
    (scalars / "reward" / "total.csv").write_text("2048,0.1\n4096,0.2\n6144,0.3\n")
    (run / "evaluation.json").write_text('{"return": 1}')
    (run / "config.yaml").write_text("seed: 0\n")
    monkeypatch.setattr(record_learning_run, "RESULTS", tmp_path / "results")
    out = record_learning_run.record(run, "demo", note="wall 1 s")
    rows = (out / "curve.csv").read_text().splitlines()
    assert rows[0].startswith("frames,return_total,reward_per_step")
    assert rows[1:] == ["2048,-5.0,0.1,,", "4096,,0.2,,", "6144,12.5,0.3,,"]
    assert (out / "evaluation.json").read_text() == '{"return": 1}'
    assert "wall 1 s" in (out / "timing.txt").read_text()
    assert not (out / "checkpoint.pt").exists()
    (run / "checkpoint.pt").write_bytes(b"state")
    walk = record_learning_run.record(run, "demo", out=tmp_path / "walk", checkpoint=True)
    assert walk == tmp_path / "walk" and (walk / "checkpoint.pt").read_bytes() == b"state"
    assert (walk / "curve.csv").read_text() == (out / "curve.csv").read_text()


def test_bench_mjx_runs(monkeypatch, capsys):
    pytest.importorskip("mujoco.mjx", reason='JAX / mujoco-mjx absent: pip install -e ".[mjx]" runs this test')
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")
    argv = ["--task", "quadcopter", "--num-envs", "2", "--steps", "2", "--threads", "1"]
    rows = [
        line
        for line in run_script("throughput/bench_mjx.py", argv, monkeypatch, capsys).splitlines()
        if line.startswith("| 2 ")
    ]
    assert [row.split("|")[2].strip() for row in rows] == ["cpu", "mjx"]


def test_curve_bins_bins_each_batch_where_its_frames_start_and_counts_episodes_over_all_batches(
    tmp_path, monkeypatch, capsys
):
    """Oracle: hand-written CSVs, rows logged at the frames after each batch. The batches ending at 100, 200
    and 1000 frames start at 0, 100 and 200, so bin [0, 1000) holds all three (reward 2e-3, 4e-3, 6e-3: mean
    4e-3; four episodes ended: 4/3 per batch); the batch ending at 1100 starts bin [1000, 2000) (8e-3, none)."""
    scalars = tmp_path / "run" / "metrics" / "scalars"
    (scalars / "reward").mkdir(parents=True)
    (scalars / "reward" / "tracking_lin_vel.csv").write_text(
        "step,value\n100,0.002\n200,0.004\n1000,0.006\n1100,0.008\n"
    )
    (scalars / "episodes.csv").write_text("step,value\n200,1.0\n1000,3.0\n")
    out = run_script("learning/curve_bins.py", [str(tmp_path / "run"), "--bin", "1000"], monkeypatch, capsys)
    assert out.strip() == "run: 0-0.001M:  4.00 eps/batch  1.3 | 0.001-0.002M:  8.00 eps/batch  0.0"


def test_curve_bins_scalar_bins_any_logged_scalar_as_logged(tmp_path, monkeypatch, capsys):
    """Oracle: the same hand-written layout with a train/entropy scalar: bin [0, 1000) holds 2.0, 3.0 and 4.0
    (mean 3.00, not scaled as rewards are), bin [1000, 2000) holds 1.5."""
    scalars = tmp_path / "run" / "metrics" / "scalars"
    (scalars / "train").mkdir(parents=True)
    (scalars / "train" / "entropy.csv").write_text("step,value\n100,2.0\n200,3.0\n1000,4.0\n1100,1.5\n")
    (scalars / "episodes.csv").write_text("step,value\n200,1.0\n")
    argv = [str(tmp_path / "run"), "--bin", "1000", "--scalar", "train/entropy"]
    out = run_script("learning/curve_bins.py", argv, monkeypatch, capsys)
    assert out.strip() == "run: 0-0.001M:  3.00 eps/batch  0.3 | 0.001-0.002M:  1.50 eps/batch  0.0"
    out = run_script("learning/curve_bins.py", [str(tmp_path / "run")], monkeypatch, capsys)  # no reward terms
    assert out.strip() == "run: no metrics/scalars/reward/tracking_lin_vel.csv"


def write_evaluated_run(run_dir: Path, seed: int, error: float, lengths: list[int], total: float = 0.0) -> None:
    """A run directory as training and `torchrl_ahrs.evaluate` leave it: config.yaml, evaluation.json and the
    reward/total scalars (two batches of 1 000 frames: `total` per step in the second, 0 in the first)."""
    (run_dir / "metrics" / "scalars" / "reward").mkdir(parents=True)
    (run_dir / "metrics" / "scalars" / "reward" / "total.csv").write_text(f"step,value\n1000,0.0\n2000,{total}\n")
    (run_dir / "config.yaml").write_text(f"seed: {seed}\ntrainer:\n  total_frames: 100\n")
    stats = {"mean": 2.0, "std": 0.0, "min": 2.0, "max": 2.0}
    evaluation = {
        "metrics": {"lin_vel_error": {**stats, "mean": error}},
        "return": {"tracking_lin_vel": {**stats, "mean": 10.0 * seed}, "total": stats},
        "per_episode": {"length": lengths, "return": [2.0] * len(lengths)},
    }
    (run_dir / "evaluation.json").write_text(json.dumps(evaluation))


def test_compare_evaluations_prints_seeds_arm_intervals_and_the_probability_of_improvement(
    tmp_path, monkeypatch, capsys
):
    """Oracle: every error of arm a (0.1, 0.2) is below every error of arm b (0.3, 0.5), so with
    --lower-is-better P(a better than b) = 1 whatever the bootstrap draws; the means are 0.15 and 0.4; b's seed 2
    has a 700-step episode (a fall), so three runs meet the bar of 0.35: both of a's and b's seed 1. The training
    total of the last 1 000-frame bin is the second batch's reward per step x 1 000, and every run of b collects
    more than every run of a there: P(a better) = 0 in it."""
    for arm, seed, error, lengths, total in [
        ("a", 1, 0.1, [1000, 1000], 0.001), ("a", 2, 0.2, [1000, 1000], 0.002),
        ("b", 1, 0.3, [1000, 1000], 0.003), ("b", 2, 0.5, [1000, 700], 0.004),
    ]:  # fmt: skip
        write_evaluated_run(tmp_path / f"{arm}_s{seed}", seed, error, lengths, total)
    argv = ["--lower-is-better", "--bar", "0.35", "--terms", "tracking_lin_vel", "--bin", "1000"]
    argv += ["--stuck", "tracking_lin_vel=15"]  # seed 1 of each arm collects 10 of it, seed 2 collects 20
    argv += ["--arm", f"a={tmp_path}/a_s1,{tmp_path}/a_s2", "--arm", f"b={tmp_path}/b_s*"]  # two globs, one glob
    out = run_script("learning/compare_evaluations.py", argv, monkeypatch, capsys)
    rows = [line.split() for line in out.splitlines() if line.startswith(("a ", "b ")) and "mean" not in line]
    assert rows == [
        ["a", "1", "0.100", "2", "of", "2", "1.00", "10.00"], ["a", "2", "0.200", "2", "of", "2", "2.00", "20.00"],
        ["b", "1", "0.300", "2", "of", "2", "3.00", "10.00"], ["b", "2", "0.500", "1", "of", "2", "4.00", "20.00"],
    ]  # fmt: skip
    assert "a            mean 0.150 [" in out and "over 2 seeds; 0 fall; 2 meet the bar" in out
    assert "b            mean 0.400 [" in out and "over 2 seeds; 1 fall; 1 meet the bar" in out
    assert out.count("; 1 stuck (tracking_lin_vel below 15)") == 2
    assert "training total, last bin: 1.50 [" in out and "training total, last bin: 3.50 [" in out
    assert "P(a better than b) = 1.00 [1.00, 1.00] in lin_vel_error, 0.00 [0.00, 0.00] in the training total" in out


def test_compare_evaluations_refuses_an_arm_that_matches_nothing_in_one_line(tmp_path, monkeypatch, capsys):
    with pytest.raises(SystemExit, match=r"arm 'a': .* matches no directory"):
        run_script("learning/compare_evaluations.py", ["--arm", f"a={tmp_path},{tmp_path}/none_*"], monkeypatch, capsys)


def test_compare_evaluations_refuses_a_malformed_or_unknown_stuck_term_in_one_line(tmp_path, monkeypatch, capsys):
    write_evaluated_run(tmp_path / "a_s1", 1, 0.1, [1000], 0.001)
    arm = ["--arm", f"a={tmp_path}/a_s1"]
    with pytest.raises(SystemExit, match=r"--stuck takes term=value, .* got 'tracking_lin_vel'"):
        run_script("learning/compare_evaluations.py", ["--stuck", "tracking_lin_vel", *arm], monkeypatch, capsys)
    with pytest.raises(SystemExit, match=r"has no evaluated return 'no_such_term' \(--stuck\)"):
        run_script("learning/compare_evaluations.py", ["--stuck", "no_such_term=8", *arm], monkeypatch, capsys)


def test_run_seeds_trains_evaluates_at_both_seeds_and_skips_what_is_done(tmp_path):
    script = BENCHMARKS / "learning" / "run_seeds.sh"
    overrides = "task=quadcopter method=ppo trainer.total_frames=128 trainer.num_envs=4 trainer.frames_per_batch=128"
    command = [
        str(script),
        "--eval",
        "episodes=2",  # the evaluation overrides reach both evaluations
        str(tmp_path),
        "tiny",
        f"{overrides} trainer.mini_batch_size=64 model.hidden_sizes=[8]",
        "3",
    ]
    subprocess.run(command, check=True, cwd=BENCHMARKS.parent)
    run = tmp_path / "tiny_s3"
    evaluations = [json.loads((run / name).read_text()) for name in ("evaluation.json", "evaluation_seed2027.json")]
    assert [evaluation["seed"] for evaluation in evaluations] == [12345, 2027]
    assert [len(evaluation["per_episode"]["length"]) for evaluation in evaluations] == [2, 2]
    assert (run / "finished.json").exists() and "seed: 3" in (run / "config.yaml").read_text()
    stamps = {path: path.stat().st_mtime_ns for path in run.rglob("*")}
    subprocess.run(command, check=True, cwd=BENCHMARKS.parent)  # done: nothing is trained or evaluated again
    assert {path: path.stat().st_mtime_ns for path in run.rglob("*")} == stamps


def test_run_seeds_refuses_missing_arguments_with_its_usage():
    done = subprocess.run([str(BENCHMARKS / "learning" / "run_seeds.sh"), "a", "b"], capture_output=True, text=True)
    assert done.returncode == 2 and done.stderr.startswith("usage: ")
