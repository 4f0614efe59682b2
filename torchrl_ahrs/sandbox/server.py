"""The isolated half of the sandbox: a worker that forks one limited child per check.

``python -m torchrl_ahrs.sandbox.server`` is started once per parent process by
:mod:`torchrl_ahrs.sandbox.isolation` (with API keys and tokens removed from its environment). It
imports torch once, runs no untrusted code itself, and for each request forks a child that

1. points stdin/stdout/stderr at ``/dev/null`` (the parent's protocol pipe is out of reach);
2. loads the request's inputs, then lowers its limits with ``resource.setrlimit``: CPU seconds
   (``RLIMIT_CPU``; the soft limit raises ``SIGXCPU``, turned into an exception naming the function),
   address space (``RLIMIT_AS``, relative to what the child already maps), no file creation or growth
   (``RLIMIT_FSIZE = 0``), a handful of file descriptors (``RLIMIT_NOFILE``), no core dumps;
3. installs an audit hook (``sys.addaudithook``, PEP 578) that refuses sockets, subprocesses,
   ``os.system``/``exec``/``fork``/``kill``, file writes and deletions, reads outside the Python
   installation, ``ctypes``, and raising the limits again;
4. runs :func:`torchrl_ahrs.sandbox.cases.validate` and writes its JSON report to a pipe.

The worker waits for the report with a wall-clock deadline and kills the child when it passes.
Forking a process that already imported torch takes milliseconds, so a check costs far less than a
fresh interpreter; a fresh child per check means nothing one file does survives into the next.

Protocol on stdin/stdout: :mod:`~torchrl_ahrs.sandbox.protocol`. Requests are pickles from the trusted
parent; replies are JSON (the parent never unpickles what a child produced).
"""

from __future__ import annotations

import inspect
import io
import json
import os
import pickle
import resource
import select
import signal
import socket  # noqa: F401  (warm: hostile code's `import socket` then meets the socket.* audit refusals by name)
import sys
import time
from typing import Any, BinaryIO

import torch

from torchrl_ahrs.sandbox.cases import CpuLimitExceeded, validate, warm_up_lazy_imports
from torchrl_ahrs.sandbox.guards import SandboxRefusal
from torchrl_ahrs.sandbox.protocol import read_message, write_message

MAX_REPORT_BYTES = 1 << 20

# Audit events (https://docs.python.org/3/library/audit_events.html) refused in the child, by prefix.
REFUSED_EVENTS: tuple[str, ...] = (
    "socket.",
    "subprocess.",
    "os.system",
    "os.exec",
    "os.posix_spawn",
    "os.spawn",
    "os.fork",
    "os.forkpty",
    "os.kill",
    "os.killpg",
    "os.remove",
    "os.unlink",
    "os.rename",
    "os.rmdir",
    "os.mkdir",
    "os.chmod",
    "os.chown",
    "os.truncate",
    "os.symlink",
    "os.link",
    "os.putenv",
    "os.unsetenv",
    "os.chdir",
    "os.listdir",
    "os.scandir",
    "pty.",
    "shutil.",
    "ctypes.",
    "mmap.",
    "fcntl.",
    "urllib.",
    "http.",
    "ftplib.",
    "smtplib.",
    "webbrowser.",
    "sqlite3.",
    "resource.setrlimit",
    "resource.prlimit",
    "sys.addaudithook",
    "sys.settrace",
    "sys.setprofile",
    "sys._getframe",
    "gc.get_",
    "pickle.find_class",
)
_WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC
_READABLE_ROOTS = tuple({sys.prefix, sys.base_prefix, sys.exec_prefix, os.path.dirname(os.path.dirname(__file__))})


def audit_refusal(event: str, args: tuple) -> str | None:
    """Why the child refuses audit ``event`` (one line), or None.

    Example:
        >>> audit_refusal("socket.connect", ()), audit_refusal("open", ("/tmp/x", "w", 0))
        ('socket.connect is refused in the sandbox', 'open for writing is refused in the sandbox: /tmp/x')
        >>> audit_refusal("open", ("/etc/passwd", "r", 0))
        'open outside the Python installation is refused in the sandbox: /etc/passwd'
    """
    if event.startswith(REFUSED_EVENTS):
        return f"{event} is refused in the sandbox"
    if event == "open" and args:
        path, mode, flags = (list(args) + [None, None])[:3]
        if (isinstance(mode, str) and any(c in mode for c in "wax+")) or (
            isinstance(flags, int) and flags & _WRITE_FLAGS
        ):
            return f"open for writing is refused in the sandbox: {path}"
        if isinstance(path, (str, bytes)):
            text = os.path.realpath(os.fsdecode(path))
            if not text.startswith(_READABLE_ROOTS):
                return f"open outside the Python installation is refused in the sandbox: {text}"
    return None


def _audit_hook(event: str, args: tuple) -> None:
    refusal = audit_refusal(event, args)
    if refusal is not None:
        raise SandboxRefusal(refusal)


def _on_cpu_limit(signum, frame):
    raise CpuLimitExceeded("CPU-time limit exceeded")


def install_limits(cpu_seconds: int | None, memory_bytes: int) -> None:
    """Lowers this process's limits (see the module docstring); only ever called in an isolated process.

    ``cpu_seconds=None`` sets no ``RLIMIT_CPU`` (a serving process bounds each call with a timer instead).

    Example:
        >>> import subprocess, sys
        >>> code = ("import resource; from torchrl_ahrs.sandbox.server import install_limits; "
        ...         "install_limits(1, 1 << 28); print(resource.getrlimit(resource.RLIMIT_FSIZE))")
        >>> subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout
        '(0, 0)\\n'
    """
    if cpu_seconds is not None:
        used = resource.getrusage(resource.RUSAGE_SELF)
        cpu_now = int(used.ru_utime + used.ru_stime) + 1
        resource.setrlimit(resource.RLIMIT_CPU, (cpu_now + cpu_seconds, cpu_now + cpu_seconds + 1))
    with open("/proc/self/statm") as statm:  # first field: total program size in pages
        virtual_now = int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    resource.setrlimit(resource.RLIMIT_AS, (virtual_now + memory_bytes, virtual_now + memory_bytes))
    resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))  # no byte may be written to any file
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    highest_fd = max(int(name) for name in os.listdir("/proc/self/fd"))
    resource.setrlimit(resource.RLIMIT_NOFILE, (highest_fd + 4, highest_fd + 4))  # lazy imports need one
    signal.signal(signal.SIGXCPU, _on_cpu_limit)
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write then fails with EFBIG instead of killing


def _load_unrestricted(source: str, filename: str = "<unrestricted>") -> dict[str, Any]:
    """Plain ``exec`` without RestrictedPython: tests use it to check the process isolation alone."""
    namespace: dict[str, Any] = {"__name__": "unrestricted"}
    exec(compile(source, filename, "exec"), namespace)  # noqa: S102 (test-only; still inside the limited child)
    return {name: value for name, value in namespace.items() if inspect.isfunction(value)}


def _child(request: dict, result_fd: int) -> None:
    devnull = os.open(os.devnull, os.O_RDWR)
    for target in (0, 1, 2):
        os.dup2(devnull, target)
    os.close(devnull)
    torch.set_num_threads(1)
    inputs = torch.load(io.BytesIO(request["inputs"]), weights_only=True) if request.get("inputs") else None
    warm_up_lazy_imports()  # np.median's lazy numpy.ma import lists a directory: done before the audit hook
    install_limits(request["cpu_seconds"], request["memory_bytes"])
    sys.addaudithook(_audit_hook)
    loader = None if request.get("restricted", True) else _load_unrestricted
    report = validate(
        request["source"],
        request["kind"],
        inputs,
        request.get("num_components"),
        loader=loader,
        batch_size=request.get("batch_size"),
    )
    payload = json.dumps(report).encode()[:MAX_REPORT_BYTES]
    while payload:
        payload = payload[os.write(result_fd, payload) :]


def _signal_reason(status: int) -> str:
    if os.WIFSIGNALED(status):
        number = os.WTERMSIG(status)
        why: dict[int, str] = {
            signal.SIGKILL: "killed (CPU-time or memory limit)",
            signal.SIGXCPU: "CPU-time limit exceeded",
        }
        return f"validation process {why.get(number, f'killed by signal {signal.Signals(number).name}')}"
    return f"validation process exited with status {os.WEXITSTATUS(status)} without a report"


def run_job(request: dict) -> dict:
    """Forks one limited child for ``request`` and returns its report (or why there is none).

    Example:
        >>> request = {"source": "def rule(m, v, h, w):\\n    return m\\n", "kind": "rule", "num_components": 2,
        ...            "inputs": None, "cpu_seconds": 2, "memory_bytes": 1 << 30, "wall_seconds": 20}
        >>> run_job(request)["ok"]
        True
    """
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: never returns into the server loop
        os.close(read_fd)
        code = 0
        try:
            _child(request, write_fd)
        except BaseException:  # noqa: BLE001 (any escape ends the child; the parent reports it)
            code = 70
        os._exit(code)
    os.close(write_fd)
    deadline = time.monotonic() + float(request["wall_seconds"])
    chunks, size, timed_out = [], 0, False
    try:
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                timed_out = True
                break
            ready, _, _ = select.select([read_fd], [], [], remaining)
            if not ready:
                continue
            chunk = os.read(read_fd, 65536)
            if not chunk:
                break
            size += len(chunk)
            if size <= MAX_REPORT_BYTES:
                chunks.append(chunk)
    finally:
        os.close(read_fd)
    if timed_out:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        return {
            "ok": False,
            "reasons": [f"validation did not finish within {request['wall_seconds']:g} s of wall time"],
        }
    _, status = os.waitpid(pid, 0)
    try:
        report = json.loads(b"".join(chunks))
    except ValueError:
        return {"ok": False, "reasons": [_signal_reason(status)]}
    return report


def serve(stdin: BinaryIO, stdout: BinaryIO) -> None:
    """Answers requests until the parent closes stdin (also when the parent dies).

    Example:
        >>> import io, json, pickle
        >>> from torchrl_ahrs.sandbox.protocol import read_message
        >>> request = {"source": "def rule(m, v, h, w):\\n    return m\\n", "kind": "rule", "num_components": 2,
        ...            "inputs": None, "cpu_seconds": 2, "memory_bytes": 1 << 30, "wall_seconds": 20}
        >>> requests, replies = io.BytesIO(), io.BytesIO()
        >>> write_message(requests, pickle.dumps(request)); _ = requests.seek(0)
        >>> serve(requests, replies); _ = replies.seek(0)
        >>> json.loads(read_message(replies))["ok"]
        True
    """
    torch.set_num_threads(1)  # no intra-op thread pool exists before the first fork
    while (message := read_message(stdin)) is not None:
        try:
            report = run_job(pickle.loads(message))  # noqa: S301 (from the parent that started us)
        except Exception as error:  # noqa: BLE001 (the worker must keep serving)
            report = {"ok": False, "reasons": [f"sandbox worker error: {type(error).__name__}: {error}"]}
        write_message(stdout, json.dumps(report).encode())


if __name__ == "__main__":
    serve(sys.stdin.buffer, sys.stdout.buffer)
