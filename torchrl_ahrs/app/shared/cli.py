"""The one way a Hydra command is declared: :func:`hydra_command`.

Every ``python -m torchrl_ahrs.<command>`` that takes ``key=value`` overrides (train, sweep, evaluate,
export, generate_rules, generate_aux) is one call of it in its root module. The helper owns what all of
them need and what used to be written four ways (a helper, a hand-written ``@hydra.main``, ``sys.argv``
rewriting for ``--multirun``): compose the packaged config, refuse a bad command line before Hydra
composes it, keep the command line's secrets out of everything printed (Hydra's own messages included),
and turn the errors the command expects into one line on stderr with the command's exit status (no
traceback for a user's mistake; any other crash as a traceback with its secrets redacted, exit status 1).

``report`` and ``sandbox`` stay ``argparse`` commands: they take paths, not a config tree (``report <sweep
dir> ...``, ``sandbox rules <file>``), and Hydra would create an ``outputs/`` run directory for each call.
"""

from __future__ import annotations

import sys
import traceback
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

import hydra
from omegaconf import DictConfig

from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.redaction import RedactingStream, redact, secret_values

CONFIG_PATH = "pkg://torchrl_ahrs.conf"  # conf/, installed inside the wheel as torchrl_ahrs.conf

# exception type -> (exit status, message template; "{}" is the exception's text)
ErrorMap = Mapping[type[Exception], tuple[int, str]]


class Command(Protocol):
    """A command's ``main``: runs on ``argv`` (default the command line) and exits with its status."""

    def __call__(self, argv: Sequence[str] | None = None) -> None: ...


def hydra_command(
    name: str,
    config_name: str,
    run: Callable[[DictConfig], Any],
    errors: ErrorMap | None = None,
    *,
    check_arguments: Callable[[list[str]], None] | None = None,
    multirun: bool = False,
) -> Command:
    """A ``main(argv=None)`` that composes ``conf/<config_name>.yaml`` with the overrides (``argv``, default
    the command line) and runs ``run(cfg)``.

    ``run`` returns an exit status (``0``/``None`` for success) or, for a command a Hydra sweeper optimises
    (``train``), a float that is handed back to Hydra. ``name`` is the command's name: Hydra's job name
    (``hydra.job.name``, so the log file is ``<name>.log``). An exception of a type in ``errors`` is printed
    as ``error: <template with its text>`` and exits with its status. ``check_arguments`` sees the overrides
    before Hydra does; a :class:`ConfigError` it raises exits with status 2. ``multirun`` always runs in
    ``--multirun`` mode (``sweep``).

    Example:
        >>> main = hydra_command("noop", "config", lambda cfg: 0, {ValueError: (2, "{}")})
        >>> callable(main)
        True
    """
    errors = dict(errors or {})

    def task(cfg: DictConfig) -> Any:
        try:
            result = run(cfg)
        except tuple(errors) as error:
            status, template = next(errors[kind] for kind in type(error).__mro__ if kind in errors)
            print(f"error: {redact(template.format(error), cfg)}", file=sys.stderr)
            sys.exit(status)
        except Exception:  # noqa: BLE001 (printed here, redacted, instead of by Hydra with the overrides in clear)
            print(redact(traceback.format_exc(), cfg), file=sys.stderr)
            sys.exit(1)
        if isinstance(result, int) and not isinstance(result, bool):
            if result:
                sys.exit(result)
            return None
        return result

    # Hydra names the job after the task function's module (the last dotted part): the command's name
    task.__module__ = f"torchrl_ahrs.{name}"
    hydra_task = hydra.main(config_path=CONFIG_PATH, config_name=config_name, version_base="1.3")(task)

    def main(argv: Sequence[str] | None = None) -> None:
        arguments = list(sys.argv[1:] if argv is None else argv)
        if multirun and "--multirun" not in arguments and "-m" not in arguments:
            arguments = ["--multirun", *arguments]
        streams, saved_argv = (sys.stdout, sys.stderr), sys.argv
        secrets = secret_values({}, arguments)
        if secrets:  # every line this process prints, Hydra's included, without the command line's secrets
            sys.stdout, sys.stderr = RedactingStream(sys.stdout, secrets), RedactingStream(sys.stderr, secrets)
        try:
            if check_arguments is not None:
                try:
                    check_arguments(arguments)
                except ConfigError as error:
                    print(f"error: {error}", file=sys.stderr)
                    sys.exit(2)
            sys.argv = [*(sys.argv[:1] or [name]), *arguments]  # Hydra parses sys.argv itself
            hydra_task()
        finally:
            sys.argv, (sys.stdout, sys.stderr) = saved_argv, streams

    return main
