"""Command line of the sandbox for LLM-written code.

``python -m torchrl_ahrs.sandbox check FILE.py --kind rule|aux`` exits 0 when the code is accepted
(RestrictedPython's static gate, then validation in the limited child) and 1 with one reason per
problem when it is refused. Options:

* ``--num-components K`` (rules): validate at the task's K (default: K = 1, 4 and 12);
* ``--inputs FILE.pt`` (aux): a ``torch.save``'d ``{name: Tensor [N, ...]}`` of real transitions;
* ``--task NAME`` (aux): collect real transitions of that task. The sandbox knows no tasks: it asks
  the provider registered under the entry-point group ``torchrl_ahrs.sandbox.aux_inputs`` (this
  project registers one in ``pyproject.toml``), which also infers the task from a generated file's
  header or a shipped file's name when ``--task`` is not given. Without a provider or a task, the
  auxiliary reward is called on synthetic ``{"observation", "action"}`` inputs;
* ``--static-only``: skip the child.

Example:
    >>> import subprocess, sys, tempfile
    >>> with tempfile.NamedTemporaryFile("w", suffix=".py") as rule:
    ...     _ = rule.write("import torch\\ndef rule(m, v, h, w):\\n    return torch.zeros(m.shape[0])\\n")
    ...     rule.flush()
    ...     subprocess.run([sys.executable, "-m", "torchrl_ahrs.sandbox", "check", rule.name, "--kind", "rule",
    ...                     "--static-only"], capture_output=True).returncode
    0
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Mapping
from importlib.metadata import entry_points

import torch

from torchrl_ahrs.sandbox.isolation import check_file, start_worker

INPUTS_GROUP = "torchrl_ahrs.sandbox.aux_inputs"

# provider(file, task or None) -> transitions {name: Tensor [N, ...]} or None (no task known)
InputsProvider = Callable[[str, "str | None"], "Mapping[str, torch.Tensor] | None"]


def installed_provider() -> InputsProvider | None:
    """The transitions provider registered under :data:`INPUTS_GROUP`, if a package registers one.

    Example:
        >>> provider = installed_provider()
        >>> provider is None or callable(provider)
        True
    """
    found = list(entry_points(group=INPUTS_GROUP))
    return found[0].load() if found else None


def main(argv: list[str] | None = None, provider: InputsProvider | None = None) -> int:
    """Runs the command line; ``provider`` overrides the registered transitions provider (tests, embedding).

    Example:
        >>> import tempfile
        >>> with tempfile.NamedTemporaryFile("w", suffix=".py") as aux:
        ...     _ = aux.write("def compute_aux_reward(obs):\\n    return obs['x'] * 2\\n"); aux.flush()
        ...     main(["check", aux.name, "--kind", "aux"], provider=lambda file, task: {"x": torch.ones(4)})
        accepted: ... (aux; functions: compute_aux_reward)
        0
    """
    parser = argparse.ArgumentParser(prog="python -m torchrl_ahrs.sandbox", description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    check = commands.add_parser("check", help="check a file of LLM-written code")
    check.add_argument("file", help="python file to check")
    check.add_argument("--kind", choices=["rule", "aux"], required=True, help="weight rules or an auxiliary reward")
    check.add_argument("--static-only", action="store_true", help="skip the child-process validation")
    check.add_argument("--num-components", type=int, default=None, help="rule: the task's number of components K")
    check.add_argument("--inputs", default=None, help="aux: torch.save'd dict of real transitions")
    check.add_argument("--task", default=None, help="aux: validate on real transitions of this task")
    args = parser.parse_args(argv)
    if not args.static_only:
        start_worker()  # its start (importing torch) overlaps reading the file and collecting transitions
    inputs = None
    try:
        if args.kind == "aux" and not args.static_only:
            if args.inputs:
                inputs = torch.load(args.inputs, weights_only=True)
            else:
                provider = provider or installed_provider()
                if provider is None and args.task:
                    print(f"refused: --task needs a transitions provider ({INPUTS_GROUP}); pass --inputs instead")
                    return 1
                inputs = provider(args.file, args.task) if provider is not None else None
        verdict = check_file(
            args.file,
            args.kind,
            run_child=not args.static_only,
            num_components=args.num_components,
            inputs=inputs,
        )
    except (OSError, UnicodeDecodeError) as error:
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
