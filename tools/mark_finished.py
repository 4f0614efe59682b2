#!/usr/bin/env python3
"""Writes ``finished.json`` into every finished run directory below the given directories that lacks one, from
its checkpoint (runs trained before the marker existed), so the runs can be committed without checkpoints.

Usage::

    python tools/mark_finished.py benchmarks/results/faithful/runs
"""

from __future__ import annotations

import sys
from pathlib import Path

import yaml

from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.app.train.checkpoint import collected_frames, mark_finished
from torchrl_ahrs.app.train.runs import find_run_dirs


def main(roots: list[str]) -> int:
    marked = 0
    for root in roots:
        for path in find_run_dirs(Path(root)):
            directory = RunDirectory(path)
            if directory.finished.is_file() or not directory.checkpoint.is_file() or not directory.config.is_file():
                continue
            total = int((yaml.safe_load(directory.config.read_text()) or {})["trainer"]["total_frames"])
            frames = collected_frames(path)
            if frames is not None and frames >= total:
                mark_finished(path, frames, total)
                marked += 1
    print(f"marked {marked} finished run(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
