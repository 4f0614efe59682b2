"""Parent side of the process isolation: sends checks to one worker process and reads JSON back.

The worker (:mod:`torchrl_ahrs.sandbox.server`) is started on first use and reused for every later
check of this process; it forks a fresh limited child per check, so only its one-time start pays for
importing torch. It is started with the parent's environment minus anything that looks like a
credential (``*KEY*``, ``*TOKEN*``, ``*SECRET*``, ``*PASSWORD*``), one thread per library, and dies
when the parent closes its stdin (at exit, or when the parent dies).
"""

from __future__ import annotations

import atexit
import io
import json
import os
import pickle
import select
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import torch

from torchrl_ahrs.sandbox.policy import Verdict, check_source
from torchrl_ahrs.sandbox.protocol import HEADER

CPU_SECONDS = 2  # CPU time granted to the validation calls of one check
MEMORY_BYTES = 1 << 30  # address space granted on top of what the child maps after importing torch
WALL_SECONDS = 20.0  # a check's child is killed after this long, whatever it is doing
START_SECONDS = 120.0  # the worker's one-time start (imports torch) on a loaded machine
_CREDENTIAL_MARKERS = ("KEY", "TOKEN", "SECRET", "PASSWORD", "CREDENTIAL")


def _worker_environment() -> dict[str, str]:
    environment = {
        key: value for key, value in os.environ.items() if not any(mark in key.upper() for mark in _CREDENTIAL_MARKERS)
    }
    environment.update({"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"})
    return environment


class _Worker:
    """One running ``torchrl_ahrs.sandbox.server`` process and its pipes."""

    def __init__(self):
        self.stderr = tempfile.TemporaryFile()
        self.process = subprocess.Popen(
            [sys.executable, "-m", "torchrl_ahrs.sandbox.server"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.stderr,
            env=_worker_environment(),
        )
        self.started = False
        self.owner = os.getpid()  # a forked copy of this process must not share the pipes

    def _read_exactly(self, size: int, deadline: float) -> bytes:
        stdout = self.process.stdout
        assert stdout is not None
        data = b""
        while len(data) < size:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError("sandbox worker did not answer in time")
            ready, _, _ = select.select([stdout], [], [], remaining)
            if ready:
                chunk = os.read(stdout.fileno(), size - len(data))
                if not chunk:
                    raise EOFError("sandbox worker exited")
                data += chunk
        return data

    def request(self, payload: bytes, timeout: float) -> bytes:
        stdin = self.process.stdin
        assert stdin is not None
        stdin.write(HEADER.pack(len(payload)) + payload)
        stdin.flush()
        deadline = time.monotonic() + timeout + (0.0 if self.started else START_SECONDS)
        (length,) = HEADER.unpack(self._read_exactly(HEADER.size, deadline))
        reply = self._read_exactly(length, deadline)
        self.started = True
        return reply

    def stderr_tail(self) -> str:
        self.stderr.seek(0)
        lines = self.stderr.read().decode(errors="replace").strip().splitlines()
        return " | ".join(lines[-3:])

    def close(self) -> None:
        if self.process.poll() is None:
            if self.process.stdin is not None:
                self.process.stdin.close()  # the worker's read sees EOF and it exits
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.stderr.close()


_lock = threading.Lock()
_worker: _Worker | None = None


def _shutdown() -> None:
    global _worker
    with _lock:
        if _worker is not None and _worker.owner == os.getpid():
            _worker.close()
            _worker = None


atexit.register(_shutdown)


def start_worker() -> None:
    """Starts the worker now, without waiting for it (it imports torch in the background).

    A caller that will check code soon (a generator before its first LLM call, training before it
    builds environments) calls this first, so the first check does not wait for the start.

    Example:
        >>> start_worker()
        >>> check("def rule(m, v, h, w):\\n    return m\\n", "rule", num_components=2).ok
        True
    """
    with _lock:
        _ensure_worker()


def _ensure_worker() -> _Worker:
    """The running worker of this process (started if needed); call with ``_lock`` held."""
    global _worker
    if _worker is not None and _worker.owner != os.getpid():
        _worker = None  # inherited through fork (e.g. a collector process): start our own
    if _worker is None or _worker.process.poll() is not None:
        _worker = _Worker()
    return _worker


def _run(request: dict) -> dict:
    """One request through the (re)started worker; a dead or stuck worker is replaced next time."""
    global _worker
    payload = pickle.dumps(request)
    with _lock:
        worker = _ensure_worker()
        try:
            reply = worker.request(payload, timeout=float(request["wall_seconds"]) + 10.0)
        except (OSError, EOFError, TimeoutError) as error:
            tail = worker.stderr_tail()
            worker.process.kill()
            worker.close()
            _worker = None
            return {"ok": False, "reasons": [f"sandbox worker failed ({error}){': ' + tail if tail else ''}"]}
    try:
        report = json.loads(reply)
        return {
            "ok": report["ok"] is True,
            "reasons": [str(reason) for reason in report.get("reasons", [])],
            "functions": [str(name) for name in report.get("functions", [])],
        }
    except (ValueError, KeyError, TypeError, AttributeError):
        return {"ok": False, "reasons": ["sandbox worker sent an unreadable report"]}


def validate_source(
    source: str,
    kind: str,
    *,
    num_components: int | Sequence[int] | None = None,
    inputs: Mapping[str, torch.Tensor] | None = None,
    cpu_seconds: int = CPU_SECONDS,
    memory_bytes: int = MEMORY_BYTES,
    wall_seconds: float = WALL_SECONDS,
    restricted: bool = True,
    batch_size: int | None = None,
) -> Verdict:
    """Calls the functions of ``source`` in a limited child process (see :mod:`~torchrl_ahrs.sandbox.server`).

    Args:
        source: the code (the child compiles it with RestrictedPython again; this does not trust the
            caller to have run :func:`~torchrl_ahrs.sandbox.policy.check_source`).
        kind: ``"rule"`` or ``"aux"``.
        num_components: the task's K for rules (None: K = 1, 4 and 12).
        inputs: aux: real transitions ``{name: Tensor [N, ...]}`` of the task (None: synthetic).
        cpu_seconds, memory_bytes, wall_seconds: the child's limits.
        restricted: False executes without RestrictedPython, to test the isolation alone; never use it
            for code that is to be accepted.
        batch_size: aux: also call at this N, the number of environments training steps at once.

    Example:
        >>> validate_source("def rule(m, v, h, w):\\n    return m * 2\\n", "rule", num_components=3).ok
        True
    """
    buffer = io.BytesIO()
    if inputs is not None:
        torch.save({name: value.detach().cpu() for name, value in inputs.items()}, buffer)
    request = {
        "source": source,
        "kind": kind,
        "num_components": num_components,
        "inputs": buffer.getvalue() or None,
        "cpu_seconds": int(cpu_seconds),
        "memory_bytes": int(memory_bytes),
        "wall_seconds": float(wall_seconds),
        "restricted": bool(restricted),
        "batch_size": batch_size,
    }
    report = _run(request)
    return Verdict(report["ok"], report["reasons"], report.get("functions", []))


def validate_in_child(
    path: str | Path,
    kind: str,
    cpu_seconds: int = CPU_SECONDS,
    memory_bytes: int = MEMORY_BYTES,
    inputs_path: str | Path | None = None,
    *,
    num_components: int | Sequence[int] | None = None,
    batch_size: int | None = None,
) -> Verdict:
    """:func:`validate_source` on a file; ``inputs_path``: a ``torch.save``'d dict of transitions.

    Example:
        >>> import tempfile
        >>> with tempfile.NamedTemporaryFile("w", suffix=".py") as handle:
        ...     _ = handle.write("def rule(m, v, h, w):\\n    return v - m\\n"); handle.flush()
        ...     validate_in_child(handle.name, "rule").ok
        True
    """
    inputs = torch.load(inputs_path, weights_only=True) if inputs_path is not None else None
    return validate_source(
        Path(path).read_text(),
        kind,
        num_components=num_components,
        inputs=inputs,
        cpu_seconds=cpu_seconds,
        memory_bytes=memory_bytes,
        batch_size=batch_size,
    )


def check(
    source: str,
    kind: str,
    filename: str = "<llm>",
    *,
    num_components: int | Sequence[int] | None = None,
    inputs: Mapping[str, torch.Tensor] | None = None,
    run_child: bool = True,
) -> Verdict:
    """All gates: the static check (every reason at once), then, if it passes, the limited child.

    Example:
        >>> check("import torch\\ndef rule(m, v, h, w):\\n    return torch.softmax(m, 0)\\n", "rule",
        ...       num_components=11).ok
        True
        >>> check("import os\\ndef rule(m, v, h, w):\\n    return m\\n", "rule").reasons[0][:34]
        "Line 1: import of 'os' is not allo"
    """
    verdict = check_source(source, filename)
    if not verdict.ok or not run_child:
        return verdict
    return validate_source(source, kind, num_components=num_components, inputs=inputs)


def check_file(
    path: str | Path,
    kind: str,
    run_child: bool = True,
    *,
    num_components: int | Sequence[int] | None = None,
    inputs: Mapping[str, torch.Tensor] | None = None,
) -> Verdict:
    """:func:`check` on a file (reasons name the file's lines).

    Example:
        >>> from pathlib import Path
        >>> import torchrl_ahrs.sandbox as sandbox
        >>> shipped = Path(sandbox.__file__).parents[1] / "scheduling" / "default_rules.py"
        >>> check_file(shipped, "rule", run_child=False).ok
        True
    """
    source = Path(path).read_text()
    return check(source, kind, str(path), num_components=num_components, inputs=inputs, run_child=run_child)
