"""Return per minute, side by side: ours and peer PPO implementations, same wall-clock budget, same machine.

Full comparisons (to be run; about ``minutes x seeds x peers`` of wall time plus evaluation)::

    nice -n 10 python benchmarks/learning/learning.py --task ant_v5 --minutes 10 --seeds 1 2 \\
        --peers ours torchrl sb3 --out benchmarks/results/learning_peers/ant_v5
    nice -n 10 python benchmarks/learning/learning.py --task cassie --minutes 20 --seeds 1 2 \\
        --peers ours rsl_rl --out benchmarks/results/learning_peers/cassie

Peers (``pip install -e ".[bench]"``; a peer whose package is absent is skipped, and says so):

* ``ours``: ``python -m torchrl_ahrs.train task=<task> method=ppo seed=<s>`` with the task's preset
  (``conf/preset/<task>.yaml``), run as a subprocess with ``hydra.run.dir`` inside ``--out`` and
  ``checkpoint.interval=1`` so that the policy of the last finished iteration is on disk when the budget
  ends the process (SIGTERM); evaluated by ``python -m torchrl_ahrs.evaluate run=<dir>``.
* ``torchrl``: TorchRL's ``sota-implementations/ppo`` MuJoCo settings on gymnasium's Ant-v5
  (``reference_ppo.py``); ``sb3``: stable-baselines3 PPO with rl-baselines3-zoo's Ant settings and
  ``VecNormalize`` on gymnasium's Ant-v5; ``rsl_rl``: rsl-rl-lib's ``OnPolicyRunner`` with legged_gym's
  Cassie PPO on our ``CassieEnv`` (``rsl_rl_adapter.py``); ``rsl_rl_mirror`` (context, run only when named in
  ``--peers``): the same with rsl-rl-lib's symmetry augmentation and bfloat16 autocast. Sources and numbers:
  ``learning_peers.py``.

Protocol. Runs go one at a time by default, each ``(peer, seed)`` in its own process. ``--lanes 2`` runs two
at once in seed order (ours and the peer of the first seed start together; each next run starts when a lane
frees), so every run has one other run beside it for nearly all of its time and all see about the same load.
Every figure then holds only for that shared load (on 2 cores each run has about one core, which is what a
lone run at ``--torch-threads 1`` uses anyway). A finished run is recorded in ``runs/<peer>_seed<s>/run.json``
and a re-invocation with the same arguments reuses it, so a cut-off comparison continues with the runs it lacks.
The budget counts from the process launch (interpreter start-up and construction included, for every
peer); a run stops at the budget or the frame cap (``--frames``; default: each peer's own horizon, also
its learning-rate annealing horizon: 1M frames for torchrl, sb3 and ours on ant_v5, 10M for ours on
cassie, none for rsl_rl's adaptive rate). Budget checks: ours at any instant (the process is ended),
sb3 and rsl_rl at every environment step, torchrl after every collected batch (it may overrun by one
batch's collection). The evaluated policy is the one after the last completed update, and ``frames``
counts the frames it was trained on. torch runs ``--torch-threads`` (default 1, for runs side by side; a
lone Cassie run of ours defaults to 2: ``conf/preset/cassie.yaml``) intra-op threads in every peer: at
two threads the torchrl peer's minibatch steps ran ~20 times slower (and its collection ~4 times) on
this loaded 2-core machine. Every final policy is evaluated the same way, as
``python -m torchrl_ahrs.evaluate`` does: our task's env (for ant_v5 EnvPool's Ant-v5, which steps like
gymnasium's Ant-v5: ``tests/envs/test_envpool.py``), 10 environments seeded 12345, each one's first
episode, the mean action; the return is the native total reward (Cassie also reports episode length
and the velocity-tracking error). Training curves record, once per collected batch, the wall time,
frames and the mean return of the episodes that ended in it (sampled actions); plots and the
time-to-threshold columns use their episode-weighted mean over the last ``--window-frames`` frames
(default thresholds: ant_v5 1 000 and 2 000; cassie 10 and 20 of a 1 000-step episode's native reward,
whose two tracking terms give at most 20 each).

Outputs in ``--out``: ``curves.csv`` (peer, seed, wall_s, frames, return, episodes, smoothed), ``summary.csv``
(one row per run: evaluation, frames, wall, stop reason, machine load from ``os.getloadavg()`` at its
start and end), ``table.md`` (per peer: evaluated return mean ± std over seeds, frames, times to
thresholds), ``return_vs_time.png`` and ``return_vs_frames.png`` (mean over seeds, band = min..max),
and ``runs/<peer>_seed<s>/`` (logs, checkpoints; not meant for the repository).
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from record_learning_run import read_scalar

HERE = Path(__file__).resolve().parent
TASKS: dict[str, dict[str, Any]] = {
    "ant_v5": {"peers": ["ours", "torchrl", "sb3"], "thresholds": [1000.0, 2000.0]},
    # "context": peers run only when named in --peers (learning_peers.py says what each one measures)
    "cassie": {"peers": ["ours", "rsl_rl"], "context": ["rsl_rl_mirror"], "thresholds": [10.0, 20.0]},
}
MODULES = {
    "ours": [],
    "torchrl": ["gymnasium", "mujoco"],
    "sb3": ["stable_baselines3", "gymnasium"],
    "rsl_rl": ["rsl_rl"],
    "rsl_rl_mirror": ["rsl_rl"],
}
POLL_S = 0.2  # how often ours' metric file is read for new iterations (the wall-time resolution of its curve)


@dataclass
class Run:
    """One (peer, seed) run: its curve ``[(wall_s, frames, return | nan, episodes)]``, evaluation and bookkeeping."""

    peer: str
    seed: int
    status: str = "ok"
    curve: list[tuple[float, int, float, int]] = field(default_factory=list)
    evaluation: dict[str, Any] | None = None
    trained_frames: int = 0
    wall_s: float = math.nan
    stop: str = ""
    load_start: tuple[float, ...] = ()
    load_end: tuple[float, ...] = ()


def missing_modules(peer: str) -> list[str]:
    """The Python modules ``peer`` needs that are not installed."""
    return [name for name in MODULES[peer] if importlib.util.find_spec(name) is None]


def smoothed(curve: list[tuple[float, int, float, int]], window_frames: int) -> list[float]:
    """Episode-weighted mean return over the rows of the last ``window_frames`` frames, per row (nan: no episode).

    Example:
        >>> smoothed([(1.0, 100, 10.0, 1), (2.0, 200, math.nan, 0), (3.0, 300, 40.0, 3)], window_frames=250)
        [10.0, 10.0, 32.5]
    """
    out = []
    for _, frames, _, _ in curve:
        window = [(r, e) for _, f, r, e in curve if frames - window_frames < f <= frames and e > 0]
        episodes = sum(e for _, e in window)
        out.append(sum(r * e for r, e in window) / episodes if episodes else math.nan)  # Σ r_i e_i / Σ e_i
    return out


def time_to(
    curve: list[tuple[float, int, float, int]], values: list[float], threshold: float
) -> tuple[float, int] | None:
    """``(wall_s, frames)`` of the first row whose smoothed return reaches ``threshold``; None if none does.

    Example:
        >>> time_to([(1.0, 100, 0, 1), (2.0, 200, 0, 1)], [5.0, 12.0], 10.0), time_to([(1.0, 100, 0, 1)], [5.0], 10.0)
        ((2.0, 200), None)
    """
    return next(((w, f) for (w, f, _, _), v in zip(curve, values, strict=True) if v >= threshold), None)


def read_curve(path: Path) -> list[tuple[float, int, float, int]]:
    """Rows of a peer's ``curve.csv``."""
    with path.open() as handle:
        rows = list(csv.DictReader(handle))
    return [(float(r["wall_s"]), int(r["frames"]), float(r["return"] or "nan"), int(r["episodes"])) for r in rows]


def _stop(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def run_ours(task: str, seed: int, args: argparse.Namespace, run_dir: Path) -> Run:
    """``python -m torchrl_ahrs.train`` until the budget or its frames end, then ``python -m torchrl_ahrs.evaluate``."""
    run = Run("ours", seed)
    cmd = [sys.executable, "-m", "torchrl_ahrs.train", f"task={task}", "method=ppo", f"seed={seed}"]
    cmd += [f"hydra.run.dir={run_dir}", "checkpoint.interval=1", f"trainer.torch_threads={args.torch_threads}"]
    cmd += [f"trainer.total_frames={args.frames}"] if args.frames else []
    cmd += args.ours_overrides  # after the harness's own, so a user's override wins
    rows_path = run_dir / "metrics" / "scalars" / "reward" / "total.csv"  # one row per iteration, after collection
    stamps: dict[int, float] = {}
    run.stop = "frames"
    t0 = time.time()
    with (run_dir / "train_stdout.log").open("w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
        while True:
            finished = proc.poll() is not None
            now = time.time() - t0
            for frames in read_scalar(rows_path) if rows_path.exists() else {}:
                stamps.setdefault(frames, now)  # first seen at this poll: collected at most POLL_S earlier
            if finished:
                break
            if now >= args.minutes * 60:
                run.stop = "budget"
                _stop(proc)
                break
            time.sleep(POLL_S)
    run.wall_s = time.time() - t0
    if run.stop == "frames" and proc.returncode != 0:
        run.status = f"failed: train exited {proc.returncode} (see {run_dir / 'train_stdout.log'})"
        return run
    scalars = run_dir / "metrics" / "scalars"
    returns, episodes = read_scalar(scalars / "return" / "total.csv"), read_scalar(scalars / "episodes.csv")
    run.curve = [(stamps[f], f, returns.get(f, math.nan), int(episodes.get(f, 0))) for f in sorted(stamps)]
    if not (run_dir / "checkpoint.pt").exists():
        run.status = "no policy: the budget ended before the first iteration"
        return run
    import torch

    run.trained_frames = int(torch.load(run_dir / "checkpoint.pt", weights_only=False)["state"]["collected_frames"])
    evaluate = [sys.executable, "-m", "torchrl_ahrs.evaluate", f"run={run_dir}", "episodes=10", "seed=12345"]
    with (run_dir / "evaluate_stdout.log").open("w") as log:
        if subprocess.run(evaluate, stdout=log, stderr=subprocess.STDOUT).returncode != 0:
            run.status = f"failed: evaluate (see {run_dir / 'evaluate_stdout.log'})"
            return run
    run.evaluation = json.loads((run_dir / "evaluation.json").read_text())
    return run


def run_peer(peer: str, task: str, seed: int, args: argparse.Namespace, run_dir: Path) -> Run:
    """``learning_peers.py <peer>`` in its own process; reads its curve, worker.json and evaluation.json."""
    run = Run(peer, seed)
    t0 = time.time()
    cmd = [sys.executable, str(HERE / "learning_peers.py"), peer, "--task", task, "--seed", str(seed)]
    cmd += ["--seconds", str(args.minutes * 60), "--run-dir", str(run_dir), "--t0", repr(t0)]
    cmd += ["--torch-threads", str(args.torch_threads)] + (["--frames", str(args.frames)] if args.frames else [])
    with (run_dir / "worker.log").open("w") as log:
        code = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
    if (run_dir / "curve.csv").exists():
        run.curve = read_curve(run_dir / "curve.csv")
    if code != 0 or not (run_dir / "evaluation.json").exists():
        run.status = f"failed: exit {code} (see {run_dir / 'worker.log'})"
        return run
    info = json.loads((run_dir / "worker.json").read_text())
    run.trained_frames, run.wall_s, run.stop = info["trained_frames"], info["wall_s"], info["stop"]
    run.evaluation = json.loads((run_dir / "evaluation.json").read_text())
    return run


def evaluated(run: Run, key: str) -> float:
    """The run's evaluated ``total`` return, ``length`` or a metric's mean (nan when absent)."""
    if run.evaluation is None:
        return math.nan
    if key == "return":
        return run.evaluation["return"]["total"]["mean"]
    if key == "length":
        return run.evaluation["episode_length"]["mean"]
    metric = run.evaluation["metrics"].get(key)
    return metric["mean"] if isinstance(metric, dict) else math.nan


def mean_std(values: list[float]) -> str:
    """``mean ± std`` over the finite values (population std, as ``evaluate`` reports over episodes)."""
    values = [v for v in values if math.isfinite(v)]
    if not values:
        return "—"
    return f"{statistics.fmean(values):,.1f} ± {statistics.pstdev(values):,.1f}".replace(",", " ")


def write_outputs(runs: list[Run], skipped: dict[str, str], args: argparse.Namespace) -> str:
    """curves.csv, summary.csv, table.md and the two PNGs in ``args.out``; returns the table's text."""
    out, thresholds = args.out, args.thresholds
    metrics = ["lin_vel_error"] if args.task == "cassie" else []
    smooth = {(r.peer, r.seed): smoothed(r.curve, args.window_frames) for r in runs}
    with (out / "curves.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["peer", "seed", "wall_s", "frames", "return", "episodes", "smoothed"])
        for r in runs:
            for row, value in zip(r.curve, smooth[(r.peer, r.seed)], strict=True):
                writer.writerow([r.peer, r.seed, *row, value])
    times = {(r.peer, r.seed, t): time_to(r.curve, smooth[(r.peer, r.seed)], t) for r in runs for t in thresholds}
    with (out / "summary.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        header = ["peer", "seed", "status", "eval_return", "eval_return_std", "eval_length", *metrics]
        header += ["trained_frames", "wall_s", "stop", "load_start", "load_end"]
        writer.writerow(header + [f"time_to_{t:g}_s" for t in thresholds] + [f"frames_to_{t:g}" for t in thresholds])
        for r in runs:
            std = r.evaluation["return"]["total"]["std"] if r.evaluation else math.nan
            row = [r.peer, r.seed, r.status, evaluated(r, "return"), std, evaluated(r, "length")]
            row += [evaluated(r, m) for m in metrics] + [r.trained_frames, f"{r.wall_s:.1f}", r.stop]
            row += [" ".join(f"{x:.2f}" for x in r.load_start), " ".join(f"{x:.2f}" for x in r.load_end)]
            hits = [times[(r.peer, r.seed, t)] for t in thresholds]
            writer.writerow(row + [f"{h[0]:.1f}" if h else "" for h in hits] + [h[1] if h else "" for h in hits])
    table = markdown_table(runs, skipped, times, metrics, args)
    (out / "table.md").write_text(table)
    from learning_plots import plot_curves

    title = f"{args.task}: {args.minutes:g} min per run, seeds {' '.join(map(str, args.seeds))}"
    for axis, name in (("wall", "return_vs_time.png"), ("frames", "return_vs_frames.png")):
        plot_curves(runs, smooth, axis, out / name, title)
    return table


def markdown_table(runs, skipped, times, metrics, args) -> str:
    """Per peer: evaluated return (mean ± std over seeds), length, frames, wall, time to each threshold, load."""
    columns = ["peer", "seeds", "evaluated return", "per seed", "episode length", *[f"{m} (m/s)" for m in metrics]]
    columns += ["frames trained", "wall (min)", *[f"time to {t:g} (min)" for t in args.thresholds], "load start → end"]
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for peer in args.peers:
        if peer in skipped:
            lines.append("| " + " | ".join([peer, f"skipped: {skipped[peer]}"] + ["—"] * (len(columns) - 2)) + " |")
            continue
        mine = [r for r in runs if r.peer == peer]
        ok = [r for r in mine if r.evaluation is not None]
        cells = [peer, f"{len(ok)} of {len(mine)}", mean_std([evaluated(r, "return") for r in ok])]
        cells.append(", ".join(f"{evaluated(r, 'return'):.1f}" if r.evaluation else r.status for r in mine))
        cells += [
            mean_std([evaluated(r, "length") for r in ok]),
            *[mean_std([evaluated(r, m) for r in ok]) for m in metrics],
        ]
        cells.append(f"{statistics.fmean([r.trained_frames for r in ok]):,.0f}".replace(",", " ") if ok else "—")
        cells.append(", ".join(f"{r.wall_s / 60:.1f}" for r in mine))
        for t in args.thresholds:
            hits = [times[(peer, r.seed, t)] for r in mine]
            cells.append(", ".join(f"{h[0] / 60:.1f}" if h else "not reached" for h in hits))
        cells.append(", ".join(f"{r.load_start[0]:.1f} → {r.load_end[0]:.1f}" for r in mine if r.load_start))
        lines.append("| " + " | ".join(cells) + " |")
    notes = (
        f"\n{args.task}, {args.minutes:g} min per run, seeds {' '.join(map(str, args.seeds))}, frame cap "
        f"{args.frames or 'each peer its own'}, torch threads {args.torch_threads}, {args.lanes} run(s) at a time"
        + (f", ours with `{' '.join(args.ours_overrides)}`" if args.ours_overrides else "")
        + ". Evaluation: 10 episodes, mean "
        "action, seed 12345, our task env; ± is the std over seeds (population); per-seed values in seed order. "
        f"Times to thresholds: first batch whose training return (sampled actions, episode-weighted mean over "
        f"the last {args.window_frames} frames) reaches it. Load: 1-minute load average at the run's start → end.\n"
    )
    return "\n".join(lines) + "\n" + notes + contrasts(runs, metrics, args)


def contrasts(runs: list[Run], metrics: list[str], args: argparse.Namespace, reps: int | None = None) -> str:
    """Ours against each other peer: means over seeds with 95 % bootstrap intervals, rliable's probability of
    improvement (``reporting.intervals``, ``reps`` resamples: its default when None), and the ratio of frames
    per second (frames trained / wall)."""
    from torchrl_ahrs.reporting.intervals import REPS, improvement_probability, mean_interval

    if "ours" not in args.peers:
        return ""
    reps = reps or REPS

    def per_seed(peer: str, key: str) -> np.ndarray:
        return np.array([evaluated(r, key) for r in runs if r.peer == peer and r.evaluation is not None])

    def rate(peer: str) -> float:
        mine = [r for r in runs if r.peer == peer and r.evaluation is not None and r.wall_s > 0]
        return statistics.fmean(r.trained_frames / r.wall_s for r in mine) if mine else math.nan

    def show(point_low_high: tuple[float, float, float]) -> str:
        return "{:.3g} [{:.3g}, {:.3g}]".format(*point_low_high)

    lines = []
    for peer in [p for p in args.peers if p != "ours" and any(r.peer == p for r in runs)]:
        parts = [f"\nours against {peer} (mean [95 % interval] over seeds; P = rliable's probability of improvement):"]
        for key, higher_is_better in [("return", True), *[(m, False) for m in metrics]]:
            ours, theirs = per_seed("ours", key), per_seed(peer, key)
            sign = 1.0 if higher_is_better else -1.0  # P(ours better): on negated values when lower is better
            p = improvement_probability(sign * ours, sign * theirs, reps)
            better = "above" if higher_is_better else "below"
            parts.append(
                f"- {key}: ours {show(mean_interval(ours, reps))}, {peer} {show(mean_interval(theirs, reps))}; "
                f"P(ours {better} {peer}) = {show(p)}"
            )
        ours_rate, peer_rate = (f"{rate(p):,.0f}".replace(",", " ") for p in ("ours", peer))
        parts.append(
            f"- frames per second: ours {ours_rate}, {peer} {peer_rate} (ratio {rate('ours') / rate(peer):.2f})"
        )
        lines += parts
    return "\n".join(lines) + ("\n" if lines else "")


def read_table(path: Path) -> list[dict[str, str]]:
    """The rows of a ``table.md`` as ``{column: cell}`` (raises ``ValueError`` if a row has the wrong width)."""
    lines = [line for line in path.read_text().splitlines() if line.startswith("|")]
    header = [cell.strip() for cell in lines[0].strip("|").split("|")]
    rows = []
    for line in lines[2:]:
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        if len(cells) != len(header):
            raise ValueError(f"row has {len(cells)} cells, header {len(header)}: {line}")
        rows.append(dict(zip(header, cells, strict=True)))
    return rows


def run_or_reuse(peer: str, seed: int, args: argparse.Namespace) -> Run:
    """One (peer, seed) run, or the one a previous invocation finished: ``run.json`` in its directory.

    The record is written only after evaluation, so an interrupted run starts again from scratch (a run's
    budget is its wall clock, so it cannot continue). A finished run is reused only if it was made with the
    same budget, frame cap, threads and overrides (``settings`` in ``run.json``); otherwise it is refused.
    """
    run_dir = args.out / "runs" / f"{peer}_seed{seed}"
    run_dir.mkdir(parents=True, exist_ok=True)
    record, settings = run_dir / "run.json", run_settings(peer, args)
    if record.exists():
        saved = json.loads(record.read_text())
        if saved["settings"] != settings:
            raise SystemExit(f"{record} was made with {saved['settings']}, not {settings}: use another --out")
        run = Run(**{k: tuple(v) if k.startswith("load") else v for k, v in saved["run"].items()})
        run.curve = [tuple(row) for row in run.curve]
        print(f"{peer} seed {seed}: reused from {record}", flush=True)
        return run
    load_start = os.getloadavg()
    run = run_ours(args.task, seed, args, run_dir) if peer == "ours" else run_peer(peer, args.task, seed, args, run_dir)
    run.load_start, run.load_end = load_start, os.getloadavg()
    if run.status == "ok":
        record.write_text(json.dumps({"settings": settings, "run": asdict(run)}))
    print(f"{peer} seed {seed}: {run.status}, return {evaluated(run, 'return'):.1f}, "
          f"{run.trained_frames} frames, {run.wall_s:.0f} s, load {load_start[0]:.2f} → {run.load_end[0]:.2f}",
          flush=True)  # fmt: skip
    return run


def run_settings(peer: str, args: argparse.Namespace) -> dict[str, Any]:
    """What a finished run's result depends on besides its peer and seed (checked before it is reused)."""
    settings = {"task": args.task, "minutes": args.minutes, "frames": args.frames, "torch_threads": args.torch_threads}
    return settings | ({"ours_overrides": list(args.ours_overrides)} if peer == "ours" else {})


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True, choices=sorted(TASKS))
    parser.add_argument("--minutes", type=float, required=True, help="wall-clock budget per (peer, seed) run")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--peers", nargs="+", default=None, help="default: every peer of the task")
    parser.add_argument("--frames", type=int, default=None, help="frame cap for every peer (default: each its own)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--thresholds", type=float, nargs="+", default=None, help="returns to time (task default)")
    parser.add_argument("--window-frames", type=int, default=20480, help="smoothing window of training returns")
    parser.add_argument("--torch-threads", type=int, default=1)
    parser.add_argument("--ours-overrides", nargs="*", default=[], help="Hydra overrides appended to ours' command")
    parser.add_argument("--lanes", type=int, default=1, help="runs at a time (default 1; the docstring says when 2)")
    args = parser.parse_args(argv)
    args.peers = args.peers or TASKS[args.task]["peers"]
    known = TASKS[args.task]["peers"] + TASKS[args.task].get("context", [])
    unknown = [p for p in args.peers if p not in known]
    if unknown or args.minutes <= 0 or args.lanes < 1:
        parser.error(f"peers for {args.task}: {known}" if unknown else "--minutes and --lanes must be positive")
    args.thresholds = args.thresholds or TASKS[args.task]["thresholds"]
    skipped = {p: f"{', '.join(m)} not installed" for p in args.peers if (m := missing_modules(p))}
    args.out.mkdir(parents=True, exist_ok=True)
    # seed-major order: with --lanes 2 the first seed's ours and peer start together; later runs fill freed lanes
    jobs = [(peer, seed) for seed in args.seeds for peer in args.peers if peer not in skipped]
    with ThreadPoolExecutor(max_workers=args.lanes) as pool:  # each run is its own process; threads only wait
        runs = list(pool.map(lambda job: run_or_reuse(*job, args), jobs))
    for peer, reason in skipped.items():
        print(f"{peer}: skipped ({reason})")
    print(write_outputs(runs, skipped, args))


if __name__ == "__main__":
    main()
