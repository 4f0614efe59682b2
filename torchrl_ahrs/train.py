"""``python -m torchrl_ahrs.train task=<task> method=<method> [key=value ...]``: train one run.

The command is :mod:`torchrl_ahrs.app.train.command` (the run directory, the command-line checks, its
errors) and the iteration :mod:`torchrl_ahrs.app.train.iteration`; this entry point chooses the offscreen
GL backend and declares the command. Configuration errors are one line on stderr with exit status 2; any
other crash is printed with every secret of the config and the command line replaced by ``<redacted>``
(Hydra's own "Error executing job with overrides" line would print ``llm.api_key=...`` in clear), exit
status 1.
"""

# ruff: noqa: E402  (the GL backend must be chosen before the imports below load mujoco)
from __future__ import annotations

from torchrl_ahrs.evaluation.render import select_gl_backend

select_gl_backend()  # MuJoCo reads MUJOCO_GL once, at import: choose offscreen GL before anything imports it

from torchrl_ahrs.app.shared.cli import hydra_command
from torchrl_ahrs.app.shared.redaction import redact
from torchrl_ahrs.app.train.command import ERRORS, check_arguments, run
from torchrl_ahrs.app.train.iteration import train

__all__ = ["main", "redact", "train"]

main = hydra_command("train", "config", run, ERRORS, check_arguments=check_arguments)

if __name__ == "__main__":
    main()
