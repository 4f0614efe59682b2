"""Evaluation behind ``python -m torchrl_ahrs.evaluate run=<run dir> [episodes=N] [video=true]``.

Rebuilds the actor from the run's ``config.yaml`` and ``checkpoint.pt`` (observation statistics included),
runs ``episodes`` episodes with the mean action (``deterministic=false`` samples), prints

    return total  -12.3 ± 4.5 over 10 episodes (length 100 ± 0)
      distance    -14.1 ± 4.0
      ...

and writes ``<run>/evaluation.json`` (returns per component, episode lengths, task metrics such as
Cassie's velocity-tracking error or the point's distance to its target). ``video=true`` also renders
environment 0 offscreen, 640x480 through a camera following the robot, into ``<run>/videos/<task>.mp4``
(``.gif`` without imageio-ffmpeg).

Importing this module imports ``mujoco``: a process that renders calls
:func:`~torchrl_ahrs.evaluation.render.select_gl_backend` before (the entry point does).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, cast

from omegaconf import DictConfig, OmegaConf

from torchrl_ahrs.app.evaluate.policy import EvaluationError, load_policy
from torchrl_ahrs.app.shared.run_dir import EVALUATION, RunDirectory
from torchrl_ahrs.envs.registry import make_env
from torchrl_ahrs.evaluation.episodes import record_frames, run_episodes, summarize
from torchrl_ahrs.evaluation.render import base_env, clip_format, make_frame_source, write_clip
from torchrl_ahrs.evaluation.task_metrics import episode_metrics, step_probe
from torchrl_ahrs.rewards.components import TOTAL

DEFAULT_FPS = 30.0  # for envs that do not say their control period


def evaluate(
    run_dir: str | Path,
    episodes: int = 10,
    deterministic: bool = True,
    seed: int = 12345,
    output: str | None = EVALUATION,
    task_overrides: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Evaluates the run's policy on ``episodes`` episodes; returns (and writes to ``run_dir/output``)
    the summary. Reported components: the run's K components, the task's other components, ``total``.
    ``task_overrides`` changes settings of the run's task for this evaluation (:func:`load_policy`); the
    summary records them under ``task_overrides``.

    Example:
        >>> evaluate("/nonexistent")
        Traceback (most recent call last):
        ...
        torchrl_ahrs.app.evaluate.policy.EvaluationError: no run directory at /nonexistent
    """
    if episodes < 1:
        raise EvaluationError(f"episodes must be a positive integer, got {episodes}")
    policy = load_policy(run_dir, task_overrides)
    reported = _reported_components(policy.components, list(policy.task.components))
    env = make_env(policy.task, episodes, seed, components=reported, transforms=policy.make_envs.transforms)
    try:
        results = run_episodes(env, policy.actor, reported, deterministic, step_probe(policy.task.name))
    finally:
        env.close()
    trained_with = policy.cfg.trainer.get("task_overrides")  # absent from the configs of runs before the option
    summary = {
        "run": str(Path(run_dir).resolve()),
        "task": policy.task.name,
        "method": policy.cfg.method.name,
        "components": policy.components,
        "deterministic": deterministic,
        "seed": seed,
        "task_overrides": dict(task_overrides or {}),
        # what the run's training environments changed (trainer.task_overrides); scored here on `task` as defined
        "trained_with_task_overrides": OmegaConf.to_container(trained_with) if trained_with else {},
        **summarize(results, episode_metrics(results.returns, results.metrics)),
    }
    if output:
        (RunDirectory(run_dir).path / output).write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def render_clip(
    run_dir: str | Path,
    num_frames: int = 200,
    stride: int = 1,
    width: int = 640,
    height: int = 480,
    video_format: str = "auto",
    name: str | None = None,
    fps: float | None = None,
    deterministic: bool = True,
    seed: int = 12345,
    task_overrides: Mapping[str, Any] | None = None,
) -> Path:
    """Renders environment 0 of a one-env copy of the task under the policy; returns the clip's path.
    ``video_format="auto"``: MP4 when imageio-ffmpeg is installed, else GIF (:func:`clip_format`).

    Raises:
        RenderUnavailable: the task or the machine cannot render (the message says why).
    """
    if num_frames < 1 or stride < 1:
        raise EvaluationError(f"video_frames and video_stride must be positive, got {num_frames}, {stride}")
    if video_format not in ("auto", "gif", "mp4"):
        raise EvaluationError(f"video_format must be auto, gif or mp4, got {video_format!r}")
    video_format = clip_format(video_format)
    policy = load_policy(run_dir, task_overrides)
    env = policy.make_envs(1, seed)
    try:
        frame_source = make_frame_source(env, width, height)
        print(f"rendering with {frame_source.description}")
        frames = record_frames(env, policy.actor, frame_source, num_frames, stride, deterministic)
        frame_source.close()
        control_dt = getattr(base_env(env), "control_dt", None)
        fps = fps or (1.0 / (control_dt * stride) if control_dt else DEFAULT_FPS)
    finally:
        env.close()
    path = RunDirectory(run_dir).videos / (name or f"{policy.task.name}.{video_format}")
    return write_clip(frames, path, fps)


def _reported_components(components: list[str], task_components: list[str]) -> list[str]:
    """The run's components in K order, then the task's others, then ``total`` (once)."""
    ordered = list(components) + [c for c in task_components if c not in components]
    return [c for c in ordered if c != TOTAL] + [TOTAL]


def format_summary(summary: dict[str, Any]) -> str:
    """The printed table: total first, then each component, then the task metrics."""
    returns, length = summary["return"], summary["episode_length"]
    total = returns[TOTAL]
    lines = [
        f"{summary['task']} ({summary['method']}): return total {total['mean']:.3f} ± {total['std']:.3f} over "
        f"{summary['episodes']} episodes (length {length['mean']:.1f} ± {length['std']:.1f}, "
        f"{'mean action' if summary['deterministic'] else 'sampled actions'})"
    ]
    if summary.get("trained_with_task_overrides"):
        lines.append(f"  task changed for training only: {json.dumps(summary['trained_with_task_overrides'])}")
    if summary.get("task_overrides"):
        lines.append(f"  task changed for this evaluation: {json.dumps(summary['task_overrides'])}")
    width = max(len(name) for name in returns)
    lines += [
        f"  {name:<{width}}  {stats['mean']:.4f} ± {stats['std']:.4f}"
        for name, stats in returns.items()
        if name != TOTAL
    ]
    for name, value in summary["metrics"].items():
        text = f"{value['mean']:.4f} ± {value['std']:.4f}" if isinstance(value, dict) else f"{value:.4f}"
        lines.append(f"  metric {name}: {text}")
    return "\n".join(lines)


def run(cfg: DictConfig) -> int:
    """The command (``conf/evaluate.yaml``): evaluate, print the table, optionally render a clip."""
    if OmegaConf.is_missing(cfg, "run"):
        raise EvaluationError("give the training run directory: python -m torchrl_ahrs.evaluate run=<run dir>")
    # a mapping: conf/evaluate.yaml declares task as one, and overrides only add keys under it
    task = cfg.get("task")
    task_overrides = cast(dict[str, Any], OmegaConf.to_container(task, resolve=True)) if task else {}
    summary = evaluate(cfg.run, cfg.episodes, cfg.deterministic, cfg.seed, cfg.output, task_overrides)
    print(format_summary(summary))
    if cfg.output:
        print(f"wrote {Path(cfg.run) / cfg.output}")
    if cfg.video:
        path = render_clip(
            cfg.run,
            cfg.video_frames,
            cfg.video_stride,
            cfg.video_width,
            cfg.video_height,
            cfg.video_format,
            cfg.video_name,
            cfg.video_fps,
            cfg.deterministic,
            cfg.seed,
            task_overrides,
        )
        print(f"wrote {path} ({cfg.video_frames} frames)")
    return 0
