"""Offscreen frames of one environment of a batched task, and clip files (GIF, MP4).

Two frame sources, picked from the env's innermost (base) environment by :func:`make_frame_source`:

* :class:`TrackingCamera` — our own MuJoCo tasks (:class:`~torchrl_ahrs.envs.backends.mujoco_base.BatchedMujocoEnv`:
  point_reach, ant, quadcopter, cassie): ``mujoco.Renderer`` draws ``env.model`` with one env's ``MjData``
  through a camera that follows the robot's root body.
* :class:`EnvPoolCamera` — EnvPool's MuJoCo tasks (ant_v5, humanoid, go1_terrain, leap_cube, shadow_hand,
  dmc_*): EnvPool's own renderer (its ``rgb_array`` mode, switched on for the existing pool) with the
  task's default camera, drawn into a GL context we make current.

Headless GL: ``MUJOCO_GL`` is read once, when ``mujoco`` is first imported, so :func:`select_gl_backend`
must run before that (the ``evaluate`` entry point does it first thing). On these machines OSMesa
(``apt-get install libosmesa6``) works; EGL finds no device without ``/dev/dri``.
"""

from __future__ import annotations

import copy
import ctypes.util
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # torchrl.envs imports mujoco, which must wait for select_gl_backend
    from torchrl.envs import EnvBase

HEADLESS_BACKENDS = ("osmesa", "egl")


class RenderUnavailable(RuntimeError):
    """This task or this machine cannot render; the message says why and what to do."""


def select_gl_backend() -> str:
    """Chooses ``MUJOCO_GL`` for offscreen rendering unless the user already did; returns the choice.

    OSMesa when its library is installed, else EGL. Has no effect once ``mujoco`` is imported.

    Example:
        >>> select_gl_backend() in ("osmesa", "egl", "glfw", "glx")
        True
    """
    chosen = os.environ.get("MUJOCO_GL", "").lower()
    if chosen:
        return chosen
    backend = "osmesa" if ctypes.util.find_library("OSMesa") else "egl"
    if "mujoco" not in sys.modules:
        os.environ["MUJOCO_GL"] = backend
        os.environ.setdefault("PYOPENGL_PLATFORM", backend)
        return backend
    return "glfw"  # mujoco already chose its default


def _check_gl_backend() -> str:
    """mujoco's GL backend, or a RenderUnavailable when it cannot work here (no display, not headless)."""
    backend = os.environ.get("MUJOCO_GL", "glfw").lower()
    if backend not in HEADLESS_BACKENDS and not os.environ.get("DISPLAY"):
        raise RenderUnavailable(
            "no display and no offscreen GL backend: start python with MUJOCO_GL=osmesa "
            "(needs the system package libosmesa6) or MUJOCO_GL=egl"
        )
    return backend


def _gl_context(width: int, height: int):
    """A current GL context of mujoco's selected backend, or a RenderUnavailable saying how to get one."""
    import mujoco

    backend = _check_gl_backend()
    try:
        context = mujoco.GLContext(width, height)
        context.make_current()
    except Exception as error:  # the GL stacks raise assorted types
        raise RenderUnavailable(f"cannot create a {backend} GL context: {error!r}") from error
    return context


class TrackingCamera:
    """Renders env ``env_index`` of a :class:`BatchedMujocoEnv` through a camera tracking its root body.

    Args:
        env: the batched MuJoCo env (its ``model`` and ``datas``).
        width, height: frame size in pixels.
        env_index: which of the N simulations to show.
        distance: camera distance as a multiple of the robot's radius (the tracked body's subtree at the
            model's reference pose; not ``model.stat.extent``, which the floor inflates: 16 m for the ant).

    Example:
        >>> from torchrl_ahrs.envs.tasks.point_reach import PointReachEnv
        >>> camera = TrackingCamera(PointReachEnv(num_envs=2), 64, 48)  # doctest: +SKIP
        >>> camera().shape  # doctest: +SKIP
        (48, 64, 3)
    """

    def __init__(self, env, width: int = 640, height: int = 480, env_index: int = 0, distance: float = 2.5):
        import mujoco

        self.env, self.env_index = env, env_index
        # a copy with the visual options changed (same sizes, so it draws the env's MjData); the env keeps its own
        model = copy.deepcopy(env.model)
        # the offscreen buffer must hold the frame
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, height)
        track = 1 if model.nbody > 1 else 0  # the first body after the world: the robot's root
        camera_distance = max(distance * robot_radius(model, track), 1.0)
        # no shadows: on the software GL of these machines the directional light's shadow map breaks up into
        # black specks across the floor (seen on ant, quadcopter and cassie at 640x480)
        model.light_castshadow[:] = 0
        try:
            self.renderer = mujoco.Renderer(model, height=height, width=width)
        except Exception as error:
            raise RenderUnavailable(f"mujoco.Renderer failed ({error!r}); try MUJOCO_GL=osmesa or egl") from error
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        self.camera.trackbodyid = track
        self.camera.distance = camera_distance
        self.camera.elevation = -20.0
        self.camera.azimuth = 135.0
        self.description = f"MuJoCo offscreen ({os.environ.get('MUJOCO_GL', 'glfw')}), camera tracking body 1"

    def __call__(self) -> np.ndarray:
        """One frame ``[H, W, 3]`` uint8 of the current state."""
        self.renderer.update_scene(self.env.datas[self.env_index], camera=self.camera)
        return self.renderer.render().copy()

    def close(self) -> None:
        self.renderer.close()


def robot_radius(model, body: int) -> float:
    """Radius (m) of the sphere around ``body`` holding every geom of its subtree, at the reference pose ``qpos0``.

    Example:
        >>> import mujoco
        >>> xml = '<mujoco><worldbody><body><geom size="0.1"/><body pos="0.5 0 0"><geom size="0.2"/></body></body></worldbody></mujoco>'
        >>> round(robot_radius(mujoco.MjModel.from_xml_string(xml), 1), 3)
        0.7
    """
    import mujoco

    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    in_subtree = np.zeros(model.nbody, dtype=bool)
    in_subtree[body] = True
    for child in range(body + 1, model.nbody):  # MuJoCo numbers a parent before its children
        in_subtree[child] = in_subtree[model.body_parentid[child]]
    geoms = np.flatnonzero(in_subtree[model.geom_bodyid])
    if not geoms.size:
        return 0.0
    reach = np.linalg.norm(data.geom_xpos[geoms] - data.xpos[body], axis=1) + model.geom_rbound[geoms]
    return float(reach.max())


class EnvPoolCamera:
    """Renders env ``env_index`` of an :class:`~torchrl_ahrs.envs.backends.envpool.EnvPoolEnv` with EnvPool's renderer.

    EnvPool 1.2.5 renders MuJoCo tasks only into a GL context current in the calling thread, and only
    in ``rgb_array`` mode; the mode is set on the live pool before each frame because ``set_seed``
    may replace the pool.
    """

    def __init__(self, env, width: int = 320, height: int = 240, env_index: int = 0):
        self.env, self.width, self.height, self.env_index = env, width, height, env_index
        self.context = _gl_context(width, height)
        self.description = f"EnvPool's renderer for {env.task_id}, the task's default camera (not our tracking camera)"

    def __call__(self) -> np.ndarray:
        pool = self.env._pool
        pool._render_mode, pool._render_width, pool._render_height = "rgb_array", self.width, self.height
        try:
            frames = pool.render(env_ids=[self.env_index])
        except Exception as error:
            raise RenderUnavailable(f"EnvPool task {self.env.task_id} did not render: {error!r}") from error
        return np.ascontiguousarray(frames[0])

    def close(self) -> None:
        self.context.free()


def base_env(env: EnvBase) -> EnvBase:
    """The innermost environment under any ``TransformedEnv`` layers."""
    while hasattr(env, "base_env"):
        env = env.base_env
    return env


def make_frame_source(env: EnvBase, width: int, height: int, env_index: int = 0):
    """A callable returning frames ``[H, W, 3]`` uint8 of ``env``'s env ``env_index``; raises
    :class:`RenderUnavailable` (with the reason) for tasks that cannot render."""
    from torchrl_ahrs.envs.backends.envpool import EnvPoolEnv
    from torchrl_ahrs.envs.backends.mujoco_base import BatchedMujocoEnv

    inner = base_env(env)
    if isinstance(inner, BatchedMujocoEnv):
        _check_gl_backend()
        return TrackingCamera(inner, width, height, env_index)
    if isinstance(inner, EnvPoolEnv):
        return EnvPoolCamera(inner, width, height, env_index)
    raise RenderUnavailable(f"{type(inner).__name__} has no renderer (only MuJoCo and EnvPool MuJoCo tasks render)")


def clip_format(requested: str = "auto") -> str:
    """``"mp4"`` or ``"gif"``: ``"auto"`` is MP4 when imageio-ffmpeg (the ``video`` extra) is installed, else GIF.

    Example:
        >>> clip_format("gif"), clip_format("auto") in ("mp4", "gif")
        ('gif', True)
    """
    if requested != "auto":
        return requested
    import importlib.util

    return "mp4" if importlib.util.find_spec("imageio_ffmpeg") is not None else "gif"


def write_clip(frames: list[np.ndarray] | np.ndarray, path: str | Path, fps: float) -> Path:
    """Writes frames ``[T, H, W, 3]`` uint8 as a GIF (Pillow) or an MP4 (imageio + imageio-ffmpeg).

    Example:
        >>> import tempfile
        >>> frames = np.zeros((3, 8, 8, 3), np.uint8)
        >>> write_clip(frames, Path(tempfile.mkdtemp()) / "clip.gif", fps=10).exists()
        True
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frames = [np.asarray(frame, dtype=np.uint8) for frame in frames]
    if path.suffix == ".gif":
        from PIL import Image

        images = [Image.fromarray(frame) for frame in frames]
        duration_ms = round(1000.0 / fps)  # GIF stores per-frame delays in ms
        images[0].save(path, save_all=True, append_images=images[1:], duration=duration_ms, loop=0, optimize=True)
    elif path.suffix == ".mp4":
        try:
            import imageio.v2 as imageio
            import imageio_ffmpeg  # noqa: F401  (imageio's MP4 writer needs it)
        except ImportError as error:
            raise RenderUnavailable("MP4 needs the package imageio-ffmpeg; use video_format=gif") from error
        imageio.mimwrite(path, frames, fps=fps, macro_block_size=1)  # type: ignore[arg-type]  # list is invariant
    else:
        raise ValueError(f"unknown clip format {path.suffix!r}; use .gif or .mp4")
    return path
