"""Atomic checkpoints and exact resumption of a training run.

A checkpoint (:attr:`RunDirectory.checkpoint <torchrl_ahrs.app.shared.run_dir.RunDirectory.checkpoint>`) is the
state of the run's one registry, ``{name: object with state_dict / load_state_dict}``, which
:func:`torchrl_ahrs.app.train.iteration.train` builds; each thing the next iteration depends on has one entry:

- ``state``: the loop's counters (collected frames, optimiser steps; :class:`~torchrl_ahrs.training.run.Progress`);
- ``collector``: frame and iteration counters, the environments (through
  :class:`~torchrl_ahrs.envs.common.snapshot.BaseEnvSnapshot`: every simulation's integration state,
  counters, targets/commands and reset-noise generator) and the carried tensordict (the last
  observation, running episode returns, trajectory ids; :class:`~torchrl_ahrs.training.collector.ResumableCollector`),
  not the policy (that is ``actor``);
- ``actor``: the policy's parameters and its observation statistics (what evaluation and export load);
- ``critic``: the K heads (with the critic's observation statistics: the actor's own, unless privileged);
- ``estimator``: the mixing weights (their only home: the scheduler reads and sets them there), the last
  shares and the value-norm statistics;
- ``optimizer``: Adam's moments and step counts, the current and the initial learning rate;
- ``minibatches``: the generator of the minibatch permutations (:class:`GeneratorState`);
- ``rule_scheduler``: counters, last rule, statistics history, selector and its generator;
- ``video_log`` (when videos are on), ``rng`` (:class:`GlobalRNG`: Python's, NumPy's and torch's global
  generators) and ``checkpoint`` (:class:`CheckpointHook`: its iteration counter and the component names).

It is written to a temporary file and renamed over the old one, so a process killed mid-write leaves
the previous checkpoint intact. Resuming loads it into a run built anew from the saved config, after
every piece has been built (and has drawn whatever random numbers building draws), so the resumed run
continues bit for bit: on CPU a run interrupted after any checkpoint and resumed equals the
uninterrupted run (parameters, optimiser, metric rows except timing, scheduler decisions;
``tests/system/test_resume.py``). Exact with ``trainer.collector=sync`` (the default) and ``scheduler.blocking=true``;
worker processes of ``multi``/``async`` collectors sample with generators of their own, and a
non-blocking scheduler decides when its thread answers. EnvPool-backed tasks (``ant_v5``, ``humanoid``,
``go1_terrain``, ``leap_cube``, ``shadow_hand``, ``dmc_*``) cannot snapshot their C++ simulators: a resumed
run starts new episodes there (re-seeded from the seed and the frame counter).

Checkpoints written before this registry (TorchRL ``Trainer.state_dict()``: ``loss_module``, the actor a
second time, the trainer's counters) cannot be resumed; evaluation still reads their ``actor`` entry.

On resume, metric rows and scheduler decisions logged after the checkpoint (by the iterations that
were lost) are removed, so each iteration appears exactly once. The LLM calls log is an audit log of
real calls and is never truncated.

A run stopped by a failing auxiliary reward saves what it can (:meth:`CheckpointHook.save_after_failure`):
the collector, shut down with the failure, is saved as None, and a run resumed from it starts new episodes.
"""

from __future__ import annotations

import json
import logging
import os
import random
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase

from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.run_dir import RunDirectory

log = logging.getLogger(__name__)


def save_atomic(state: dict[str, Any], path: Path) -> None:
    """``torch.save`` to ``path.tmp`` then rename: readers see the old file or the new one, never half."""
    temporary = path.with_suffix(path.suffix + ".tmp")
    torch.save(state, temporary)
    os.replace(temporary, path)


def load_checkpoint(path: Path) -> dict[str, Any]:
    """The checkpoint at ``path``; a missing file is a ``FileNotFoundError`` naming the path."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}; cannot resume")
    return torch.load(path, weights_only=False)


def mark_finished(run_dir: Path, collected_frames: int, total_frames: int) -> Path:
    """Writes the run directory's ``finished.json`` (see :mod:`torchrl_ahrs.app.shared.run_dir`); returns its path."""
    path = RunDirectory(run_dir).finished
    path.write_text(json.dumps({"collected_frames": int(collected_frames), "total_frames": int(total_frames)}) + "\n")
    return path


def collected_frames(run_dir: Path) -> int | None:
    """Frames a run has collected: from ``finished.json`` when it finished, else from its checkpoint; None
    without either. Raises what ``torch.load`` raises on a torn checkpoint."""
    directory = RunDirectory(run_dir)
    if directory.finished.is_file():
        return int(json.loads(directory.finished.read_text())["collected_frames"])
    if directory.checkpoint.is_file():
        return int(load_checkpoint(directory.checkpoint)["state"]["collected_frames"])
    return None


def truncate_metrics(metrics_dir: Path, last_step: int) -> int:
    """Drops CSV rows whose step is after ``last_step`` (a ``step,value`` header stays); returns how many rows
    were dropped."""
    dropped = 0
    for csv_path in Path(metrics_dir).rglob("*.csv"):
        rows = csv_path.read_text().splitlines()
        kept = [
            row for row in rows if row and (row.startswith("step,") or int(float(row.split(",", 1)[0])) <= last_step)
        ]
        dropped += len(rows) - len(kept)
        if len(kept) != len(rows):
            csv_path.write_text("".join(line + "\n" for line in kept))
    return dropped


def truncate_jsonl(path: Path, last_frames: int, frames_field: str = "frames") -> int:
    """Drops JSON lines whose ``frames_field`` is after ``last_frames`` (e.g. scheduler decisions)."""
    path = Path(path)
    if not path.is_file():
        return 0
    lines = path.read_text().splitlines()
    kept = [line for line in lines if line.strip() and json.loads(line).get(frames_field, 0) <= last_frames]
    if len(kept) != len(lines):
        path.write_text("".join(line + "\n" for line in kept))
    return len(lines) - len(kept)


def registry_state(registry: Mapping[str, Any], skip_failed: bool = False) -> dict[str, Any]:
    """``{name: obj.state_dict()}``: what a checkpoint holds.

    ``skip_failed``: an entry whose ``state_dict`` raises is saved as None (a run stopped by a failing
    auxiliary reward: its collector was shut down with the failure; a resumed run starts fresh episodes).

    Example:
        >>> registry_state({"rng": GeneratorState(torch.Generator().manual_seed(0))})["rng"]["generator"].dtype
        torch.uint8
    """
    if not skip_failed:
        return {name: obj.state_dict() for name, obj in registry.items()}
    state: dict[str, Any] = {}
    for name, obj in registry.items():
        try:
            state[name] = obj.state_dict()
        except Exception as error:  # noqa: BLE001 (the rest of the run's state is still worth keeping)
            log.warning("checkpoint after the failure: no %s state (%s: %s)", name, type(error).__name__, error)
            state[name] = None
    return state


def load_registry(registry: Mapping[str, Any], state: Mapping[str, Any], path: Path | str = "the checkpoint") -> None:
    """Loads ``state`` into every entry of ``registry``, in the registry's order.

    Raises:
        ConfigError: ``state`` lacks entries of the registry (a checkpoint of an older layout), naming them.
    """
    missing = [name for name in registry if name not in state]
    if missing:
        raise ConfigError(
            f"{path} has no {', '.join(missing)} entries: it was written by an older version (TorchRL Trainer "
            "layout) and cannot be resumed; start a new run (evaluation still reads its actor)"
        )
    for name, obj in registry.items():
        if state[name] is None:  # written when a run stopped (registry_state(skip_failed=True))
            log.warning("%s holds no %s state (saved when the run stopped): it starts fresh", path, name)
            continue
        obj.load_state_dict(state[name])


class GlobalRNG:
    """Python's, NumPy's and torch's global generators as one registry entry (with the learner's CUDA
    generator, which samples the policy's actions, when it runs on a GPU).

    Example:
        >>> rng = GlobalRNG()
        >>> state = rng.state_dict(); first = torch.rand(1)
        >>> rng.load_state_dict(state); bool(torch.rand(1) == first)
        True
    """

    def __init__(self, device: torch.device | str = "cpu"):
        self.device = torch.device(device)

    def state_dict(self) -> dict[str, Any]:
        state = {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state()}
        if self.device.type == "cuda":
            state["cuda"] = torch.cuda.get_rng_state(self.device)
        return state

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        random.setstate(state_dict["python"])
        np.random.set_state(state_dict["numpy"])
        torch.set_rng_state(state_dict["torch"])
        if "cuda" in state_dict and self.device.type == "cuda":
            torch.cuda.set_rng_state(state_dict["cuda"], self.device)


class GeneratorState:
    """A ``torch.Generator`` (e.g. the minibatch permutations') as a registry entry.

    Example:
        >>> entry = GeneratorState(torch.Generator().manual_seed(0))
        >>> state = entry.state_dict(); first = torch.randperm(4, generator=entry.generator)
        >>> entry.load_state_dict(state); torch.equal(torch.randperm(4, generator=entry.generator), first)
        True
    """

    def __init__(self, generator: torch.Generator):
        self.generator = generator

    def state_dict(self) -> dict[str, Any]:
        return {"generator": self.generator.get_state()}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.generator.set_state(state_dict["generator"])


class CheckpointHook:
    """Saves ``state_fn()`` (the registry's state) atomically every ``interval`` training iterations and
    at the last one (``is_last()`` true).

    The loop calls it after everything else in an iteration (the last of its ``after_iteration`` callables), so
    that the saved state is the one the next iteration starts from. Its own state (the iteration counter and the component names, which an
    evaluation reads to rebuild the critic-free policy) is a registry entry too.

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> path = Path(tempfile.mkdtemp()) / "state.pt"
        >>> hook = CheckpointHook(path, interval=2, state_fn=lambda: {"answer": 42})
        >>> hook(); path.exists()
        False
        >>> hook(); torch.load(path)["answer"]
        42
        >>> hook.state_dict()["iteration"]
        2
    """

    def __init__(
        self,
        path: Path,
        interval: int,
        state_fn: Callable[[], dict[str, Any]],
        components: Sequence[str] = (),
        is_last: Callable[[], bool] = lambda: False,
        state_after_failure: Callable[[], dict[str, Any]] | None = None,
    ):
        self.path = Path(path)
        self.interval = interval
        self.state_fn = state_fn
        self.components = list(components)
        self.is_last = is_last
        self.state_after_failure = state_after_failure or state_fn
        self.iteration = 0

    def __call__(self, batch: TensorDictBase | None = None, metrics: Mapping[str, float] | None = None) -> None:
        # (batch, metrics): what the loop hands every after-iteration callable; the state is the registry's
        self.iteration += 1
        if self.iteration % self.interval == 0 or self.is_last():  # the last one before the collector shuts down
            self.save()

    def save(self) -> None:
        save_atomic(self.state_fn(), self.path)

    def save_after_failure(self) -> None:
        """Saves what can be saved when the run stops on a failure (``state_after_failure``)."""
        save_atomic(self.state_after_failure(), self.path)

    def state_dict(self) -> dict[str, Any]:
        return {"iteration": self.iteration, "components": self.components}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.iteration = int(state_dict["iteration"])
        self.components = list(state_dict["components"])
