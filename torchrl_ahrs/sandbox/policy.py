"""The static gate: RestrictedPython's compiler with this project's policy on top.

RestrictedPython (:class:`~RestrictedPython.transformer.RestrictingNodeTransformer`) already refuses
names and attributes that start with ``_``, ``exec``/``eval`` calls and frame/traceback attributes,
and rewrites every attribute read, item read, item write, ``for`` loop and in-place operator into calls
of guard functions (``_getattr_``, ``_getitem_``, ``_write_``, ``_getiter_``, ``_inplacevar_``) that
:mod:`torchrl_ahrs.sandbox.runtime` supplies. :class:`SandboxPolicy` adds what numeric code never needs
and what the runtime guards cannot bound:

* imports other than :data:`~torchrl_ahrs.sandbox.guards.ALLOWED_MODULES`;
* builtins that are not in the sandbox's table (``open``, ``getattr``, ``globals``...), unless the code
  binds the name itself (a variable called ``input`` is fine);
* attributes refused by :func:`~torchrl_ahrs.sandbox.guards.attribute_refusal` (``torch.load``,
  ``torch.os``...), checked here on dotted names rooted at an imported module so the reason comes
  before anything runs;
* ``while`` loops (not counted by ``_getiter_``, so not bounded), ``try`` (could swallow the limits'
  exceptions), ``with``, classes, lambdas, nested functions, decorators, ``global``, generators,
  ``async``, f-strings, star-arguments, attribute assignment, and top-level statements other than
  imports, constants and functions;
* huge constant exponents and multiplications (``10 ** 10 ** 9`` would pin one core inside C code).

Every refusal is one line, ``Line N: <why>``.
"""

from __future__ import annotations

import ast
import builtins
import copy
import types
from dataclasses import dataclass, field

from RestrictedPython import compile_restricted_exec
from RestrictedPython.transformer import RestrictingNodeTransformer

from torchrl_ahrs.sandbox.guards import ALLOWED_MODULES, MODULES, attribute_refusal, name_refusal

# The builtins sandboxed code finds at run time (see runtime.SAFE_BUILTINS); any other builtin name is
# refused statically so the reason names it instead of a NameError at validation.
SAFE_BUILTIN_NAMES: frozenset[str] = frozenset(
    """
    abs min max sum len range float int bool str enumerate zip round sorted list tuple dict set reversed
    all any map filter isinstance divmod slice print
    ValueError TypeError ZeroDivisionError RuntimeError IndexError KeyError ArithmeticError
    True False None
    """.split()
)
_BUILTIN_NAMES = frozenset(dir(builtins))
_MAX_EXPONENT = 64
_MAX_FACTOR = 10**6


@dataclass
class Verdict:
    """Outcome of a sandbox check: ``ok``, one human-readable reason per problem, the functions found.

    Example:
        >>> Verdict(False, ["Line 1: import of 'os' is not allowed"]).ok
        False
    """

    ok: bool
    reasons: list[str] = field(default_factory=list)
    functions: list[str] = field(default_factory=list)


def _bound_names(tree: ast.AST) -> frozenset[str]:
    """Every name the code binds itself (assignments, arguments, functions, imports, loop targets)."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
        elif isinstance(node, ast.FunctionDef):
            names.add(node.name)
        elif isinstance(node, ast.alias):
            names.add((node.asname or node.name).split(".")[0])
    return frozenset(names)


def _has_call(node: ast.AST) -> bool:
    return any(isinstance(child, ast.Call) for child in ast.walk(node))


class SandboxPolicy(RestrictingNodeTransformer):
    """RestrictedPython's transformer plus the project's refusals (see the module docstring).

    ``bound`` (set per check by :func:`check_source`) holds the names the code binds itself; ``modules``
    maps the names imports bind to the real module, to resolve dotted names statically.

    Example:
        >>> from RestrictedPython import compile_restricted_exec
        >>> compile_restricted_exec("def f(x):\\n    while x:\\n        pass\\n", policy=SandboxPolicy).errors[0][:29]
        'Line 2: While is not allowed '
    """

    bound: frozenset[str] = frozenset()

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.modules: dict[str, object] = {}
        self.function_depth = 0

    # ---- refused constructs ------------------------------------------------------------------------

    def _refuse(self, node: ast.AST, why: str) -> ast.AST:
        self.error(node, why)
        return node

    def visit_While(self, node):
        return self._refuse(node, "While is not allowed (use for ... in range(n); for-loops are counted and bounded)")

    def visit_Try(self, node):
        return self._refuse(node, "Try is not allowed (it could swallow the sandbox's limits)")

    visit_TryStar = visit_Try

    def visit_With(self, node):
        return self._refuse(node, "With is not allowed (no context managers in numeric code)")

    def visit_ClassDef(self, node):
        return self._refuse(node, "ClassDef is not allowed (define functions)")

    def visit_Lambda(self, node):
        return self._refuse(node, "Lambda is not allowed (define a top-level helper function)")

    def visit_Global(self, node):
        return self._refuse(node, "Global is not allowed (functions must not rebind module state)")

    visit_Nonlocal = visit_Global

    def visit_Yield(self, node):
        return self._refuse(node, "Yield is not allowed (a generator runs after the call's limits)")

    visit_YieldFrom = visit_Yield

    def visit_JoinedStr(self, node):
        return self._refuse(node, "JoinedStr (f-string) is not allowed (no string formatting in numeric code)")

    def visit_NamedExpr(self, node):
        return self._refuse(node, "NamedExpr (:=) is not allowed")

    def visit_AsyncFunctionDef(self, node):
        return self._refuse(node, "async code is not allowed")

    visit_AsyncFor = visit_AsyncWith = visit_Await = visit_AsyncFunctionDef

    # ---- functions -----------------------------------------------------------------------------------

    def visit_FunctionDef(self, node):
        if self.function_depth:
            return self._refuse(node, "nested functions are not allowed (define helpers at top level)")
        if node.decorator_list:
            self.error(node, "decorators are not allowed")
        if node.args.vararg or node.args.kwarg:
            self.error(node, "*args / **kwargs parameters are not allowed")
        self.function_depth += 1
        try:
            return super().visit_FunctionDef(node)
        finally:
            self.function_depth -= 1

    def visit_Call(self, node):
        if any(isinstance(arg, ast.Starred) for arg in node.args) or any(kw.arg is None for kw in node.keywords):
            self.error(node, "Starred arguments (*x, **x) in calls are not allowed")
        return super().visit_Call(node)

    # ---- imports -------------------------------------------------------------------------------------

    def visit_Import(self, node):
        for alias in node.names:
            if alias.name not in ALLOWED_MODULES:
                self.error(
                    node, f"import of {alias.name!r} is not allowed (allowed: {', '.join(sorted(ALLOWED_MODULES))})"
                )
            elif alias.asname:
                self.modules[alias.asname] = MODULES[alias.name]
            else:
                root = alias.name.split(".")[0]
                self.modules[root] = MODULES[root]
        return super().visit_Import(node)

    def visit_ImportFrom(self, node):
        if node.level or node.module not in ALLOWED_MODULES:
            self.error(node, f"import from {node.module!r} is not allowed")
            return super().visit_ImportFrom(node)
        module = MODULES[node.module]
        for alias in node.names:
            refusal = attribute_refusal(module, alias.name) if alias.name != "*" else None
            if refusal is not None:
                self.error(node, refusal)
            submodule = f"{node.module}.{alias.name}"
            if submodule in MODULES:
                self.modules[alias.asname or alias.name] = MODULES[submodule]
        return super().visit_ImportFrom(node)

    # ---- names and attributes ------------------------------------------------------------------------

    def visit_Name(self, node):
        if (
            isinstance(node.ctx, ast.Load)
            and node.id in _BUILTIN_NAMES
            and node.id not in SAFE_BUILTIN_NAMES
            and node.id not in self.bound
            and not node.id.startswith("_")  # RestrictedPython's own message covers these
        ):
            self.error(node, f"name {node.id!r} is not allowed")
        return super().visit_Name(node)

    def _resolve(self, node: ast.expr) -> object | None:
        """The module object a dotted name rooted at an import denotes (None: not statically known)."""
        if isinstance(node, ast.Name) and node.id not in self.bound - set(self.modules):
            return self.modules.get(node.id)
        if isinstance(node, ast.Attribute):
            owner = self._resolve(node.value)
            return getattr(owner, node.attr, None) if owner is not None else None
        return None

    def visit_Attribute(self, node):
        if not isinstance(node.ctx, ast.Load):
            return self._refuse(node, f"assigning to attribute {node.attr!r} is not allowed")
        if not node.attr.startswith("_"):
            owner = self._resolve(node.value)
            refusal = attribute_refusal(owner, node.attr) if owner is not None else name_refusal(node.attr)
            if refusal is not None:
                self.error(node, refusal)
        return super().visit_Attribute(node)

    # ---- arithmetic ----------------------------------------------------------------------------------

    def visit_BinOp(self, node):
        if isinstance(node.op, ast.Pow) and isinstance(node.right, ast.Constant):
            exponent = node.right.value
            if isinstance(exponent, (int, float)) and abs(exponent) > _MAX_EXPONENT:
                self.error(node, f"exponent {exponent} is too large")
        if isinstance(node.op, ast.Pow) and isinstance(node.right, ast.BinOp) and isinstance(node.right.op, ast.Pow):
            self.error(node, "tower of exponents (a ** b ** c) is not allowed")
        if isinstance(node.op, (ast.Mult, ast.LShift)) and any(
            isinstance(side, ast.Constant) and isinstance(side.value, int) and abs(side.value) > _MAX_FACTOR
            for side in (node.left, node.right)
        ):
            self.error(node, "integer constant too large in a multiplication or shift")
        return super().visit_BinOp(node)

    def visit_AugAssign(self, node):
        # RestrictedPython refuses ``a[i] += b``; rule code writes it often. ``a[i] = a[i] + b`` is the
        # same for tensors and lists and goes through the item guards, as long as ``a`` and ``i`` have
        # no side effects (evaluated twice).
        target = node.target
        if isinstance(target, ast.Subscript) and not _has_call(target):
            load = ast.Subscript(value=copy.deepcopy(target.value), slice=copy.deepcopy(target.slice), ctx=ast.Load())
            assign = ast.Assign(targets=[target], value=ast.BinOp(left=load, op=node.op, right=node.value))
            ast.copy_location(assign, node)
            ast.fix_missing_locations(assign)
            return self.visit(assign)
        return super().visit_AugAssign(node)


def _top_level_refusals(tree: ast.Module) -> tuple[list[str], list[str]]:
    """(reasons, function names) for the module's top-level statements."""
    reasons, functions = [], []
    for statement in tree.body:
        if isinstance(statement, ast.FunctionDef):
            functions.append(statement.name)
        elif isinstance(statement, (ast.Import, ast.ImportFrom, ast.Assign, ast.AnnAssign)):
            pass  # imports are checked by the policy; module-level constants (hyper-parameters) are fine
        elif not (isinstance(statement, ast.Expr) and isinstance(statement.value, ast.Constant)):
            reasons.append(f"Line {statement.lineno}: top-level {type(statement).__name__} is not allowed")
    return reasons, functions


def compile_checked(source: str, filename: str = "<llm>") -> tuple[Verdict, types.CodeType | None]:
    """(verdict, code object) for ``source``; the code object is None when the verdict refuses.

    Example:
        >>> verdict, code = compile_checked("def f(x):\\n    return x\\n")
        >>> verdict.ok, code is not None
        (True, True)
    """
    try:
        tree = ast.parse(source, filename=filename)
    except SyntaxError as error:
        return Verdict(False, [f"Line {error.lineno}: syntax error: {error.msg}"]), None
    reasons, functions = _top_level_refusals(tree)
    policy = type("BoundPolicy", (SandboxPolicy,), {"bound": _bound_names(tree)})
    result = compile_restricted_exec(tree, filename, policy=policy)
    reasons.extend(result.errors)
    if not functions:
        reasons.append("no function defined")
    ok = not reasons and result.code is not None
    return Verdict(ok, reasons, functions), (result.code if ok else None)


def check_source(source: str, filename: str = "<llm>") -> Verdict:
    """Static gate: every reason to refuse ``source`` before it runs (empty ``reasons`` = accepted).

    Example:
        >>> check_source("import torch\\ndef rule(m, v, h, w):\\n    return torch.zeros(m.shape[0]) + m\\n").ok
        True
        >>> check_source("import os\\ndef f():\\n    return 1\\n").reasons[0][:35]
        "Line 1: import of 'os' is not allow"
    """
    return compile_checked(source, filename)[0]
