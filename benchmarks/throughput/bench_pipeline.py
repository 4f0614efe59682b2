"""Training throughput: our pipeline against TorchRL's reference PPO pipeline, same task, same frames.

Both train PPO on the MuJoCo Ant-v5 task for the same number of frames with the same batch geometry
(N envs x T steps per batch, E epochs, M minibatches), the same network widths, the same seed and
the same thread count:

- ``ours``: :func:`torchrl_ahrs.app.train.iteration.train` with ``task=ant_v5 method=<ppo|hdppo>`` (EnvPool's Ant-v5
  behind our batched env, reward components, K-head critic, WeightedMultiGAE, the loop of training/loop.py,
  CSV + TensorBoard logging), exactly as ``python -m torchrl_ahrs.train`` runs it.
- ``reference``: the pipeline TorchRL's ``sota-implementations/ppo`` builds for MuJoCo, written here
  from its description (``reference_ppo.py``, shared with ``learning.py``): gymnasium's ``Ant-v5`` through ``GymEnv`` in a ``ParallelEnv`` holding the
  same N environments, VecNorm + ClipTransform + RewardSum + StepCounter + DoubleToFloat, a
  ``Collector``, ``GAE``, ``ClipPPOLoss``, a ``TensorDictReplayBuffer`` with
  ``SamplerWithoutReplacement``, Adam with linear learning-rate annealing and gradient clipping.

Timing: let ``t_i`` be the moment batch ``i`` (i = 1..n) leaves the collector. Frames per second are
``(n - 2 - w) * frames_per_batch / (t_{n-1} - t_{w+1})`` with ``w`` warm-up batches, so both numbers
cover whole iterations (update on batch i, then collection of batch i+1) and neither counts
construction, process start-up, the first ``w`` iterations, the collector's teardown in its last
batch or the final checkpoint. CPU milliseconds per frame over the same interval (all threads, and
the ``ParallelEnv`` worker processes) are the load-independent companion figure. For ``ours`` the
``t_i`` are taken by a thin proxy around the collector that ``train`` builds (nothing else changes). Pipelines alternate across ``--repeat`` rounds (so a busy
neighbour on a shared machine penalises neither more) and the median of each is reported.

``ParallelEnv`` starts one process per environment. With more environments than ``--ref-workers``
each worker process steps ``N / workers`` gymnasium envs in a ``SerialEnv`` (TorchRL's nested batched
env): 64 worker processes (each a Python interpreter with torch, ~0.3 GB) would crowd a 2-core
machine; ``--ref-workers 64`` gives the one-process-per-env form.

Run: ``python benchmarks/throughput/bench_pipeline.py --frames 32768 --num-envs 64 --repeat 3``
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import torch
from hydra import compose, initialize_config_module
from tensordict import TensorDictBase

# reference_ppo.py is shared with the learning benchmark (learning/learning_peers.py) and lives there
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "learning"))
from reference_ppo import ReferenceConfig, ReferencePPO  # noqa: E402


def frames_per_second(batch_times: list[float], frames_per_batch: int, warmup: int) -> float:
    """Frames/s over the batches after the first ``warmup`` ones, from the batch delivery times [s].

    Example:
        >>> frames_per_second([0.0, 5.0, 6.0, 7.0], frames_per_batch=100, warmup=1)
        100.0
    """
    if len(batch_times) <= warmup + 1:
        raise ValueError(f"need more than {warmup + 1} batches to time, got {len(batch_times)}")
    return frames_per_batch * (len(batch_times) - 1 - warmup) / (batch_times[-1] - batch_times[warmup])


class CpuClock:
    """CPU seconds (user + system) used by this process and its descendant processes since creation.

    Descendants (``ParallelEnv`` workers) are found through ``/proc`` on Linux (elsewhere only this
    process counts). A process that has exited keeps its last reading, so the clock never goes back.
    """

    def __init__(self):
        self.tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
        self.children: dict[int, float] = {}

    def __call__(self) -> float:
        pending = [os.getpid()]
        while pending:
            pid = pending.pop()
            for task in Path(f"/proc/{pid}/task").glob("*/children") if Path("/proc").exists() else []:
                try:
                    children = [int(child) for child in task.read_text().split()]
                except OSError:
                    continue
                for child in children:
                    pending.append(child)
                    try:
                        fields = Path(f"/proc/{child}/stat").read_text().rsplit(")", 1)[1].split()
                    except OSError:
                        continue
                    self.children[child] = (int(fields[11]) + int(fields[12])) / self.tick  # utime + stime
        return time.process_time() + sum(self.children.values())


class TimedCollector:
    """Delegates to a collector and records ``(wall, cpu)`` each time it hands out a batch.

    ``collecting`` holds the wall seconds each batch took to arrive, from the moment the consumer asked for it.
    ``beside(batch)``, when given, runs as each batch arrives, before it is handed out; its wall and CPU time are
    taken off the clocks, so the stamps time the pipeline alone (bench_floor.py times the floor there, beside each
    batch).
    """

    def __init__(self, collector, beside: Callable[[TensorDictBase], None] | None = None):
        self._collector = collector
        self._cpu = CpuClock()
        self._beside = beside
        self.stamps: list[tuple[float, float]] = []
        self.collecting: list[float] = []

    def __iter__(self):
        paused_wall = paused_cpu = 0.0  # [s] spent in beside(), left out of the stamps
        asked = time.perf_counter()
        for batch in self._collector:
            self.collecting.append(time.perf_counter() - asked)
            if self._beside is not None:
                wall, cpu = time.perf_counter(), self._cpu()
                self._beside(batch)
                paused_wall += time.perf_counter() - wall
                paused_cpu += self._cpu() - cpu
            self.stamps.append((time.perf_counter() - paused_wall, self._cpu() - paused_cpu))
            yield batch
            asked = time.perf_counter()

    def __getattr__(self, name):
        return getattr(self._collector, name)


def rates(stamps: list[tuple[float, float]], frames_per_batch: int, warmup: int) -> tuple[float, float]:
    """(frames per wall-clock second, CPU milliseconds per frame) over the timed iterations.

    Example:
        >>> rates([(0.0, 0.0), (5.0, 9.0), (6.0, 11.0), (7.0, 13.0)], frames_per_batch=100, warmup=1)
        (100.0, 20.0)
    """
    fps = frames_per_second([wall for wall, _ in stamps], frames_per_batch, warmup)
    timed_frames = frames_per_batch * (len(stamps) - 1 - warmup)
    return fps, 1e3 * (stamps[-1][1] - stamps[warmup][1]) / timed_frames


# --- ours ----------------------------------------------------------------------------------------


def run_ours(method: str, args: argparse.Namespace, total_frames: int) -> tuple[float, float]:
    """(frames/s, CPU ms/frame) of ``torchrl_ahrs.app.train.iteration.train`` on task=ant_v5 after ``args.warmup`` batches."""
    overrides = [
        "task=ant_v5",
        f"method={method}",
        f"seed={args.seed}",
        f"trainer.total_frames={total_frames}",
        f"trainer.num_envs={args.num_envs}",
        f"trainer.frames_per_batch={args.num_envs * args.rollout_steps}",
        f"trainer.num_epochs={args.epochs}",
        f"trainer.mini_batch_size={args.num_envs * args.rollout_steps // args.minibatches}",
        f"model.hidden_sizes=[{','.join(map(str, args.hidden))}]",
        "trainer.progress_bar=false",
        "checkpoint.interval=0",
        *args.ours_overrides,
    ]
    with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    return rates(timed_train(cfg), args.num_envs * args.rollout_steps, args.warmup)


def timed_train(cfg) -> list[tuple[float, float]]:
    """``(wall, cpu)`` at each batch :func:`torchrl_ahrs.app.train.iteration.train` collects on ``cfg`` (in a scratch
    run directory), but the last: its collection carries the collector's teardown."""
    return train_with_timed_collector(cfg).stamps[:-1]


def train_with_timed_collector(cfg, beside: Callable[[TensorDictBase], None] | None = None) -> TimedCollector:
    """Runs :func:`torchrl_ahrs.app.train.iteration.train` on ``cfg`` in a scratch run directory; returns the
    :class:`TimedCollector` (with ``beside``) put around the collector ``train`` builds, its only instrumentation."""
    import torchrl_ahrs.app.train.iteration as training

    timed: list[TimedCollector] = []
    build_collector = training.build_collector

    def make_timed_collector(*a, **kw):
        timed.append(TimedCollector(build_collector(*a, **kw), beside))
        return timed[-1]

    training.build_collector = make_timed_collector
    try:
        with tempfile.TemporaryDirectory() as run_dir:
            training.train(cfg, Path(run_dir))
    finally:
        training.build_collector = build_collector
    return timed[0]


# --- TorchRL reference ---------------------------------------------------------------------------


def run_reference(args: argparse.Namespace, total_frames: int) -> tuple[float, float]:
    """(frames/s, CPU ms/frame, worker processes included) of TorchRL's reference PPO pipeline
    (``reference_ppo.py``) on gymnasium Ant-v5 at our batch geometry, after ``args.warmup`` batches.

    The reference's structure with this benchmark's settings: N envs in a ``ParallelEnv``, our widths,
    epochs and minibatches; entropy off, critic coefficient 0.5, gradient norm 1.0, PyTorch's default
    initialisation (the objective of our default config).
    """
    frames_per_batch = args.num_envs * args.rollout_steps
    config = ReferenceConfig(
        num_envs=args.num_envs,
        workers=args.ref_workers,
        frames_per_batch=frames_per_batch,
        total_frames=total_frames,
        mini_batch_size=frames_per_batch // args.minibatches,
        epochs=args.epochs,
        max_grad_norm=1.0,
        critic_coeff=0.5,
        entropy_bonus=False,
        hidden=list(args.hidden),
        orthogonal_init=False,
    )
    ppo = ReferencePPO(config, args.seed)
    stamps = []
    cpu = CpuClock()
    for _ in ppo.batches():
        stamps.append((time.perf_counter(), cpu()))
    return rates(stamps[:-1], frames_per_batch, args.warmup)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=32768, help="timed frames per run (after warm-up)")
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--rollout-steps", type=int, default=32, help="T; frames_per_batch = N * T")
    parser.add_argument("--epochs", type=int, default=5)
    parser.add_argument("--minibatches", type=int, default=4)
    parser.add_argument("--hidden", type=int, nargs="+", default=[256, 256])
    parser.add_argument("--warmup", type=int, default=1, help="batches excluded from the timing")
    parser.add_argument("--repeat", type=int, default=1, help="alternating rounds; medians are reported")
    parser.add_argument("--methods", nargs="+", default=["ppo", "hdppo"], choices=["ppo", "hdppo"])
    parser.add_argument("--ref-workers", type=int, default=4, help="ParallelEnv worker processes (reference)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--ours-overrides", nargs="*", default=[], help="extra Hydra overrides for ours, e.g. trainer.collector=multi"
    )
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    frames_per_batch = args.num_envs * args.rollout_steps
    batches = max(1, -(-args.frames // frames_per_batch))  # ceil
    # n batches time n - 2 - warmup iterations: the last batch is not timed either, because the collector's
    # final rollout carries teardown work (3-4 s with ParallelEnv workers, measured)
    total_frames = (batches + args.warmup + 2) * frames_per_batch
    print(
        f"Ant-v5  N={args.num_envs} T={args.rollout_steps} frames_per_batch={frames_per_batch} "
        f"epochs={args.epochs} minibatches={args.minibatches} hidden={args.hidden} "
        f"timed frames={batches * frames_per_batch} (+{args.warmup} warm-up batch) "
        f"torch threads={torch.get_num_threads()} ref ParallelEnv workers={min(args.ref_workers, args.num_envs)}"
    )
    results: dict[str, list[tuple[float, float]]] = {"reference": [], **{method: [] for method in args.methods}}
    for round_index in range(args.repeat):
        for name, runs in results.items():
            result = run_reference(args, total_frames) if name == "reference" else run_ours(name, args, total_frames)
            runs.append(result)
            print(
                f"  round {round_index + 1}: {name:9s} {result[0]:8.0f} frames/s {result[1]:7.3f} CPU ms/frame",
                flush=True,
            )
    medians = {
        name: [statistics.median(column) for column in zip(*runs, strict=True)] for name, runs in results.items()
    }
    reference_fps, reference_cpu = medians["reference"]
    print(
        f"reference (TorchRL sota PPO, gymnasium ParallelEnv) {reference_fps:8.0f} frames/s "
        f"{reference_cpu:7.3f} CPU ms/frame (medians)"
    )
    for method in args.methods:
        fps, cpu = medians[method]
        print(
            f"ours method={method:5s} (train.train, EnvPool)       {fps:8.0f} frames/s {cpu:7.3f} CPU ms/frame  "
            f"ratio ours/reference {fps / reference_fps:5.2f}x (CPU per frame: reference/ours {reference_cpu / cpu:5.2f}x)"
        )


if __name__ == "__main__":
    main()
