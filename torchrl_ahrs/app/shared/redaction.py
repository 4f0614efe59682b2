"""Keeping secrets (API keys, tokens) out of the files Hydra writes into a run directory.

Hydra saves the composed config and the command-line overrides under ``<run dir>/.hydra/``
(``config.yaml``, ``hydra.yaml``, ``overrides.yaml``; ``multirun.yaml`` in a sweep directory), so
``llm.api_key=sk-...`` on the command line would land there verbatim. :class:`RedactHydraOutput`,
registered in ``conf/config.yaml`` under ``hydra.callbacks``, rewrites those files right after Hydra
writes them (before the job starts) with every secret value replaced by ``<redacted>``.

A field is secret when its last name part contains ``secret`` or ``password`` or ends in ``api_key``,
``apikey`` or ``token`` (so ``max_tokens`` is not), except names ending in ``_env`` (they hold the
*name* of an environment variable, which a resumed run needs). Redaction is by value: every occurrence of a secret value in those files is
replaced, so it also reaches ``hydra.job.override_dirname`` and any interpolated copy.
"""

from __future__ import annotations

import logging
import os
import re
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from torchrl_ahrs.app.shared.run_dir import HYDRA_FILES, MULTIRUN, REDACTED

log = logging.getLogger(__name__)

SECRET_NAME = re.compile(r"secret|passw(or)?d|api_?key$|token$")  # searched in the lower-case last name part


def is_secret_key(key: Any) -> bool:
    """True for a config field name that holds a secret (``llm.api_key``), false for ``api_key_env``.

    Example:
        >>> [is_secret_key(name) for name in ("llm.api_key", "hf_token", "client_secret", "api_key_env", "max_tokens")]
        [True, True, True, False, False]
    """
    if not isinstance(key, str):
        return False
    name = key.lstrip("+~").rsplit(".", 1)[-1].lower()  # "+llm.api_key" -> "api_key"
    return not name.endswith("_env") and SECRET_NAME.search(name) is not None


def secret_values(config: Any, overrides: Iterable[str] = ()) -> set[str]:
    """Every secret value in a plain/OmegaConf config tree and in ``key=value`` override strings.

    Example:
        >>> sorted(secret_values({"llm": {"api_key": "sk-1", "api_key_env": "K"}}, ["db.password=hunter2", "seed=1"]))
        ['hunter2', 'sk-1']
    """
    if OmegaConf.is_config(config):
        try:
            config = OmegaConf.to_container(config, resolve=True)
        except Exception:  # noqa: BLE001 (a missing/unresolvable value: take the raw tree)
            config = OmegaConf.to_container(config, resolve=False)
    found: set[str] = set()

    def walk(node: Any) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                if is_secret_key(key) and isinstance(value, str | int) and not isinstance(value, bool):
                    found.add(str(value))
                else:
                    walk(value)
        elif isinstance(node, list):
            for value in node:
                walk(value)

    walk(config)
    for override in overrides:
        key, separator, value = str(override).partition("=")
        if separator and is_secret_key(key):
            found.add(value.strip("'\""))
    return {value for value in found if len(value) > 3 and value not in (REDACTED, "null", "None")}


def redact(text: str, cfg: Any, overrides: Iterable[str] | None = None) -> str:
    """``text`` with every secret of ``cfg``, of the command line (``overrides``, default ``sys.argv[1:]``)
    and of credential-like environment variables replaced by ``<redacted>``.

    Example:
        >>> redact("key sk-abcdef failed", {"llm": {"api_key": "sk-abcdef"}}, [])
        'key <redacted> failed'
    """
    secrets = secret_values(cfg, sys.argv[1:] if overrides is None else overrides)
    secrets |= {
        value
        for name, value in os.environ.items()
        if any(mark in name.upper() for mark in ("KEY", "TOKEN", "SECRET", "PASSWORD")) and len(value) > 7
    }
    for secret in sorted(secrets, key=len, reverse=True):  # longest first: a secret may contain another
        text = text.replace(secret, REDACTED)
    return text


class RedactingStream:
    """A text stream that replaces each of ``secrets`` before writing: Hydra's own messages (a composition
    error quotes the override, ``+llm.api_key=sk-...``) are printed before any of our code could catch them.

    Example:
        >>> import io
        >>> stream = RedactingStream(io.StringIO(), {"sk-abcdef"})
        >>> _ = stream.write("bad key sk-abcdef")
        >>> stream.getvalue()
        'bad key <redacted>'
    """

    def __init__(self, stream: Any, secrets: Iterable[str]):
        self.stream, self.secrets = stream, sorted(secrets, key=len, reverse=True)

    def write(self, text: str) -> int:
        for secret in self.secrets:
            text = text.replace(secret, REDACTED)
        return self.stream.write(text)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


def redact_files(paths: Iterable[Path], secrets: set[str]) -> list[Path]:
    """Replaces each secret in each existing text file (atomically); returns the files changed."""
    changed = []
    for path in paths:
        path = Path(path)
        if not secrets or not path.is_file():
            continue
        text = original = path.read_text()
        for secret in sorted(secrets, key=len, reverse=True):  # longest first: a secret may contain another
            text = text.replace(secret, REDACTED)
        if text != original:
            temporary = path.with_name(path.name + ".tmp")
            temporary.write_text(text)
            temporary.replace(path)
            changed.append(path)
    return changed


class RedactHydraOutput(Callback):
    """Hydra callback: secrets out of ``.hydra/*.yaml`` (each job) and ``multirun.yaml`` (each sweep).

    Register it in the primary config::

        hydra:
          callbacks:
            redact_secrets:
              _target_: torchrl_ahrs.app.shared.redaction.RedactHydraOutput

    Example:
        >>> import tempfile
        >>> folder = Path(tempfile.mkdtemp())
        >>> _ = (folder / "overrides.yaml").write_text("- llm.api_key=sk-abcdef\\n- seed=1\\n")
        >>> [path.name for path in redact_files([folder / "overrides.yaml"], secret_values({}, ["llm.api_key=sk-abcdef"]))]
        ['overrides.yaml']
        >>> (folder / "overrides.yaml").read_text()
        '- llm.api_key=<redacted>\\n- seed=1\\n'
    """

    def on_job_start(self, config: DictConfig, **kwargs: Any) -> None:
        hydra = config.hydra
        if hydra.output_subdir is None:
            return
        folder = Path(hydra.runtime.output_dir) / hydra.output_subdir
        secrets = secret_values(config, _raw_overrides(hydra))
        changed = redact_files([folder / name for name in HYDRA_FILES], secrets)
        if changed:
            log.info("redacted %d secret value(s) in %s", len(secrets), ", ".join(path.name for path in changed))

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        secrets = secret_values(config, _raw_overrides(config.hydra))
        redact_files([Path(config.hydra.sweep.dir) / MULTIRUN], secrets)


def _raw_overrides(hydra: Any) -> list[str]:
    """The command-line overrides as typed: ``seed=${oc.env:NOPE}`` is a string here, not an interpolation
    to resolve (which would fail before the run's own one-line error)."""
    return [str(item) for item in OmegaConf.to_container(hydra.overrides.task, resolve=False)]  # type: ignore[union-attr]
