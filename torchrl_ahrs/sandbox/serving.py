"""The isolated half of a :class:`~torchrl_ahrs.sandbox.session.SandboxSession`: one process serving calls.

``python -m torchrl_ahrs.sandbox.serving`` is started by a session (with API keys and tokens removed from
its environment) and serves the functions of one file for as long as the run uses them: the rules of a
repository at each decision, an auxiliary reward at each environment step. Before it runs a line of that
file it

1. maps the session's shared-memory block (a ``memfd`` it inherited; inputs and outputs cross there; the pipe carries small JSON);
2. warms up what torch and numpy import lazily (``np.median`` imports ``numpy.ma``, which lists a directory),
   so ordinary calls do not meet the audit hook's refusals;
3. lowers its limits as the check's child does (:func:`~torchrl_ahrs.sandbox.server.install_limits`):
   address space (the memory cap), no file writes, a handful of descriptors, no core dumps, and installs
   the same audit hook (no sockets, subprocesses, ``ctypes``, file writes, reads outside the Python
   installation, raising the limits again).

Each call then runs under a CPU-time timer (``ITIMER_PROF``, the per-call counterpart of the check's
``RLIMIT_CPU``), and its output passes :func:`~torchrl_ahrs.sandbox.cases.output_contract`, the same
function the check applies. The session kills this process when a call overruns its wall clock.
"""

from __future__ import annotations

import inspect
import json
import mmap
import os
import signal
import sys
from typing import Any, BinaryIO

import numpy
import torch

from torchrl_ahrs.sandbox.cases import CpuLimitExceeded, output_contract, warm_up_lazy_imports
from torchrl_ahrs.sandbox.guards import SandboxRefusal
from torchrl_ahrs.sandbox.protocol import read_message, write_message
from torchrl_ahrs.sandbox.server import _audit_hook, _load_unrestricted, install_limits

MAX_ERROR_CHARS = 300  # a raised message crosses the pipe (and reaches logs) at most this long


def _on_cpu_timer(signum, frame):
    raise CpuLimitExceeded("CPU-time limit exceeded")


def _dtype(name: str) -> torch.dtype:
    dtype = getattr(torch, name.removeprefix("torch."))
    if not isinstance(dtype, torch.dtype):
        raise ValueError(f"not a dtype: {name}")
    return dtype


def tensor_at(buffer: memoryview, spec: dict) -> torch.Tensor:
    """A tensor view of ``buffer`` described by ``{"dtype", "shape", "offset"}`` (no copy).

    Example:
        >>> block = bytearray(16)
        >>> view = tensor_at(memoryview(block), {"dtype": "float32", "shape": [2], "offset": 8})
        >>> view[:] = 1.0; view.tolist(), block[8:12] != bytes(4)
        ([1.0, 1.0], True)
    """
    dtype, shape = _dtype(spec["dtype"]), tuple(spec["shape"])
    count = int(numpy.prod(shape)) if shape else 1
    if count == 0:
        return torch.empty(shape, dtype=dtype)
    return torch.frombuffer(buffer, dtype=dtype, count=count, offset=int(spec["offset"])).view(shape)


def decode_arguments(buffer: memoryview, layout: list) -> list[Any]:
    """Views of the block for the call's arguments, from their layout: ``{"tensor": spec}``,
    ``{"dict": {name: spec}}`` or ``{"value": x}``. They alias the block, which the session rewrites before
    every call, so they are built once per layout (restricted code works on private copies of them)."""
    arguments: list[Any] = []
    for entry in layout:
        if "tensor" in entry:
            arguments.append(tensor_at(buffer, entry["tensor"]))
        elif "dict" in entry:
            arguments.append({name: tensor_at(buffer, spec) for name, spec in entry["dict"].items()})
        else:
            arguments.append(entry.get("value"))
    return arguments


def _one_line(text: str) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= MAX_ERROR_CHARS else text[:MAX_ERROR_CHARS] + f"... ({len(text)} chars)"


def call_function(fn, buffer: memoryview, arguments: list[Any], request: dict, cpu_seconds: float) -> dict:
    """Runs one call on the shared block; the reply says where the output is, or why there is none."""
    arguments = [dict(value) if isinstance(value, dict) else value for value in arguments]  # its own dicts
    signal.setitimer(signal.ITIMER_PROF, cpu_seconds)
    try:
        output = fn(*arguments)
    except CpuLimitExceeded:
        return {"ok": False, "error": f"CPU-time limit exceeded ({cpu_seconds:g} s per call)"}
    except SandboxRefusal as error:
        return {"ok": False, "error": f"refused while running: {_one_line(str(error))}"}
    except MemoryError:
        return {"ok": False, "error": "memory limit exceeded"}
    except Exception as error:  # noqa: BLE001 (the file's failure is the reply, the worker keeps serving)
        text = str(error)
        if "can't allocate memory" in text.lower() or "not enough memory" in text.lower():
            return {"ok": False, "error": "memory limit exceeded"}
        return {"ok": False, "error": f"raised {type(error).__name__}: {_one_line(text)}"}
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
    tensor, problem = output_contract(output, tuple(request["expected_shape"]))
    if tensor is None:
        return {"ok": False, "error": problem}
    offset, size = int(request["output_offset"]), tensor.numel() * tensor.element_size()
    if offset + size > len(buffer):
        return {"ok": False, "error": f"output of {size} bytes does not fit the shared block"}
    tensor_at(buffer, {"dtype": "float32", "shape": list(tensor.shape), "offset": offset}).copy_(tensor)
    return {"ok": True, "shape": list(tensor.shape)}


def _signature(fn) -> list[str]:
    return list(inspect.signature(fn).parameters)


def serve(stdin: BinaryIO, stdout: BinaryIO) -> None:
    """Loads the file the first message names, then answers calls until the session closes stdin."""
    message = read_message(stdin)
    if message is None:
        return
    setup = json.loads(message)
    block = mmap.mmap(int(setup["fd"]), int(setup["size"]))  # mapped before the audit hook refuses mmap
    os.close(int(setup["fd"]))
    buffer = memoryview(block)
    torch.set_num_threads(1)
    warm_up_lazy_imports()
    install_limits(None, int(setup["memory_bytes"]))
    sys.addaudithook(_audit_hook)
    signal.signal(signal.SIGPROF, _on_cpu_timer)
    try:
        if setup.get("restricted", True):
            from torchrl_ahrs.sandbox.runtime import load_functions

            functions = load_functions(setup["source"], setup["filename"])
        else:
            functions = _load_unrestricted(setup["source"], setup["filename"])
    except Exception as error:  # noqa: BLE001
        write_message(stdout, json.dumps({"ok": False, "error": f"could not load: {_one_line(str(error))}"}).encode())
        return
    described = {name: {"parameters": _signature(fn), "doc": fn.__doc__} for name, fn in functions.items()}
    write_message(stdout, json.dumps({"ok": True, "functions": described}).encode())
    cpu_seconds = float(setup["cpu_seconds"])
    views: list[Any] = []
    while (message := read_message(stdin)) is not None:
        request = json.loads(message)
        if request.get("args") is not None:  # a new layout (None: the last one, rewritten in place)
            views = decode_arguments(buffer, request["args"])
        fn = functions.get(request.get("fn"))
        if fn is None:
            reply = {"ok": False, "error": f"no function {request.get('fn')!r}"}
        else:
            reply = call_function(fn, buffer, views, request, cpu_seconds)
        write_message(stdout, json.dumps(reply).encode())


if __name__ == "__main__":
    serve(sys.stdin.buffer, sys.stdout.buffer)
