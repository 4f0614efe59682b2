"""The application layer: one subpackage ("room") per command, and what several commands share.

- ``shared/``: the config checks and translation to typed settings (``config``, ``settings``), the run
  directory layout (``run_dir``), secrets redaction, the auxiliary-reward wiring, the error type and
  :func:`~torchrl_ahrs.app.shared.cli.hydra_command`, the one way a Hydra command is declared;
- ``train/``: ``train`` and ``sweep`` (building a run, the iteration, checkpoints, start-up checks, the
  periodic video) and reading what a run wrote (``runs``);
- ``evaluate/``: ``evaluate`` and ``export`` (loading a trained policy);
- ``report/``: ``report``;
- ``generate/``: ``generate_rules`` and ``generate_aux``.

A room imports ``shared`` and, to read or start what ``train`` writes, ``train``; never another room
(``tests/package/test_architecture.py`` checks it). The root modules (``torchrl_ahrs/train.py`` ...) declare the
commands.
"""
