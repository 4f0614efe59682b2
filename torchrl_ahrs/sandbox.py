"""Command line of the sandbox for LLM-written code.

``python -m torchrl_ahrs.sandbox check FILE.py --kind rule|aux [--task TASK]`` exits 0 when the code is
accepted (static allow-list, then validation in a limited child process) and 1 with one reason per
problem when it is refused. An auxiliary reward is called on real transitions of its task (``--task``,
else the task named in a generated file's header or a shipped file's name; without a task, on
synthetic ``{"observation", "action"}`` inputs). See :mod:`torchrl_ahrs.llm.sandbox` for what is allowed.

Example:
    >>> import subprocess, sys
    >>> from torchrl_ahrs.scheduling.rules import DEFAULT_REPOSITORY
    >>> subprocess.run([sys.executable, "-m", "torchrl_ahrs.sandbox", "check", str(DEFAULT_REPOSITORY),
    ...                 "--kind", "rule", "--static-only"]).returncode
    0
"""

from __future__ import annotations

import argparse
import sys

from torchrl_ahrs.app.auxiliary import infer_aux_task, validate_aux_file
from torchrl_ahrs.llm.sandbox import check_file


def _aux_task(args: argparse.Namespace) -> dict | None:
    """The task config whose real transitions an auxiliary reward is validated on (None: synthetic inputs)."""
    from omegaconf import OmegaConf

    from torchrl_ahrs.envs.registry import load_task_config

    name = args.task or infer_aux_task(args.file)
    return OmegaConf.to_container(load_task_config(name), resolve=True) if name else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m torchrl_ahrs.sandbox", description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    check = commands.add_parser("check", help="check a file of LLM-written code")
    check.add_argument("file", help="python file to check")
    check.add_argument("--kind", choices=["rule", "aux"], required=True, help="weight rules or an auxiliary reward")
    check.add_argument("--static-only", action="store_true", help="skip the child-process validation")
    check.add_argument("--task", default=None, help="aux: validate on real transitions of this task")
    args = parser.parse_args(argv)
    try:
        task = _aux_task(args) if args.kind == "aux" and not args.static_only else None
        if task is not None:
            verdict = validate_aux_file(args.file, task)
        else:
            verdict = check_file(args.file, args.kind, run_child=not args.static_only)
    except OSError as error:
        print(f"refused: cannot read {args.file}: {error}")
        return 1
    if verdict.ok:
        print(f"accepted: {args.file} ({args.kind}; functions: {', '.join(verdict.functions)})")
        return 0
    print(f"refused: {args.file} ({args.kind})")
    for reason in verdict.reasons:
        print(f"  - {reason}")
    return 1


if __name__ == "__main__":
    sys.exit(main())
