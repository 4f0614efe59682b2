"""``python -m torchrl_ahrs.evaluate run=<run dir> [episodes=N] [video=true]``: evaluate a trained run.

The evaluation is :mod:`torchrl_ahrs.app.evaluate.evaluate`; this entry point chooses the offscreen GL backend,
composes ``conf/evaluate.yaml`` and turns errors into one line on stderr: exit status 2 for a run or an
option that cannot be evaluated, 3 when the clip cannot be rendered here.

Hydra (not argparse) so that the command reads like ``train``'s (``key=value`` overrides, the same
error style) and every option is documented in one file, ``conf/evaluate.yaml``.
"""

# ruff: noqa: E402  (the GL backend must be chosen before the imports below load mujoco)
from __future__ import annotations

from torchrl_ahrs.evaluation.render import select_gl_backend

select_gl_backend()  # MuJoCo reads MUJOCO_GL once, at import: choose offscreen GL before anything imports it

from torchrl_ahrs.app.evaluate.evaluate import evaluate, render_clip, run
from torchrl_ahrs.app.evaluate.policy import EvaluationError
from torchrl_ahrs.app.shared.cli import hydra_command
from torchrl_ahrs.evaluation.render import RenderUnavailable

__all__ = ["evaluate", "main", "render_clip"]

main = hydra_command("evaluate", "evaluate", run, {EvaluationError: (2, "{}"), RenderUnavailable: (3, "no video: {}")})

if __name__ == "__main__":
    main()
