"""``python -m torchrl_ahrs.export run=<run dir>``: the trained policy as TorchScript and ONNX files.

The export is :mod:`torchrl_ahrs.app.evaluate.export`; this entry point composes ``conf/export.yaml`` and turns errors
into one line on stderr with exit status 2 (a run that has no policy, a format that cannot be written here).

Example (after ``python -m torchrl_ahrs.train task=quadcopter hydra.run.dir=runs/quad``)::

    python -m torchrl_ahrs.export run=runs/quad
    python -c "import torch; print(torch.jit.load('runs/quad/export/policy.pt')(torch.zeros(1, 13)))"
"""

from __future__ import annotations

from torchrl_ahrs.app.evaluate.export import ExportError, export, run
from torchrl_ahrs.app.evaluate.policy import EvaluationError
from torchrl_ahrs.app.shared.cli import hydra_command

__all__ = ["export", "main"]

main = hydra_command("export", "export", run, {EvaluationError: (2, "{}"), ExportError: (2, "{}")})

if __name__ == "__main__":
    main()
