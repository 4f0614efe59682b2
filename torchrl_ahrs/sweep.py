"""Sweeps over methods x tasks x seeds: ``python -m torchrl_ahrs.sweep +sweep=<profile> [overrides]``.

The train command (:mod:`torchrl_ahrs.app.train.command`) declared in ``--multirun`` mode: the same
run, checks and errors as ``python -m torchrl_ahrs.train -m``, and the same job name (each run's log is
``train.log``).

Profiles (``conf/sweep/``, packaged as ``torchrl_ahrs.conf``):

- ``smoke``: 2 tasks x 2 methods x 2 seeds, 4096 frames each (about a minute on 2 cores).
- ``paper``: 4 methods x 2 tasks x 3 seeds at 81 920 frames per run, the budget a 2-core CPU affords
  (about 13 minutes; see ``benchmarks/SWEEPS.md``).

Launchers (``conf/hydra/launcher/``): ``local`` (joblib, 2 jobs; the profiles' default) and ``slurm``
(submitit), e.g. ``+sweep=paper hydra/launcher=slurm hydra.launcher.partition=<partition>``.

Every run lands in ``<hydra.sweep.dir>/<task>/<method>/seed_<seed>``; then
``python -m torchrl_ahrs.report <hydra.sweep.dir>`` writes the tables and figures.

Example::

    python -m torchrl_ahrs.sweep +sweep=smoke hydra.sweep.dir=outputs/sweeps/smoke
"""

# ruff: noqa: E402  (the GL backend must be chosen before the imports below load mujoco)
from __future__ import annotations

from torchrl_ahrs.evaluation.render import select_gl_backend

select_gl_backend()  # MuJoCo reads MUJOCO_GL once, at import: choose offscreen GL before anything imports it

from torchrl_ahrs.app.shared.cli import hydra_command
from torchrl_ahrs.app.train.command import ERRORS, check_arguments, run

__all__ = ["main"]

main = hydra_command("train", "config", run, ERRORS, check_arguments=check_arguments, multirun=True)

if __name__ == "__main__":
    main()
