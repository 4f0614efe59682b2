"""The run directory: the one place that names its files and says what each holds.

``python -m torchrl_ahrs.train`` writes one directory per run (Hydra's output directory, or the one
``resume=`` names); ``evaluate``, ``report`` and ``resume`` read it. Layout::

    <run>/
      config.yaml                the composed, validated config, secrets replaced by REDACTED (written at start;
                                 resume and evaluate rebuild the run from it)
      checkpoint.pt              the state registry: everything the next iteration depends on (see
                                 app/train/checkpoint.py); written atomically every checkpoint.interval iterations
                                 and at the end
      finished.json              written when the frame budget is reached: {"collected_frames", "total_frames"};
                                 small and committed with a sweep's results (checkpoints are not), so a rerun sweep
                                 and the report know a finished run without its checkpoint
      metrics/                   the logger's experiment: scalars/<name>.csv (a "step,value" header, then one
                                 row per log, step = collected frames) and TensorBoard events (scalars,
                                 hyperparameters, the config as text)
      scheduler_decisions.jsonl  one JSON line per scheduler decision (iteration, frames, rule, weights, ...)
      llm_calls.jsonl            one JSON line per LLM request (audit log, never truncated; replayable)
      evaluation.json            written by `evaluate`: returns per component, lengths, task metrics
      videos/                    GIF/MP4 clips: policy_<iteration>.gif during training, <task>.gif from evaluate
      .hydra/                    Hydra's own config.yaml, hydra.yaml, overrides.yaml, secrets replaced by REDACTED

Example:
    >>> run = RunDirectory("/tmp/run")
    >>> run.checkpoint, run.scalars
    (PosixPath('/tmp/run/checkpoint.pt'), PosixPath('/tmp/run/metrics/scalars'))
"""

from __future__ import annotations

import os
from pathlib import Path

CONFIG = "config.yaml"
CHECKPOINT = "checkpoint.pt"
FINISHED = "finished.json"
METRICS = "metrics"  # the logger's experiment name
SCALARS = "scalars"
DECISIONS = "scheduler_decisions.jsonl"
LLM_CALLS = "llm_calls.jsonl"
EVALUATION = "evaluation.json"
VIDEOS = "videos"
HYDRA = ".hydra"
HYDRA_FILES = (CONFIG, "hydra.yaml", "overrides.yaml")  # what Hydra writes into HYDRA
MULTIRUN = "multirun.yaml"  # Hydra's record of a sweep, in the sweep directory
PLAN = "plan.yaml"  # the cells an experiment planned, written before it ran (app/train/runs.py::planned_cells)
REDACTED = "<redacted>"  # the redaction marker: what a secret value is replaced with in every file above


class RunDirectory:
    """Paths of one run directory (see the module docstring); creates nothing until asked."""

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunDirectory({str(self.path)!r})"

    @property
    def config(self) -> Path:
        return self.path / CONFIG

    @property
    def checkpoint(self) -> Path:
        return self.path / CHECKPOINT

    @property
    def finished(self) -> Path:
        return self.path / FINISHED

    @property
    def metrics(self) -> Path:
        return self.path / METRICS

    @property
    def scalars(self) -> Path:
        return self.metrics / SCALARS

    def scalar(self, name: str) -> Path:
        """The CSV file of scalar ``name`` (e.g. ``return/total``)."""
        return self.scalars / f"{name}.csv"

    @property
    def decisions(self) -> Path:
        return self.path / DECISIONS

    @property
    def llm_calls(self) -> Path:
        return self.path / LLM_CALLS

    @property
    def evaluation(self) -> Path:
        return self.path / EVALUATION

    @property
    def videos(self) -> Path:
        return self.path / VIDEOS

    @property
    def hydra(self) -> Path:
        return self.path / HYDRA

    @property
    def hydra_files(self) -> list[Path]:
        return [self.hydra / name for name in HYDRA_FILES]

    @property
    def saved_config(self) -> Path:
        """``config.yaml``, or Hydra's copy when training never started (a job that crashed before)."""
        return self.config if self.config.is_file() else self.hydra / CONFIG

    def is_run(self) -> bool:
        """Whether this looks like a run directory (it holds ``config.yaml`` or ``.hydra/config.yaml``)."""
        return self.config.is_file() or (self.hydra / CONFIG).is_file()

    def mkdir(self) -> RunDirectory:
        self.path.mkdir(parents=True, exist_ok=True)
        return self


def calls_log(replay_from: str | os.PathLike[str]) -> str:
    """``llm.replay_from`` as a file: a run directory stands for its ``llm_calls.jsonl``."""
    path = Path(replay_from)
    return str(RunDirectory(path).llm_calls if path.is_dir() else path)
