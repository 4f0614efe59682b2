"""Sweeps over methods x tasks x seeds: ``python -m torchrl_ahrs.sweep +sweep=<profile> [overrides]``.

A thin front to ``torchrl_ahrs.train``'s Hydra entry point that always runs in ``--multirun`` mode. It
exists because the joblib launcher pickles the task function into fresh worker processes: run as
``python -m torchrl_ahrs.train`` that function lives in ``__main__`` and drags unpicklable module state
along; imported from here it is pickled by reference.

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

from __future__ import annotations

import sys

from torchrl_ahrs.train import main as train_main


def run(argv: list[str]) -> None:
    """Runs ``torchrl_ahrs.train.main`` with ``argv`` as Hydra overrides, in multirun mode."""
    if "--multirun" not in argv and "-m" not in argv:
        argv = ["--multirun", *argv]
    sys.argv = [sys.argv[0], *argv]
    train_main()


def main() -> None:
    """The console script ``torchrl-ahrs-sweep``: :func:`run` on the command line's arguments."""
    run(sys.argv[1:])


if __name__ == "__main__":
    main()
