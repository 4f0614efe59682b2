#!/usr/bin/env python3
"""Which of the package's files one training iteration runs: the measure of issue 25's "a reader finds one
iteration in one function, and the files it touches are <= 8 besides the task's environment".

Trains a tiny ``task=cassie method=ahrs`` run (three iterations of 64 frames, a scheduler decision and a
checkpoint every iteration, so the traced iteration does everything an iteration can), lets the first
iteration warm up, and traces the second from the line ``for batch in run.collector`` of
:func:`~torchrl_ahrs.training.loop.learn` to its next pass. It prints

(a) direct: the package files a reader of ``learn()`` opens, i.e. those of the first package function reached
    from each of its lines, looking through library code (``torch``, ``tensordict``, ``torchrl``): ``loss(mb)``
    names ``training/loss.py`` although ``nn.Module.__call__`` sits in between;
(b) transitive: every package file that runs during the iteration,

each split into the task's environment and the rest. The environment is ``envs/`` and whatever runs only inside
its ``step``: the collector steps a TorchRL ``TransformedEnv``, so a reward transform the task's env carries
(``rewards/auxiliary.py``'s ``AuxiliaryReward``) is the environment's when no line of ``learn()`` reaches its
file except through an ``EnvBase`` or ``Transform`` frame. Threads started during the iteration are traced
too (they count towards (b) only).

Usage::

    python tools/iteration_files.py
"""

from __future__ import annotations

import contextlib
import inspect
import io
import sys
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

import torchrl_ahrs
from torchrl_ahrs.training import loop

PACKAGE = Path(torchrl_ahrs.__file__).parent
OVERRIDES = [
    "task=cassie",
    "method=ahrs",
    "trainer.total_frames=192",  # three iterations: warm-up, the traced one, and one that breaks the loop
    "trainer.num_envs=8",
    "trainer.frames_per_batch=64",
    "trainer.mini_batch_size=32",
    "trainer.num_epochs=2",
    "trainer.table_interval=1",
    "model.hidden_sizes=[32,32]",
    "scheduler.interval=1",
    "checkpoint.interval=1",
]
TRACED = 2  # the iteration traced: the second pass over learn()'s `for` line


@dataclass
class IterationFiles:
    """The package files (relative to ``torchrl_ahrs/``) one iteration of :func:`learn` ran."""

    direct: set[str] = field(default_factory=set)
    transitive: set[str] = field(default_factory=set)
    # direct files reached at least once other than from inside the environment's step
    outside_env_step: set[str] = field(default_factory=set)

    def environment(self, names: set[str]) -> set[str]:
        """The task's environment among ``names``: ``envs/`` files, and direct files only its step reached."""
        return {name for name in names if name.startswith("envs/") or name not in self.outside_env_step}


def _package_file(frame: FrameType) -> str | None:
    path = Path(frame.f_code.co_filename)
    return path.relative_to(PACKAGE).as_posix() if path.is_relative_to(PACKAGE) else None


def trace_iteration(run: Callable[[], Any], iteration: int = TRACED) -> IterationFiles:
    """Calls ``run()``, which must call :func:`learn` once, and returns the files of ``learn``'s ``iteration``-th
    iteration (1 = the first; its collection included)."""
    files = IterationFiles()
    code = loop.learn.__code__
    lines, start = inspect.getsourcelines(loop.learn)
    for_line = start + next(i for i, text in enumerate(lines) if text.strip() == "for batch in run.collector:")
    state = {"passes": 0, "learn": None}

    def local(frame: FrameType, event: str, arg: Any):  # line events of learn()'s frame only
        if event == "line" and frame.f_lineno == for_line:
            state["passes"] += 1
        return local

    def on_call(frame: FrameType, event: str, arg: Any):
        if frame.f_code is code:
            state["learn"] = frame
            return local
        name = _package_file(frame)
        if state["passes"] != iteration or name is None:
            return None
        files.transitive.add(name)
        caller = frame.f_back  # the first package frame up the stack: learn's makes this file a direct one
        in_env_step = _is_env_frame(frame)
        while caller is not None and _package_file(caller) is None:
            in_env_step = in_env_step or _is_env_frame(caller)
            caller = caller.f_back
        if caller is state["learn"]:
            files.direct.add(name)
            if not in_env_step:
                files.outside_env_step.add(name)
        return None

    sys.settrace(on_call)
    threading.settrace(on_call)
    try:
        run()
    finally:
        sys.settrace(None)
        threading.settrace(None)  # type: ignore[arg-type]
    if state["passes"] <= iteration:
        raise RuntimeError(f"learn() ran {state['passes']} iteration(s); {iteration + 1} are needed")
    own = Path(code.co_filename).relative_to(PACKAGE).as_posix()  # the loop's own file
    files.direct.add(own)
    files.outside_env_step.add(own)
    return files


def _is_env_frame(frame: FrameType) -> bool:
    """Whether ``frame`` is a method of a TorchRL environment or transform (the environment's step)."""
    from torchrl.envs import EnvBase, Transform

    owner = frame.f_locals.get("self")
    return isinstance(owner, (EnvBase, Transform))


def trace_cassie_ahrs() -> IterationFiles:
    """:func:`trace_iteration` of the tiny ``task=cassie method=ahrs`` run of :data:`OVERRIDES` (console output
    swallowed unless the run fails)."""
    from hydra import compose, initialize_config_module

    from torchrl_ahrs.app.train.iteration import train

    with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=OVERRIDES)
    output = io.StringIO()
    with tempfile.TemporaryDirectory() as run_dir:
        try:
            with contextlib.redirect_stdout(output), contextlib.redirect_stderr(output):
                return trace_iteration(lambda: train(cfg, Path(run_dir)))
        except BaseException:
            print(output.getvalue(), file=sys.stderr)
            raise


def split(names: set[str], files: IterationFiles | None = None) -> tuple[list[str], list[str]]:
    """``(the environment's files, the rest)``, each sorted; without ``files``, the environment is ``envs/``."""
    envs = files.environment(names) if files is not None else {name for name in names if name.startswith("envs/")}
    return sorted(envs), sorted(names - envs)


def main() -> int:
    files = trace_cassie_ahrs()
    parts = (
        (
            "(a) direct, from learn()'s frame",
            split(files.direct, files),
            "the environment (envs/, and what only its step reached)",
        ),
        ("(b) transitive", split(files.transitive), "envs/"),
    )
    for title, (envs, rest), where in parts:
        print(f"{title}: {len(envs) + len(rest)} files, {len(rest)} besides the environment, {len(envs)} in {where}")
        for group, members in (("besides the environment", rest), ("environment", envs)):
            print(f"  {group}:", *(f"\n    {name}" for name in members) or [" none"], sep="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
