"""A sandbox for code written by an LLM (weight rules, auxiliary rewards).

Code is data until it passes three gates:

1. **Static allow-list** (:func:`check_source`): the source is parsed with :mod:`ast` and every node
   type, name, attribute and import must be on an allow-list. Refused outright: imports other than
   ``math``, ``torch`` and ``numpy``; any name or attribute starting with ``_`` (the dunder escape
   hatches); ``exec``/``eval``/``compile``/``open``/``getattr``/``globals``... (they are simply not
   on the list); ``while`` loops, ``lambda``, nested functions, classes, ``try``, ``with``,
   ``global``, f-strings, star-arguments; ``for`` loops and comprehensions whose ``range`` bound is
   not a small constant or a ``len(...)``/``.shape[...]``/``.numel()`` of a variable.
2. **Restricted execution** (:func:`load_functions`): accepted code runs with a tiny builtins table
   (``abs``, ``min``, ``max``, ``range``... and an ``__import__`` that hands out only the three
   allowed modules), so even an overlooked path finds nothing to call.
3. **Child-process validation** (:func:`validate_in_child`): the functions are called on random and
   edge-case inputs in a separate Python process with CPU-time and address-space limits
   (``resource.setrlimit``) and a wall-clock timeout; outputs must have the right shape and be finite.

The command line is ``python -m torchrl_ahrs.sandbox check FILE.py --kind rule|aux``.

Residual risk (documented, not hidden): accepted code later runs in the training process, where no
CPU limit applies. Loops are bounded statically and inputs at validation include extreme values, so a
data-dependent hang is unlikely; callers still treat exceptions and non-finite outputs as a failed
decision and keep their previous state.
"""

from __future__ import annotations

import ast
import builtins
import importlib
import json
import math
import os
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy
import torch

ALLOWED_MODULES = {"math": math, "torch": torch, "numpy": numpy}

# Attribute names that may follow any expression (module functions, tensor methods, dtypes).
ALLOWED_ATTRIBUTES = frozenset(
    """
    abs absolute amax amin all any arange argmax argmin argsort as_tensor atan atan2 cat ceil clamp
    clamp_max clamp_min clip cos cosh cumprod cumsum diff dim double dtype e exp expm1 fabs float float32
    float64 floor full_like inf isclose isfinite isnan item linspace log log10 log1p log2 logsumexp max
    maximum mean median min minimum nan_to_num ndim neg norm numel ones_like pi pow prod reciprocal
    relu reshape round rsqrt shape sigmoid sign sin sinh size softmax sort sqrt square squeeze stack std
    sub sum T tan tanh tensor tolist topk unsqueeze values indices var where zeros_like array mul div add
    flatten nansum nanmean fmax fmin hypot isinf
    """.split()
)

SAFE_BUILTINS: dict[str, object] = {
    name: getattr(builtins, name)
    for name in (
        "abs",
        "min",
        "max",
        "sum",
        "len",
        "range",
        "float",
        "int",
        "bool",
        "enumerate",
        "zip",
        "round",
        "sorted",
        "list",
        "tuple",
        "dict",
        "reversed",
        "all",
        "any",
        "ValueError",
    )
}
SAFE_BUILTINS.update({"True": True, "False": False, "None": None})


# builtins that sandboxed code may not even name (refused statically; absent at run time anyway)
FORBIDDEN_NAMES = frozenset(name for name in dir(builtins) if name not in SAFE_BUILTINS) - {"True", "False", "None"}


def _restricted_import(name, globals=None, locals=None, fromlist=(), level=0):  # noqa: A002
    """``__import__`` for sandboxed code: the allow-listed modules and their own submodules.

    Submodules are needed because torch's C code imports e.g. ``torch.storage`` through the calling
    frame's ``__import__`` (``torch.tensor([1.0])`` does); the code itself cannot name them, since the
    static check accepts only ``import math|torch|numpy``.
    """
    if level != 0 or name.split(".")[0] not in ALLOWED_MODULES:
        raise ImportError(f"import of {name!r} is not allowed in the sandbox")
    module = importlib.import_module(name)
    return module if fromlist else ALLOWED_MODULES[name.split(".")[0]]


_ALLOWED_NODES = (
    ast.Module,
    ast.FunctionDef,
    ast.arguments,
    ast.arg,
    ast.Return,
    ast.Assign,
    ast.AugAssign,
    ast.AnnAssign,
    ast.Expr,
    ast.If,
    ast.IfExp,
    ast.For,
    ast.Pass,
    ast.Break,
    ast.Continue,
    ast.ListComp,
    ast.GeneratorExp,
    ast.comprehension,
    ast.BinOp,
    ast.UnaryOp,
    ast.BoolOp,
    ast.Compare,
    ast.Call,
    ast.keyword,
    ast.Name,
    ast.Load,
    ast.Store,
    ast.Attribute,
    ast.Subscript,
    ast.Slice,
    ast.Tuple,
    ast.List,
    ast.Dict,
    ast.Constant,
    ast.Import,
    ast.ImportFrom,
    ast.alias,
    ast.operator,
    ast.unaryop,
    ast.boolop,
    ast.cmpop,
    ast.expr_context,
)
_MAX_RANGE = 10_000  # largest constant loop bound accepted
_MAX_LOOP_DEPTH = 2  # nested for loops / comprehension generators


@dataclass
class Verdict:
    """Outcome of a sandbox check: ``ok`` and one human-readable reason per problem."""

    ok: bool
    reasons: list[str] = field(default_factory=list)
    functions: list[str] = field(default_factory=list)


class _Checker(ast.NodeVisitor):
    """Collects every allow-list violation (not just the first), with line numbers."""

    def __init__(self):
        self.reasons: list[str] = []
        self.function_depth = 0
        self.loop_depth = 0

    def refuse(self, node: ast.AST, why: str) -> None:
        self.reasons.append(f"line {getattr(node, 'lineno', '?')}: {why}")

    def generic_visit(self, node: ast.AST) -> None:
        if not isinstance(node, _ALLOWED_NODES):
            self.refuse(node, f"{type(node).__name__} is not allowed")
            return
        super().generic_visit(node)

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            if alias.name not in ALLOWED_MODULES:
                self.refuse(node, f"import of {alias.name!r} is not allowed (allowed: {sorted(ALLOWED_MODULES)})")
            if alias.asname and alias.asname.startswith("_"):
                self.refuse(node, f"name {alias.asname!r} starts with '_'")

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        if node.module not in ALLOWED_MODULES or node.level:
            self.refuse(node, f"import from {node.module!r} is not allowed")
        for alias in node.names:
            if alias.name not in ALLOWED_ATTRIBUTES:
                self.refuse(node, f"importing {alias.name!r} is not allowed")

    def visit_FunctionDef(self, node: ast.FunctionDef) -> None:
        if self.function_depth:
            self.refuse(node, "nested functions are not allowed")
            return
        if node.decorator_list:
            self.refuse(node, "decorators are not allowed")
        if node.name.startswith("_"):
            self.refuse(node, f"function name {node.name!r} starts with '_'")
        if node.args.vararg or node.args.kwarg:
            self.refuse(node, "*args / **kwargs are not allowed")
        self.function_depth += 1
        for child in [*node.args.args, *node.args.kwonlyargs, *node.args.defaults, *node.body]:
            self.visit(child)
        self.function_depth -= 1

    def visit_arg(self, node: ast.arg) -> None:
        if node.arg.startswith("_"):
            self.refuse(node, f"argument {node.arg!r} starts with '_'")
        # annotations are not evaluated for meaning; they must still be plain allowed expressions
        if node.annotation is not None:
            self.visit(node.annotation)

    def visit_Name(self, node: ast.Name) -> None:
        if node.id.startswith("_"):
            self.refuse(node, f"name {node.id!r} starts with '_'")
        elif node.id in FORBIDDEN_NAMES:
            self.refuse(node, f"name {node.id!r} is not allowed")

    def visit_Attribute(self, node: ast.Attribute) -> None:
        if node.attr.startswith("_"):
            self.refuse(node, f"attribute {node.attr!r} starts with '_'")
        elif node.attr not in ALLOWED_ATTRIBUTES:
            self.refuse(node, f"attribute {node.attr!r} is not on the allow-list")
        self.visit(node.value)

    def visit_Constant(self, node: ast.Constant) -> None:
        if isinstance(node.value, bytes):
            self.refuse(node, "bytes literals are not allowed")

    def visit_Expr(self, node: ast.Expr) -> None:
        # bare expressions only as docstrings: a call for its side effect has no business here
        if not (isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)):
            self.refuse(node, "expression statements other than docstrings are not allowed")

    def visit_BinOp(self, node: ast.BinOp) -> None:
        if isinstance(node.op, ast.Pow) and isinstance(node.right, ast.Constant):
            exponent = node.right.value
            if isinstance(exponent, (int, float)) and abs(exponent) > 64:
                self.refuse(node, f"exponent {exponent} is too large")
        if isinstance(node.op, (ast.Mult, ast.LShift)) and any(
            isinstance(side, ast.Constant) and isinstance(side.value, int) and abs(side.value) > 10**6
            for side in (node.left, node.right)
        ):
            self.refuse(node, "integer constant too large in a multiplication or shift")
        self.generic_visit(node)

    def _check_iterable(self, node: ast.AST, iterable: ast.expr) -> None:
        if isinstance(iterable, ast.Call) and isinstance(iterable.func, ast.Name) and iterable.func.id == "range":
            for bound in iterable.args:
                if not self._is_bounded(bound):
                    self.refuse(node, "range() bound must be a constant <= 10000, len(x), x.numel() or x.shape[i]")
        elif (
            isinstance(iterable, ast.Call)
            and isinstance(iterable.func, ast.Name)
            and iterable.func.id
            in (
                "enumerate",
                "zip",
                "reversed",
            )
        ):
            for arg in iterable.args:
                self._check_iterable(node, arg)
        elif not isinstance(iterable, (ast.Name, ast.Tuple, ast.List, ast.Subscript, ast.Attribute)):
            self.refuse(node, "loops may only run over range(...), a variable, a tuple or a list")

    def _is_bounded(self, bound: ast.expr) -> bool:
        if isinstance(bound, ast.Constant):
            return isinstance(bound.value, int) and abs(bound.value) <= _MAX_RANGE
        if isinstance(bound, ast.UnaryOp) and isinstance(bound.op, ast.USub):
            return self._is_bounded(bound.operand)
        if isinstance(bound, ast.Call) and isinstance(bound.func, ast.Name) and bound.func.id == "len":
            return True
        if (
            isinstance(bound, ast.Call)
            and isinstance(bound.func, ast.Attribute)
            and bound.func.attr in ("numel", "size")
        ):
            return True
        if isinstance(bound, ast.Subscript) and isinstance(bound.value, ast.Attribute):
            return bound.value.attr == "shape"
        if isinstance(bound, ast.Attribute):
            return bound.attr == "ndim"
        return False

    def visit_For(self, node: ast.For) -> None:
        if node.orelse:
            self.refuse(node, "for ... else is not allowed")
        self._check_iterable(node, node.iter)
        self.loop_depth += 1
        if self.loop_depth > _MAX_LOOP_DEPTH:
            self.refuse(node, f"loops nested deeper than {_MAX_LOOP_DEPTH}")
        self.generic_visit(node)
        self.loop_depth -= 1

    def _visit_comprehension(self, node: ast.ListComp | ast.GeneratorExp) -> None:
        if len(node.generators) + self.loop_depth > _MAX_LOOP_DEPTH:
            self.refuse(node, f"comprehension loops nested deeper than {_MAX_LOOP_DEPTH}")
        for generator in node.generators:
            self._check_iterable(node, generator.iter)
        self.loop_depth += len(node.generators)
        self.generic_visit(node)
        self.loop_depth -= len(node.generators)

    visit_ListComp = _visit_comprehension
    visit_GeneratorExp = _visit_comprehension

    def visit_Call(self, node: ast.Call) -> None:
        for arg in node.args:
            if isinstance(arg, ast.Starred):
                self.refuse(node, "*args in calls are not allowed")
        for keyword in node.keywords:
            if keyword.arg is None:
                self.refuse(node, "**kwargs in calls are not allowed")
        self.generic_visit(node)


def check_source(source: str, filename: str = "<llm>") -> Verdict:
    """Static gate: parses ``source`` and returns every allow-list violation.

    Example:
        >>> check_source("def rule(m, v, h, w):\\n    return m * 2\\n").ok
        True
        >>> check_source("import os\\n").reasons[0]
        "line 1: import of 'os' is not allowed (allowed: ['math', 'numpy', 'torch'])"
    """
    try:
        tree = ast.parse(source, filename=filename)
    except SyntaxError as error:
        return Verdict(False, [f"line {error.lineno}: syntax error: {error.msg}"])
    checker = _Checker()
    functions = []
    for statement in tree.body:
        if isinstance(statement, ast.FunctionDef):
            functions.append(statement.name)
        elif isinstance(statement, (ast.Import, ast.ImportFrom, ast.Assign, ast.AnnAssign)):
            pass  # imports are checked by the visitor; module-level constants (hyper-parameters) are fine
        elif not (isinstance(statement, ast.Expr) and isinstance(statement.value, ast.Constant)):
            checker.refuse(statement, f"top-level {type(statement).__name__} is not allowed")
    checker.visit(tree)
    if not functions:
        checker.reasons.append("no function defined")
    return Verdict(not checker.reasons, checker.reasons, functions)


def load_functions(source: str, filename: str = "<llm>") -> dict[str, Callable]:
    """Executes statically accepted ``source`` with restricted builtins; returns its top-level functions.

    Raises:
        ValueError: when :func:`check_source` refuses the code (the message lists every reason).

    Example:
        >>> import torch
        >>> fns = load_functions("import torch\\ndef double(x):\\n    return torch.abs(x) * 2\\n")
        >>> fns["double"](torch.tensor([-1.0, 2.0])).tolist()
        [2.0, 4.0]
    """
    verdict = check_source(source, filename)
    if not verdict.ok:
        raise ValueError("sandbox refused the code:\n" + "\n".join(verdict.reasons))
    restricted_builtins = dict(SAFE_BUILTINS)
    restricted_builtins["__import__"] = _restricted_import
    namespace: dict[str, object] = {"__builtins__": restricted_builtins, "__name__": "sandboxed"}
    exec(compile(ast.parse(source, filename=filename), filename, "exec"), namespace)  # noqa: S102 (checked above)
    return {name: namespace[name] for name in verdict.functions}  # type: ignore[misc]


# ----------------------------------------------------------------------------------------------------
# Child-process validation
# ----------------------------------------------------------------------------------------------------

CPU_SECONDS = 2  # CPU time granted to the validation calls (on top of the interpreter's start-up)
MEMORY_BYTES = 1 << 30  # address space granted on top of what the child uses after importing torch
WALL_SECONDS = 60.0  # the parent gives up on the child after this long


def validate_in_child(
    path: str | Path,
    kind: str,
    cpu_seconds: int = CPU_SECONDS,
    memory_bytes: int = MEMORY_BYTES,
    inputs_path: str | Path | None = None,
) -> Verdict:
    """Runs :mod:`torchrl_ahrs.llm.sandbox_worker` on ``path`` in a limited child process.

    ``inputs_path`` (aux kind): a ``torch.save``'d ``dict[str, Tensor [N, ...]]`` of real transitions the
    function is called on instead of the synthetic cases.

    Returns a :class:`Verdict` with one reason per failing function/input (or the limit that was hit).
    """
    command = [
        sys.executable,
        "-m",
        "torchrl_ahrs.llm.sandbox_worker",
        str(path),
        kind,
        str(cpu_seconds),
        str(memory_bytes),
        *([str(inputs_path)] if inputs_path is not None else []),
    ]
    environment = {key: value for key, value in os.environ.items() if "KEY" not in key and "TOKEN" not in key}
    environment.update({"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"})
    try:
        finished = subprocess.run(
            command, capture_output=True, text=True, timeout=WALL_SECONDS, env=environment, stdin=subprocess.DEVNULL
        )
    except subprocess.TimeoutExpired:
        return Verdict(False, [f"validation did not finish within {WALL_SECONDS:.0f} s of wall time"])
    last_line = finished.stdout.strip().splitlines()[-1] if finished.stdout.strip() else ""
    try:
        report = json.loads(last_line)
    except json.JSONDecodeError:
        if finished.returncode < 0:
            signal_number = -finished.returncode
            why = {9: "killed (CPU-time limit)", 24: "CPU-time limit exceeded"}.get(
                signal_number, f"signal {signal_number}"
            )
            return Verdict(False, [f"validation process {why}"])
        tail = finished.stderr.strip().splitlines()[-3:]
        return Verdict(False, [f"validation process failed (exit {finished.returncode}): {' | '.join(tail)}"])
    return Verdict(bool(report["ok"]), list(report["reasons"]), list(report.get("functions", [])))


def check_file(path: str | Path, kind: str, run_child: bool = True) -> Verdict:
    """All gates for a file: static check, then (if accepted and ``run_child``) child validation."""
    source = Path(path).read_text()
    verdict = check_source(source, str(path))
    if not verdict.ok or not run_child:
        return verdict
    return validate_in_child(path, kind)
