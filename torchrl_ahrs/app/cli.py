"""The one way a Hydra command enters: compose the packaged config, run the command, and turn the errors
it expects into one line on stderr with the command's exit status (no traceback for a user's mistake)."""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable, Mapping

import hydra
from omegaconf import DictConfig

CONFIG_PATH = "pkg://torchrl_ahrs.conf"  # conf/, installed inside the wheel as torchrl_ahrs.conf

# exception type -> (exit status, text printed after "error: ")
ErrorMap = Mapping[type[Exception], tuple[int, str]]


def hydra_command(
    config_name: str, run: Callable[[DictConfig], int], errors: ErrorMap | None = None
) -> Callable[[], None]:
    """A ``main()`` that composes ``conf/<config_name>.yaml`` with the command-line overrides and exits with
    the status ``run(cfg)`` returns; an exception of a type in ``errors`` is printed as
    ``error: <prefix><message>`` and exits with its status.

    Example:
        >>> main = hydra_command("config", lambda cfg: 0, {ValueError: (2, "")})
        >>> callable(main)
        True
    """
    errors = dict(errors or {})

    @functools.wraps(run)  # Hydra names the job (hydra.job.name, its log file) after run's module
    def task(cfg: DictConfig) -> None:
        try:
            status = run(cfg)
        except tuple(errors) as error:
            status, prefix = next(errors[kind] for kind in type(error).__mro__ if kind in errors)
            print(f"error: {prefix}{error}", file=sys.stderr)
        if status:
            sys.exit(status)

    return hydra.main(config_path=CONFIG_PATH, config_name=config_name, version_base="1.3")(task)
