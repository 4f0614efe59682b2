"""Atomic checkpoints and exact resumption of a training run.

A checkpoint (:attr:`RunDirectory.checkpoint <torchrl_ahrs.app.run_dir.RunDirectory.checkpoint>`) is
``Trainer.state_dict()``, the trainer's one registry of everything the next iteration depends on:

- ``loss_module``: actor and K-head critic parameters, observation normaliser statistics;
- ``optimizer``: Adam's moments and step counts, the current learning rate;
- ``collector``: frames and iteration counters, the policy's weights, the environments (through
  :class:`~torchrl_ahrs.envs.common.snapshot.BaseEnvSnapshot`: every simulation's integration state,
  counters, targets/commands and reset-noise generator) and the carried tensordict (the last
  observation, running episode returns, trajectory ids; :class:`~torchrl_ahrs.training.collector.ResumableCollector`);
- ``state``: the trainer's counters (collected frames, optimisation steps, last log/save);
- every registered module by name: ``estimator`` (the mixing weights, their only home: the scheduler
  reads and sets them there), ``actor``, ``component_returns``,
  ``ppo_minibatches`` (its shuffling generator), ``obs_norm``, ``lr_decay`` (when ``anneal_lr``),
  ``update_weights``, ``rule_scheduler`` (counters, last rule, statistics history, selector and its generator),
  ``video_log`` (when videos are on), ``rng`` (Python's, NumPy's and torch's global generators) and
  ``checkpoint`` (its iteration counter and the component names).

It is written to a temporary file and renamed over the old one, so a process killed mid-write leaves
the previous checkpoint intact. Resuming loads it into a trainer built anew from the saved config, after
every piece has been built (and has drawn whatever random numbers building draws), so the resumed run
continues bit for bit: on CPU a run interrupted after any checkpoint and resumed equals the
uninterrupted run (parameters, optimiser, metric rows except timing, scheduler decisions;
``tests/test_resume.py``). Exact with ``trainer.collector=sync`` (the default) and ``scheduler.blocking=true``;
worker processes of ``multi``/``async`` collectors sample with generators of their own, and a
non-blocking scheduler decides when its thread answers. EnvPool-backed tasks (``ant_v5``, ``humanoid``,
``go1_terrain``, ``leap_cube``, ``shadow_hand``, ``dmc_*``) cannot snapshot their C++ simulators: a resumed
run starts new episodes there (re-seeded from the seed and the frame counter).

On resume, metric rows and scheduler decisions logged after the checkpoint (by the iterations that
were lost) are removed, so each iteration appears exactly once. The LLM calls log is an audit log of
real calls and is never truncated.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
from torchrl.trainers import Trainer, TrainerHookBase

from torchrl_ahrs.app.run_dir import RunDirectory


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
    """Writes the run directory's ``finished.json`` (see :mod:`torchrl_ahrs.app.run_dir`); returns its path."""
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
    """Drops CSV rows whose step is after ``last_step``; returns how many rows were dropped."""
    dropped = 0
    for csv_path in Path(metrics_dir).rglob("*.csv"):
        rows = csv_path.read_text().splitlines()
        kept = [row for row in rows if row and int(float(row.split(",", 1)[0])) <= last_step]
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


class CheckpointHook(TrainerHookBase):
    """Saves ``state_fn()`` (``Trainer.state_dict``) atomically every ``interval`` training iterations.

    Register it after every other ``post_steps`` hook, so that the saved state is the one the next
    iteration starts from. Its own state (the iteration counter and the component names, which an
    evaluation reads to rebuild the critic-free policy) is part of what it saves once registered.

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
        self, path: Path, interval: int, state_fn: Callable[[], dict[str, Any]], components: Sequence[str] = ()
    ):
        self.path = Path(path)
        self.interval = interval
        self.state_fn = state_fn
        self.components = list(components)
        self.iteration = 0
        self.trainer: Trainer | None = None

    def __call__(self) -> None:
        self.iteration += 1
        finished = self.trainer is not None and self.trainer.collected_frames >= self.trainer.total_frames
        if self.iteration % self.interval == 0 or finished:  # the last one is saved before the collector shuts down
            self.save()

    def save(self) -> None:
        save_atomic(self.state_fn(), self.path)

    def state_dict(self) -> dict[str, Any]:
        return {"iteration": self.iteration, "components": self.components}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.iteration = int(state_dict["iteration"])
        self.components = list(state_dict["components"])

    def register(self, trainer: Trainer, name: str = "checkpoint") -> None:
        self.trainer = trainer
        trainer.register_op("post_steps", self)
        trainer.register_module(name, self)
