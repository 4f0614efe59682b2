"""Paper-style report of a sweep: ``python -m torchrl_ahrs.report <sweep dir> [<sweep dir> ...] [--out DIR]``.

The report (tables, figures, ``report.md``) is :mod:`torchrl_ahrs.app.report.report`; this entry point parses
the command line, refuses a sweep directory that does not exist (one line, exit status 2) and prints
which runs are not ok.

argparse, not :func:`~torchrl_ahrs.app.shared.cli.hydra_command` (the other commands' one declaration):
the command takes sweep directories, not a config tree, and a Hydra command would create an ``outputs/``
run directory of its own for every report.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from torchrl_ahrs.app.report.report import write_report

__all__ = ["main", "write_report"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("sweep_dir", type=Path, nargs="+", help="sweep directories (hydra.sweep.dir), pooled")
    parser.add_argument("--out", type=Path, default=None, help="output directory (default <sweep dir>/report)")
    parser.add_argument("--title", default=None, help="report title (default: the sweep directory's name)")
    args = parser.parse_args(argv)
    for sweep_dir in args.sweep_dir:
        if not sweep_dir.is_dir():
            print(f"error: {sweep_dir} is not a directory", file=sys.stderr)
            return 2
    out_dir = args.out or args.sweep_dir[0] / "report"
    tables = write_report(list(args.sweep_dir), out_dir, args.title)
    not_ok = [row for row in tables["runs"] if row["status"] != "ok"]
    print(f"{len(tables['runs'])} runs, {len(not_ok)} not ok; report in {out_dir / 'report.md'}")
    for row in not_ok:
        print(f"  not ok: {row['task']} {row['method']} seed {row['seed']}: {row['status']} ({row['reason']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
