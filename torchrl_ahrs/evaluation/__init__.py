"""Evaluating a trained run: per-component returns, task metrics and clips of the policy.

``python -m torchrl_ahrs.evaluate run=<run dir>`` is the command-line entry (``torchrl_ahrs/evaluate.py``).
Modules: ``policy`` (rebuild the actor from a run), ``episodes`` (run and summarise episodes, record
frames), ``task_metrics`` (per-task metrics), ``render`` (offscreen frames, clip files). Nothing is
imported here, so that ``render.select_gl_backend`` can run before anything imports ``mujoco``.
"""
