"""Atomic checkpoints and exact resumption of a training run.

A checkpoint (``<run dir>/checkpoint.pt``) is ``Trainer.state_dict()``: the trainer's one registry of
everything the next iteration depends on — loss module (actor, critic, observation statistics),
optimiser (with its current learning rate), collector, and every registered module (the estimator's
mixing weights, scheduler history and selector, minibatch order, LR schedule, the random generators,
the checkpoint's own counter). It is written to a temporary file and renamed over the old one, so a
process killed mid-write leaves the previous checkpoint intact.

On resume, metric rows and scheduler decisions logged after the checkpoint (by the iterations that
were lost) are removed, so each iteration appears exactly once. Environments cannot be snapshotted: the
resumed run starts fresh episodes, re-seeded from the seed and the frame counter. ``llm_calls.jsonl``
is an audit log of real calls and is never truncated; the checkpoint records how many lines it had.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
from torchrl.trainers import Trainer, TrainerHookBase

CHECKPOINT_FILE = "checkpoint.pt"


def save_atomic(state: dict[str, Any], path: Path) -> None:
    """``torch.save`` to ``path.tmp`` then rename: readers see the old file or the new one, never half."""
    temporary = path.with_suffix(path.suffix + ".tmp")
    torch.save(state, temporary)
    os.replace(temporary, path)


def load_checkpoint(run_dir: Path) -> dict[str, Any]:
    """The checkpoint of ``run_dir``; a missing file is a ``FileNotFoundError`` naming the path."""
    path = Path(run_dir) / CHECKPOINT_FILE
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}; cannot resume")
    return torch.load(path, weights_only=False)


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
        >>> path = Path(tempfile.mkdtemp()) / "checkpoint.pt"
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
