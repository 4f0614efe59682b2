"""Accepted code at time of use: the functions of one file, called in an isolated, key-free process.

The check (:mod:`~torchrl_ahrs.sandbox.isolation`) runs a file a few times in a limited child; code that
holds back until after those calls (a call counter, a trigger on input values) would otherwise run
unlimited inside the training process. A :class:`SandboxSession` keeps the file in its own process
(:mod:`~torchrl_ahrs.sandbox.serving`) for as long as training uses it, with the check's protection: no
API keys in its environment, the check's rlimits (memory cap, no file writes, few descriptors) and
audit hook, a CPU-time timer per call and a wall clock per call enforced from here (the process is killed
when a call overruns). Arguments and outputs cross through one shared-memory block (a ``memfd``), with
one small JSON message each way per call, so a per-step auxiliary reward stays cheap.

A failed call raises :class:`SandboxCallError`, one line naming the file and the function; the next call
starts a fresh process (a rule's caller keeps its weights and goes on; an auxiliary reward's stops the run).
"""

from __future__ import annotations

import ast
import inspect
import json
import mmap
import os
import select
import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from typing import Any

import torch

from torchrl_ahrs.sandbox.isolation import MEMORY_BYTES, START_SECONDS, _worker_environment
from torchrl_ahrs.sandbox.protocol import HEADER
from torchrl_ahrs.sandbox.serving import tensor_at

CALL_WALL_SECONDS = 10.0  # one call's wall clock: a hang costs at most this much of a run
CALL_CPU_SECONDS = 2.0  # one call's CPU time, as the check's child grants all its calls together
INITIAL_CAPACITY = 1 << 20  # bytes of the shared block; grown (by a restart) when a call needs more
_ALIGN = 64


class SandboxCallError(RuntimeError):
    """A call through a :class:`SandboxSession` failed (message: one line naming the file and the function).

    Example:
        >>> str(SandboxCallError("rules.py: rule: raised KeyError: 'x'"))
        "rules.py: rule: raised KeyError: 'x'"
    """


def _aligned(size: int) -> int:
    return (size + _ALIGN - 1) // _ALIGN * _ALIGN


class _Layout:
    """Where each argument tensor goes in the shared block, and the JSON that tells the worker.

    Tensors are placed back to back; when they share one dtype (an auxiliary reward's float32 step) they are
    written with one ``torch.cat`` into the block. ``key`` identifies the layout: the worker keeps its views
    of the block from the last call, so a step with the same layout sends no layout at all.
    """

    def __init__(self, arguments: tuple):
        self.entries: list[dict] = []
        self.tensors: list[torch.Tensor] = []
        self.size = 0
        for argument in arguments:
            if isinstance(argument, torch.Tensor):
                self.entries.append({"tensor": self._place(argument)})
            elif isinstance(argument, Mapping):
                self.entries.append({"dict": {str(name): self._place(value) for name, value in argument.items()}})
            elif argument is None or isinstance(argument, (int, float, bool)):
                self.entries.append({"value": argument})
            else:
                raise TypeError(f"cannot pass {type(argument).__name__} to sandboxed code (tensors, dicts, numbers)")
        self.key = json.dumps(self.entries)
        dtypes = {tensor.dtype for tensor in self.tensors}
        self.packed = dtypes.pop() if len(dtypes) == 1 else None  # one dtype: contiguous, one write
        self.output_offset = _aligned(self.size)

    def _place(self, value: Any) -> dict:
        tensor = torch.as_tensor(value).detach().to("cpu")
        size = tensor.element_size()
        self.size = (self.size + size - 1) // size * size  # the element's own alignment: same dtypes stay contiguous
        spec = {"dtype": str(tensor.dtype).removeprefix("torch."), "shape": list(tensor.shape), "offset": self.size}
        self.tensors.append(tensor)
        self.size += tensor.numel() * size
        return spec

    def write(self, buffer: memoryview) -> None:
        """Copies every argument tensor into ``buffer`` at its place."""
        if self.packed is not None:
            count = sum(tensor.numel() for tensor in self.tensors)
            if count:
                target = torch.frombuffer(buffer, dtype=self.packed, count=count)
                torch.cat([tensor.reshape(-1) for tensor in self.tensors], out=target)
            return
        specs = [spec for entry in self.entries for spec in _specs(entry)]
        for spec, tensor in zip(specs, self.tensors, strict=True):
            if tensor.numel():
                tensor_at(buffer, spec).copy_(tensor)


def _specs(entry: dict) -> list[dict]:
    if "tensor" in entry:
        return [entry["tensor"]]
    return list(entry.get("dict", {}).values())


class SandboxSession:
    """The functions of one file, served by an isolated process (started on first call, in each process).

    Args:
        source: the file's text (compiled with RestrictedPython again in the worker).
        filename: named in every error.
        wall_seconds: one call's wall clock (the worker is killed past it).
        cpu_seconds: one call's CPU time.
        memory_bytes: address space granted on top of what the worker maps after importing torch.
        restricted: False serves without RestrictedPython, to test the isolation alone.

    Example:
        >>> session = SandboxSession("import torch\\ndef double(x):\\n    return x * 2\\n", "double.py")
        >>> session.call("double", torch.tensor([1.0, 2.0]), expected_shape=(2,)).tolist()
        [2.0, 4.0]
        >>> session.call("double", torch.ones(2), expected_shape=(3,))
        Traceback (most recent call last):
        ...
        torchrl_ahrs.sandbox.session.SandboxCallError: double.py: double: output shape (2,), expected (3,)
        >>> session.close()
    """

    def __init__(
        self,
        source: str,
        filename: str = "<llm>",
        *,
        wall_seconds: float = CALL_WALL_SECONDS,
        cpu_seconds: float = CALL_CPU_SECONDS,
        memory_bytes: int = MEMORY_BYTES,
        restricted: bool = True,
    ):
        self.source, self.filename = source, filename
        self.wall_seconds, self.cpu_seconds, self.memory_bytes = wall_seconds, cpu_seconds, memory_bytes
        self.restricted = restricted
        self.capacity = INITIAL_CAPACITY
        self._lock = threading.Lock()
        self._process: subprocess.Popen | None = None
        self._block: mmap.mmap | None = None
        self._owner = -1
        self._functions: dict[str, dict] | None = None
        self._last_layout: str | None = None

    # ---- the worker's life ------------------------------------------------------------------------------

    def _start(self) -> None:
        fd = os.memfd_create("torchrl_ahrs_sandbox", 0)
        try:
            os.ftruncate(fd, self.capacity)
            self._block = mmap.mmap(fd, self.capacity)
            self._process = subprocess.Popen(
                [sys.executable, "-m", "torchrl_ahrs.sandbox.serving"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                env=_worker_environment(),
                pass_fds=(fd,),
            )
        finally:
            os.close(fd)
        self._owner = os.getpid()
        self._last_layout = None  # a new worker has no views yet
        setup = {
            "fd": fd,
            "size": self.capacity,
            "source": self.source,
            "filename": self.filename,
            "memory_bytes": int(self.memory_bytes),
            "cpu_seconds": float(self.cpu_seconds),
            "restricted": bool(self.restricted),
        }
        reply = self._exchange(setup, START_SECONDS, "loading")
        if not reply.get("ok"):
            self._stop()
            raise SandboxCallError(f"{self.filename}: {reply.get('error', 'the sandbox worker could not load it')}")
        self._functions = dict(reply["functions"])

    def _stop(self) -> None:
        process, self._process = self._process, None
        if process is not None and process.poll() is None:
            process.kill()
            process.wait()
        for stream in (process.stdin, process.stdout) if process is not None else ():
            if stream is not None:
                stream.close()
        if self._block is not None:
            self._block.close()
            self._block = None

    def _ensure(self) -> None:
        if self._process is not None and self._owner != os.getpid():
            self._process, self._block = None, None  # inherited through fork: this process starts its own
        if self._process is None or self._process.poll() is not None:
            self._stop()
            self._start()

    def close(self) -> None:
        """Stops the worker (a later call starts a new one)."""
        with self._lock:
            if self._owner == os.getpid():
                self._stop()

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 (interpreter shutdown)
            pass

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state.update(_lock=None, _process=None, _block=None, _owner=-1)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()

    # ---- one exchange -----------------------------------------------------------------------------------

    def _read_exactly(self, size: int, deadline: float, what: str) -> bytes:
        assert self._process is not None and self._process.stdout is not None
        stdout, data = self._process.stdout, b""
        while len(data) < size:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(what)
            ready, _, _ = select.select([stdout], [], [], remaining)
            if ready:
                chunk = os.read(stdout.fileno(), size - len(data))
                if not chunk:
                    raise EOFError(what)
                data += chunk
        return data

    def _exchange(self, message: dict, timeout: float, what: str) -> dict:
        assert self._process is not None and self._process.stdin is not None
        payload = json.dumps(message).encode()
        deadline = time.monotonic() + timeout
        try:
            self._process.stdin.write(HEADER.pack(len(payload)) + payload)
            self._process.stdin.flush()
            (length,) = HEADER.unpack(self._read_exactly(HEADER.size, deadline, what))
            return json.loads(self._read_exactly(length, deadline, what))
        except TimeoutError:
            self._stop()
            raise SandboxCallError(
                f"{self.filename}: {what} did not finish within {timeout:g} s of wall time; its worker was killed"
            ) from None
        except (EOFError, OSError, ValueError):
            code = self._process.wait() if self._process is not None else None
            self._stop()
            why = f"killed by signal {-code}" if code is not None and code < 0 else f"exited with status {code}"
            raise SandboxCallError(
                f"{self.filename}: the sandbox worker died during {what} ({why}; memory or CPU limit, or a crash)"
            ) from None

    # ---- calls --------------------------------------------------------------------------------------------

    def functions(self) -> dict[str, dict]:
        """``{name: {"parameters": [...], "doc": str | None}}`` of the file's top-level functions (starts the worker)."""
        with self._lock:
            self._ensure()
            assert self._functions is not None
            return dict(self._functions)

    def call(self, name: str, *arguments: Any, expected_shape: tuple[int, ...]) -> torch.Tensor:
        """``name(*arguments)`` in the worker; its output as float32 ``expected_shape``
        (:func:`~torchrl_ahrs.sandbox.cases.output_contract`).

        Raises:
            SandboxCallError: the call raised, was refused, broke the contract, overran or killed its worker.
        """
        layout = _Layout(arguments)
        output_size = _aligned(4 * max(1, int(torch.Size(expected_shape).numel())))
        with self._lock:
            if layout.output_offset + output_size > self.capacity:
                self._stop()
                self.capacity = max(2 * self.capacity, _aligned(2 * (layout.output_offset + output_size)))
            self._ensure()
            assert self._block is not None
            with memoryview(self._block) as buffer:  # released before the exchange: a failure closes the block
                layout.write(buffer)
            same = layout.key == self._last_layout  # the worker still holds its views of this layout
            request = {
                "fn": name,
                "args": None if same else layout.entries,
                "expected_shape": list(expected_shape),
                "output_offset": layout.output_offset,
            }
            reply = self._exchange(request, self.wall_seconds, f"{name}()")
            self._last_layout = layout.key
            if not reply.get("ok"):
                raise SandboxCallError(f"{self.filename}: {name}: {reply.get('error')}")
            with memoryview(self._block) as buffer:
                spec = {"dtype": "float32", "shape": reply["shape"], "offset": layout.output_offset}
                return tensor_at(buffer, spec).clone()


class IsolatedFunction:
    """One function of a :class:`SandboxSession`, callable like the function itself.

    ``inspect.signature`` and ``__doc__`` are the function's; the expected output shape is ``[K]`` (the
    first argument's, ``kind="rule"``) or ``[N]`` (the first dict entry's batch size, ``kind="aux"``).

    Example:
        >>> session = SandboxSession("def rule(m, v, h, w):\\n    '''Doubles.'''\\n    return m * 2\\n", "r.py")
        >>> rule = isolated_functions(session, "rule")["rule"]
        >>> len(inspect.signature(rule).parameters), rule.__doc__, rule(torch.ones(2), None, None, None).tolist()
        (4, 'Doubles.', [2.0, 2.0])
        >>> session.close()
    """

    def __init__(self, session: SandboxSession, name: str, parameters: list[str], doc: str | None, kind: str):
        self.session, self.__name__, self.__doc__, self.kind = session, name, doc, kind
        self.__signature__ = inspect.Signature(
            [inspect.Parameter(p, inspect.Parameter.POSITIONAL_OR_KEYWORD) for p in parameters]
        )

    def __call__(self, *arguments: Any) -> torch.Tensor:
        first = arguments[0] if arguments else None
        if self.kind == "aux" and isinstance(first, Mapping):
            expected: tuple[int, ...] = (int(next(iter(first.values())).shape[0]),)
        else:
            expected = tuple(torch.as_tensor(first).shape)
        return self.session.call(self.__name__, *arguments, expected_shape=expected)


def describe_functions(source: str) -> dict[str, dict]:
    """``{name: {"parameters": [...], "doc": str | None}}`` of the source's top-level functions, read from its
    syntax tree (no worker needed: a probe environment that never calls the function starts none).

    Example:
        >>> describe_functions("def rule(m, v, h, w):\\n    '''Doubles.'''\\n    return m * 2\\n")
        {'rule': {'parameters': ['m', 'v', 'h', 'w'], 'doc': 'Doubles.'}}
    """
    described = {}
    for node in ast.parse(source).body:
        if isinstance(node, ast.FunctionDef):
            arguments = [*node.args.posonlyargs, *node.args.args, *node.args.kwonlyargs]
            doc = ast.get_docstring(node, clean=False)
            described[node.name] = {"parameters": [argument.arg for argument in arguments], "doc": doc}
    return described


def isolated_functions(session: SandboxSession, kind: str) -> dict[str, IsolatedFunction]:
    """Every top-level function of the session's file as an :class:`IsolatedFunction` (the worker starts at the
    first call; the caller has checked the source statically)."""
    return {
        name: IsolatedFunction(session, name, info["parameters"], info.get("doc"), kind)
        for name, info in describe_functions(session.source).items()
    }
