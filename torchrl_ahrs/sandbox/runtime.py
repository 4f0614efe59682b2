"""Restricted execution: the guard functions RestrictedPython's compiled code calls, and the loader.

Code accepted by :func:`~torchrl_ahrs.sandbox.policy.check_source` is executed with

* a builtins table of numeric helpers only (:data:`SAFE_BUILTINS`) and an ``__import__`` that hands
  out the allowed modules (and the torch/numpy submodules their own C code imports);
* ``_getattr_`` / ``_write_`` from :mod:`torchrl_ahrs.sandbox.guards`;
* ``_getiter_``, which counts every ``for``-loop and comprehension step against a per-call budget
  (:class:`LoopBudget`), and a ``range`` that refuses more items than that budget.

The budget is what makes ``for i in range(k)`` with a computed ``k`` safe to accept: a loop bound is
no longer checked by reading the source, it is checked while the code runs, in the validation child
and later in the training process alike.
"""

from __future__ import annotations

import builtins
import functools
import importlib
import operator
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy
import torch
from RestrictedPython.Guards import guarded_iter_unpack_sequence, guarded_unpack_sequence
from RestrictedPython.PrintCollector import PrintCollector

from torchrl_ahrs.sandbox.guards import ALLOWED_MODULES, SandboxRefusal, guarded_getattr, guarded_write
from torchrl_ahrs.sandbox.policy import SAFE_BUILTIN_NAMES, compile_checked

LOOP_BUDGET = 1_000_000  # loop steps one top-level call may take (a rule over K=11 takes dozens)
_IMPORT_ROOTS = frozenset(name.split(".")[0] for name in ALLOWED_MODULES)


class LoopBudget:
    """Counts loop steps of one top-level call; raises :class:`SandboxRefusal` past ``limit``.

    Example:
        >>> budget = LoopBudget(limit=3)
        >>> list(budget.iterate([1, 2, 3]))
        [1, 2, 3]
        >>> list(budget.iterate([4]))
        Traceback (most recent call last):
        ...
        torchrl_ahrs.sandbox.guards.SandboxRefusal: more than 3 loop iterations in one call
    """

    def __init__(self, limit: int = LOOP_BUDGET):
        self.limit = limit
        self._calls = threading.local()  # a function called from two threads counts each call alone

    @property
    def steps(self) -> int:
        return getattr(self._calls, "steps", 0)

    @steps.setter
    def steps(self, value: int) -> None:
        self._calls.steps = value

    @property
    def depth(self) -> int:
        return getattr(self._calls, "depth", 0)

    @depth.setter
    def depth(self, value: int) -> None:
        self._calls.depth = value

    def iterate(self, iterable: Iterable) -> Iterator:
        calls = self._calls
        for item in iter(iterable):
            calls.steps = getattr(calls, "steps", 0) + 1
            if calls.steps > self.limit:
                raise SandboxRefusal(f"more than {self.limit} loop iterations in one call")
            yield item

    def range(self, *args: int) -> range:
        """``range`` that refuses more items than the budget (``list(range(10**10))`` never runs).

        Example:
            >>> LoopBudget(limit=5).range(2, 4)
            range(2, 4)
        """
        items = range(*args)
        try:
            size = len(items)
        except OverflowError:
            size = self.limit + 1
        if size > self.limit:
            raise SandboxRefusal(f"range of {size} items exceeds the sandbox's {self.limit}")
        return items


def restricted_import(name, globals=None, locals=None, fromlist=(), level=0):  # noqa: A002
    """``__import__`` for sandboxed code: allowed modules and the torch/numpy internals they import.

    torch's C code imports submodules such as ``torch.storage`` through the calling frame's
    ``__import__`` (``torch.tensor([1.0])`` does), so submodules of an allowed root are granted here;
    the code itself can only name what the static gate allowed.

    Example:
        >>> restricted_import("math").__name__
        'math'
        >>> restricted_import("os")
        Traceback (most recent call last):
        ...
        ImportError: import of 'os' is not allowed in the sandbox
    """
    if level != 0 or name.split(".")[0] not in _IMPORT_ROOTS:
        raise ImportError(f"import of {name!r} is not allowed in the sandbox")
    module = importlib.import_module(name)
    return module if fromlist else importlib.import_module(name.split(".")[0])


_INPLACE = {
    "+=": operator.iadd,
    "-=": operator.isub,
    "*=": operator.imul,
    "/=": operator.itruediv,
    "//=": operator.ifloordiv,
    "%=": operator.imod,
    "**=": operator.ipow,
    "@=": operator.imatmul,
    "<<=": operator.ilshift,
    ">>=": operator.irshift,
    "&=": operator.iand,
    "|=": operator.ior,
    "^=": operator.ixor,
}


def inplace_operation(op: str, target: Any, value: Any) -> Any:
    """RestrictedPython's ``_inplacevar_``: ``x += y`` on a name.

    Example:
        >>> inplace_operation("+=", 2, 3)
        5
    """
    return _INPLACE[op](target, value)


SAFE_BUILTINS: dict[str, Any] = {
    name: getattr(builtins, name) for name in SAFE_BUILTIN_NAMES if name not in ("True", "False", "None", "print")
}
SAFE_BUILTINS.update({"True": True, "False": False, "None": None})


def restricted_globals(budget: LoopBudget) -> dict[str, Any]:
    """The global namespace sandboxed code runs in (fresh per load: module state is not shared).

    Example:
        >>> namespace = restricted_globals(LoopBudget())
        >>> "open" in namespace["__builtins__"], namespace["_getiter_"].__name__
        (False, 'iterate')
    """
    table = dict(SAFE_BUILTINS)
    table["__import__"] = restricted_import
    table["range"] = budget.range
    return {
        "__builtins__": table,
        "__name__": "sandboxed",
        "_getattr_": guarded_getattr,
        "_getitem_": operator.getitem,
        "_write_": guarded_write,
        "_getiter_": budget.iterate,
        "_iter_unpack_sequence_": guarded_iter_unpack_sequence,
        "_unpack_sequence_": guarded_unpack_sequence,
        "_inplacevar_": inplace_operation,
        "_print_": PrintCollector,  # print() inside a function collects into nothing
    }


def private_copy(value: Any) -> Any:
    """``value`` with every tensor and array cloned and every dict/list/tuple rebuilt.

    Sandboxed code gets its arguments through this, so an in-place edit (``obs["observation"][:, 0] =
    0``, ``x.mul_(0)``) changes its own copy, never the environment's tensors or the scheduler's
    statistics, and a returned tensor never aliases the caller's.

    Example:
        >>> original = {"x": torch.zeros(2)}
        >>> copy = private_copy(original); copy["x"][0] = 1.0
        >>> original["x"].tolist()
        [0.0, 0.0]
    """
    if isinstance(value, torch.Tensor):
        return value.detach().clone()
    if isinstance(value, numpy.ndarray):
        return value.copy()
    if isinstance(value, dict):
        return {key: private_copy(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(private_copy(item) for item in value)
    return value


def _budgeted(fn: Callable, budget: LoopBudget) -> Callable:
    """``fn`` with private copies of its arguments and the loop budget reset at each outermost call
    (helpers called from inside share their caller's budget)."""

    @functools.wraps(fn)
    def call(*args, **kwargs):
        if budget.depth == 0:
            budget.steps = 0
        budget.depth += 1
        try:
            return fn(*private_copy(args), **private_copy(kwargs))
        finally:
            budget.depth -= 1

    return call


def load_functions(source: str, filename: str = "<llm>", loop_budget: int = LOOP_BUDGET) -> dict[str, Callable]:
    """Executes statically accepted ``source`` in the restricted namespace; returns its top-level functions.

    Each returned function keeps its name, docstring and signature (``inspect.signature`` follows
    ``__wrapped__``), runs under a fresh :class:`LoopBudget` per call and works on private copies of
    its arguments (:func:`private_copy`).

    Raises:
        ValueError: when the static gate refuses the code (the message lists every reason).

    Example:
        >>> import torch
        >>> fns = load_functions("import torch\\ndef double(x):\\n    return torch.abs(x) * 2\\n")
        >>> fns["double"](torch.tensor([-1.0, 2.0])).tolist()
        [2.0, 4.0]
    """
    verdict, code = compile_checked(source, filename)
    if not verdict.ok or code is None:
        raise ValueError("sandbox refused the code:\n" + "\n".join(verdict.reasons))
    budget = LoopBudget(loop_budget)
    namespace = restricted_globals(budget)
    exec(code, namespace)  # noqa: S102 (compiled by RestrictedPython, guards installed above)
    return {name: _budgeted(namespace[name], budget) for name in verdict.functions}
