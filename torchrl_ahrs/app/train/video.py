"""Clips of the current policy during training, every ``logger.video_interval`` iterations.

Each clip is a fresh one-env episode of the task under the mean action, rendered offscreen (see
``torchrl_ahrs/evaluation/render.py``), fed frame by frame through TorchRL's
:class:`~torchrl.record.VideoRecorder` and dumped to :class:`GifVideoLogger`, which writes

* ``<run>/videos/policy_<iteration>.gif`` and
* a TensorBoard video (TensorBoard stores videos as GIF-encoded image summaries) under ``<run>/metrics``.

TorchRL's own ``TensorboardLogger.log_video`` needs ``moviepy`` and ``CSVLogger.log_video`` needs
``torchcodec``; neither is a dependency, so the GIF is encoded with Pillow here.

Rendering needs a headless GL backend chosen before ``mujoco`` is imported: run training with
``MUJOCO_GL=osmesa`` (or call :func:`~torchrl_ahrs.evaluation.render.select_gl_backend` first thing).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import EnvBase
from torchrl.record import VideoRecorder
from torchrl.record.loggers import Logger
from torchrl.trainers import Trainer, TrainerHookBase

from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.evaluation.episodes import record_frames
from torchrl_ahrs.evaluation.render import base_env, make_frame_source, write_clip


class GifVideoLogger(Logger):
    """A TorchRL logger for videos only: GIF files plus TensorBoard video summaries, no extra packages.

    Example:
        >>> import tempfile
        >>> logger = GifVideoLogger(tempfile.mkdtemp(), fps=10)
        >>> logger.log_video("policy", torch.zeros(1, 4, 3, 8, 8, dtype=torch.uint8), step=3)
        >>> [path.name for path in logger.written]
        ['policy_3.gif']
    """

    def __init__(self, run_dir: str | Path, fps: float = 30.0, tensorboard_dir: str | Path | None = None):
        self.run_dir, self.fps = Path(run_dir), float(fps)
        self.tensorboard_dir = tensorboard_dir
        self.written: list[Path] = []
        super().__init__(exp_name="videos", log_dir=str(RunDirectory(self.run_dir).videos))

    def _create_experiment(self):
        if self.tensorboard_dir is None:
            return None
        from torch.utils.tensorboard import SummaryWriter

        return SummaryWriter(log_dir=str(self.tensorboard_dir))

    def log_video(self, name: str, video: torch.Tensor, step: int | None = None, **kwargs) -> None:
        """``video`` ``[1, T, C, H, W]`` uint8 (the layout :class:`VideoRecorder` dumps)."""
        frames = video[0].permute(0, 2, 3, 1).cpu().numpy().astype(np.uint8)  # [T, H, W, C]
        path = write_clip(frames, Path(self.log_dir) / f"{name.replace('/', '_')}_{step or 0}.gif", self.fps)
        self.written.append(path)
        if self.experiment is not None:
            from tensorboard.compat.proto.summary_pb2 import Summary

            image = Summary.Image(
                height=frames.shape[1], width=frames.shape[2], colorspace=3, encoded_image_string=path.read_bytes()
            )
            self.experiment.file_writer.add_summary(Summary(value=[Summary.Value(tag=name, image=image)]), step)
            self.experiment.flush()

    def log_scalar(self, name: str, value: float, step: int | None = None) -> None:
        raise NotImplementedError("GifVideoLogger logs videos only")

    def log_hparams(self, cfg) -> None:
        pass

    def log_histogram(self, name: str, data, **kwargs) -> None:
        pass

    def close(self) -> None:
        if self.experiment is not None:
            self.experiment.close()


class VideoLog(TrainerHookBase):
    """Every ``interval`` iterations: one clip of ``num_frames`` frames of the policy (mean action).

    Args:
        make_envs: ``(num_envs, seed) -> env``, the run's environment factory
            (:class:`~torchrl_ahrs.app.train.build.EnvFactory`).
        policy: the actor (reads ``"observation"``).
        run_dir: the run directory (clips go to ``videos/``, TensorBoard summaries to ``metrics/``).
        interval: iterations between clips.
        num_frames, width, height: clip size.
        seed: seed of the one-env copy of the task that is rendered.

    Example:
        >>> hook = VideoLog(make_envs, actor, run_dir, interval=10)  # doctest: +SKIP
        >>> hook.register(trainer)  # doctest: +SKIP
    """

    def __init__(
        self,
        make_envs: Callable[[int, int], EnvBase],
        policy,
        run_dir: str | Path,
        interval: int,
        num_frames: int = 100,
        width: int = 640,
        height: int = 480,
        seed: int = 0,
    ):
        if interval < 1:
            raise ValueError(f"logger.video_interval must be a positive integer, got {interval}")
        self.policy, self.interval, self.num_frames = policy, interval, num_frames
        self.env = make_envs(1, seed)
        self.frame_source = make_frame_source(self.env, width, height)  # fails now, not mid-run, if it cannot render
        control_dt = getattr(base_env(self.env), "control_dt", None)
        self.logger = GifVideoLogger(run_dir, 1.0 / control_dt if control_dt else 30.0, RunDirectory(run_dir).metrics)
        self.recorder = VideoRecorder(self.logger, tag="policy", in_keys=["pixels"], skip=1)
        self.iteration = 0

    def __call__(self, batch: TensorDictBase | None = None, metrics: Mapping[str, float] | None = None) -> None:
        # (batch, metrics): what the loop hands every after-iteration callable; a clip runs an episode of its own
        self.iteration += 1
        if self.iteration % self.interval:
            return
        training = self.policy.training
        self.policy.eval()
        frames = record_frames(self.env, self._policy_on_env_device(), self.frame_source, self.num_frames)
        self.policy.train(training)
        for frame in torch.from_numpy(frames):
            self.recorder(TensorDict({"pixels": frame}, []))
        self.recorder.dump(step=self.iteration)

    def _policy_on_env_device(self):
        """The policy, called across devices when it lives elsewhere than the rendered env (a CPU simulator
        with ``trainer.device=cuda``): observation to the policy's device, action back."""
        device = next(self.policy.parameters()).device
        if self.env.device is None or device == self.env.device:
            return self.policy
        return lambda td: self.policy(td.to(device)).to(self.env.device)

    def state_dict(self) -> dict[str, Any]:
        return {"iteration": self.iteration}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.iteration = state_dict["iteration"]

    def register(self, trainer: Trainer, name: str = "video_log") -> None:
        trainer.register_op("post_steps", self)
        trainer.register_module(name, self)


def register_video_log(
    trainer: Trainer | None, cfg: DictConfig, policy, make_envs: Callable[[int, int], EnvBase], run_dir: Path
):
    """Registers a :class:`VideoLog` when ``cfg.logger.video_interval`` is a positive number; returns it
    (or None). Also reads ``logger.video_frames`` / ``video_width`` / ``video_height`` when present."""
    logger_cfg = cfg.get("logger") or {}
    interval = int(logger_cfg.get("video_interval", 0) or 0)
    if interval <= 0:
        return None
    hook = VideoLog(
        make_envs,
        policy,
        run_dir,
        interval,
        num_frames=int(logger_cfg.get("video_frames", 100)),
        width=int(logger_cfg.get("video_width", 640)),
        height=int(logger_cfg.get("video_height", 480)),
        seed=int(cfg.seed) + 777,
    )
    if trainer is not None:  # None: only built, for training/loop.py, which calls it once per iteration
        hook.register(trainer)
    return hook
