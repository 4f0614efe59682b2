"""Overhead of the isolated sandbox worker (issue 28) as a share of a training step, on real tasks.

An auxiliary reward from a file runs in a :class:`~torchrl_ahrs.sandbox.SandboxSession` (a key-free process;
tensors cross in shared memory, one small JSON message each way), called once per environment step on the
``num_envs`` rows of that step. Two measurements per task, both with the task's preset and ``method=ppo_a``:

* **per call**: the shipped auxiliary reward on real transitions of the task at the training batch size,
  called in-process and through the worker; the difference is what the worker adds to every env step;
* **end to end**: short training runs with the shipped file (in-process) and with a copy of it (worker),
  alternated; the median of the iterations' frames/s after the first.

``overhead = (per-call worker - per-call in-process) / (num_envs / frames_per_second in-process)``: the added
time per env step over the time one env step of training takes (collection and its share of the update).

    python benchmarks/throughput/bench_sandbox_worker.py --tasks quadcopter cassie --iterations 4 --repeat 2
"""

from __future__ import annotations

import argparse
import csv
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any, cast

import torch
from hydra import compose, initialize_config_module
from omegaconf import OmegaConf

from torchrl_ahrs.app.shared.auxiliary import collect_aux_inputs
from torchrl_ahrs.app.train.iteration import train
from torchrl_ahrs.rewards.auxiliary import load_aux_function, shipped_aux_path


def compose_cfg(overrides: list[str]) -> Any:
    with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def per_call_seconds(fn, inputs: dict[str, torch.Tensor], calls: int) -> float:
    for _ in range(10):  # warm-up (the worker's first call maps the block's pages)
        fn(inputs)
    started = time.perf_counter()
    for _ in range(calls):
        fn(inputs)
    return (time.perf_counter() - started) / calls


def training_frames_per_second(task: str, aux_path: Path, iterations: int, run_dir: Path) -> float:
    cfg = compose_cfg([f"task={task}", "method=ppo_a", "trainer.progress_bar=false", f"aux.path={aux_path}"])
    frames = int(cfg.trainer.frames_per_batch) * (iterations + 1)
    cfg = compose_cfg(
        [
            f"task={task}",
            "method=ppo_a",
            "trainer.progress_bar=false",
            f"aux.path={aux_path}",
            f"trainer.total_frames={frames}",
            "logger.backends=[csv]",
        ]
    )
    train(cfg, run_dir)
    with open(run_dir / "metrics" / "scalars" / "frames_per_second.csv") as handle:
        rates = [float(row[1]) for row in csv.reader(handle)]
    return statistics.median(rates[1:])  # the first iteration carries start-up


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["quadcopter", "cassie"])
    parser.add_argument("--iterations", type=int, default=4, help="timed training iterations per run")
    parser.add_argument("--repeat", type=int, default=2, help="runs per mode, alternated")
    parser.add_argument("--calls", type=int, default=300, help="timed calls per mode")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    for task in args.tasks:
        cfg = compose_cfg([f"task={task}", "method=ppo_a"])
        num_envs = int(cfg.trainer.num_envs)
        shipped = shipped_aux_path(task)
        with tempfile.TemporaryDirectory() as scratch:
            copy = Path(scratch) / f"{task}.py"  # not shipped: served by the worker
            copy.write_text(shipped.read_text())
            task_cfg = cast(dict[str, Any], OmegaConf.to_container(cfg.task, resolve=True))
            inputs = collect_aux_inputs(task_cfg, num_envs=num_envs, steps=2)
            inputs = {name: value[:num_envs] for name, value in inputs.items()}
            in_process, isolated = load_aux_function(shipped), load_aux_function(copy)
            call_in = per_call_seconds(in_process, inputs, args.calls)
            call_worker = per_call_seconds(isolated, inputs, args.calls)
            isolated.session.close()  # type: ignore[attr-defined]
            rates: dict[str, list[float]] = {"in-process": [], "worker": []}
            for round_index in range(args.repeat):
                for mode, path in (("in-process", shipped), ("worker", copy)):
                    run_dir = Path(scratch) / f"{mode}-{round_index}"
                    rates[mode].append(training_frames_per_second(task, path, args.iterations, run_dir))
        fps_in, fps_worker = statistics.median(rates["in-process"]), statistics.median(rates["worker"])
        step_seconds = num_envs / fps_in  # one env step of N envs and its share of the update
        rows.append(
            (
                task,
                num_envs,
                call_in * 1e3,
                call_worker * 1e3,
                100 * (call_worker - call_in) / step_seconds,
                fps_in,
                fps_worker,
                100 * (fps_in / fps_worker - 1),
                rates,
            )
        )
    print(
        "| task | N | call in-process ms | call worker ms | overhead per step (calls) | frames/s in-process |"
        " frames/s worker | overhead (end to end) | runs (frames/s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for task, n, c_in, c_w, over_call, f_in, f_w, over_e2e, rates in rows:
        runs = "; ".join(f"{mode}: {', '.join(f'{r:.0f}' for r in values)}" for mode, values in rates.items())
        print(
            f"| {task} | {n} | {c_in:.3f} | {c_w:.3f} | {over_call:.1f} % | {f_in:.0f} | {f_w:.0f} | "
            f"{over_e2e:.1f} % | {runs} |"
        )


if __name__ == "__main__":
    main()
