"""What sandboxed code may reach: modules, module attributes and attribute names.

One function, :func:`attribute_refusal`, decides whether ``obj.name`` is allowed; the static gate
(:mod:`torchrl_ahrs.sandbox.policy`) applies it to dotted names rooted at an imported module, and the
runtime guard (:func:`guarded_getattr`, installed as RestrictedPython's ``_getattr_``) applies it to
every attribute access while the code runs. Names that start with ``_`` are refused by
RestrictedPython itself, before this module is asked.

The rules are deliberately coarse, so they do not need a list of every safe torch function:

* a module may be reached only if it is in :data:`ALLOWED_MODULES` (``torch.os``, ``torch.hub``,
  ``numpy.lib``, ``numpy.ctypeslib``... are modules outside it and are refused);
* an attribute name that reads or writes files, loads code, or changes process-wide state is refused
  on any object (:data:`REFUSED_NAME_PARTS`: ``load``, ``save``, ``file``, ``memmap``, ``seed``,
  ``set_``, ``register``, ``guard``, ``dispatch``...), because torch and numpy expose such functions both
  as module functions and methods;
* nothing may be read from a module outside the set, however it was reached (a call that returns a
  module, such as ``torch.get_device_module``, hands out ``torch.cuda``);
* pybind11 classes (TorchScript internals, ``torch.Future``, dispatch keys and guards, file readers and
  writers) are refused: numeric code never needs them, and they act on the whole process.
"""

from __future__ import annotations

import copy
import functools
import math
import re
import types
from typing import Any

import numpy
import torch
import torch.distributions
import torch.fft
import torch.linalg
import torch.nn.functional
import torch.special
from RestrictedPython.Guards import safer_getattr

# Importable by name and reachable as attributes. Submodules are listed one by one: a package being
# allowed does not allow what it happens to import (torch imports os, numpy imports ctypes helpers).
ALLOWED_MODULES: frozenset[str] = frozenset(
    {
        "math",
        "torch",
        "torch.nn",
        "torch.nn.functional",
        "torch.linalg",
        "torch.special",
        "torch.fft",
        "torch.distributions",
        "numpy",
        "numpy.linalg",
        "numpy.fft",
        "numpy.random",
    }
)
# The names ``import X`` may bind at top level (``import torch.nn.functional as F`` is one of these too).
IMPORT_ROOTS: frozenset[str] = frozenset(name.split(".")[0] for name in ALLOWED_MODULES)

# Substrings of attribute names refused on every object: file and code loading (torch.load,
# np.fromfile, ndarray.tofile, torch.ops.load_library, np.memmap, np.DataSource), process-wide state
# (torch.manual_seed, torch.set_num_threads, np.seterr, torch.use_deterministic_algorithms), code
# generation (torch.compile), raw memory (ndarray.ctypes), shared-memory files (Tensor.share_memory_),
# module imports by name (torch.ops.import_module), str.format (reaches dunder attributes), callables that
# return modules (torch.get_device_module("cuda") is torch.cuda, whose allocator loads shared libraries),
# guard and dispatch objects that change the whole process (torch.ExcludeDispatchKeyGuard kept alive turns
# autograd off), and process-wide registries and buffers (torch.distributions.register_kl, np.setbufsize).
REFUSED_NAME_PARTS: tuple[str, ...] = (
    "load",
    "save",
    "file",
    "dump",
    "memmap",
    "datasource",
    "fromregex",
    "txt",
    "seed",
    "rng_state",
    "set_",
    "seterr",
    "deterministic",
    "compile",
    "ctypes",
    "format",
    "hub",
    "library",
    "storage",
    "share_memory",
    "import",
    "device_module",
    "guard",
    "dispatch",
    "register",
    "setbufsize",
)
_REFUSED_NAMES = re.compile("|".join(re.escape(part) for part in REFUSED_NAME_PARTS), re.IGNORECASE)


@functools.lru_cache(maxsize=4096)  # called on every attribute access of running sandboxed code
def name_refusal(name: str) -> str | None:
    """Why the attribute ``name`` is refused on any object, or None.

    Example:
        >>> name_refusal("softmax") is None, name_refusal("fromfile")
        (True, "attribute 'fromfile' is not allowed (file, code loading or process-wide state)")
    """
    if _REFUSED_NAMES.search(name):
        return f"attribute {name!r} is not allowed (file, code loading or process-wide state)"
    return None


def attribute_refusal(obj: Any, name: str) -> str | None:
    """Why ``obj.name`` is refused (one line), or None when sandboxed code may read it.

    Example:
        >>> import torch
        >>> attribute_refusal(torch, "zeros") is None
        True
        >>> attribute_refusal(torch, "os")
        "attribute 'os' of torch is a module outside the sandbox"
        >>> attribute_refusal(torch, "Future")
        "attribute 'Future' of torch is a pybind11 class (TorchScript, dispatch or guard internals act process-wide)"
    """
    refusal = name_refusal(name)
    if refusal is not None:
        return refusal
    if isinstance(obj, types.ModuleType) and obj.__name__ not in ALLOWED_MODULES:
        return f"attribute {name!r} of module {obj.__name__}: the module is outside the sandbox (returned by a call?)"
    value = getattr(obj, name, None)
    owner = obj.__name__ if isinstance(obj, types.ModuleType) else type(obj).__name__
    if isinstance(value, types.ModuleType) and value.__name__ not in ALLOWED_MODULES:
        return f"attribute {name!r} of {owner} is a module outside the sandbox"
    if isinstance(value, type) and "pybind11" in type(value).__name__:
        return f"attribute {name!r} of {owner} is a pybind11 class (TorchScript, dispatch or guard internals act process-wide)"
    return None


_SHARED_CONTAINERS = (dict, list, set, bytearray)


class SandboxRefusal(RuntimeError):
    """Raised while sandboxed code runs and reaches something it may not (message: the one-line reason).

    Example:
        >>> str(SandboxRefusal("attribute 'load' is not allowed"))
        "attribute 'load' is not allowed"
    """


def guarded_getattr(obj: Any, name: str, default: Any = None) -> Any:
    """RestrictedPython's ``_getattr_``: :func:`attribute_refusal`, then ``safer_getattr``.

    ``safer_getattr`` (the library's) refuses ``_`` names, ``str.format`` and frame/traceback
    attributes; this adds the module and name rules of this module, and hands out copies of the
    dicts and lists that modules and classes hold (shared library state).

    Example:
        >>> guarded_getattr(math, "sqrt")(4.0)
        2.0
        >>> guarded_getattr(torch, "load")
        Traceback (most recent call last):
        ...
        torchrl_ahrs.sandbox.guards.SandboxRefusal: attribute 'load' is not allowed (file, code loading or process-wide state)
    """
    refusal = attribute_refusal(obj, name) if isinstance(name, str) else None
    if refusal is not None:
        raise SandboxRefusal(refusal)
    value = safer_getattr(obj, name, default)
    if isinstance(value, _SHARED_CONTAINERS) and not _own_attribute(obj, name):
        # a module's or class's dict/list is state every user of the library shares (np.typecodes,
        # Normal(0, 1).arg_constraints): sandboxed code reads a copy, its writes stay its own
        return copy.copy(value)
    return value


def _own_attribute(obj: Any, name: str) -> bool:
    """Whether ``name`` lives in ``obj``'s own instance dict (not a module's, not inherited from a class)."""
    if isinstance(obj, (types.ModuleType, type)):
        return False
    try:
        return name in vars(obj)
    except TypeError:  # no __dict__
        return False


WRITABLE_TYPES = (torch.Tensor, numpy.ndarray, list, dict, set)


def guarded_write(obj: Any) -> Any:
    """RestrictedPython's ``_write_``: item assignment into tensors, arrays and containers only.

    ``scores[i] = v`` is ordinary rule code; ``torch.zeros = f`` (rebinding a module attribute in the
    training process) is not. Attribute assignment is refused statically; this is the runtime half.

    Example:
        >>> guarded_write([0, 1]) == [0, 1]
        True
        >>> guarded_write(torch)
        Traceback (most recent call last):
        ...
        torchrl_ahrs.sandbox.guards.SandboxRefusal: writing into module is not allowed
    """
    if isinstance(obj, WRITABLE_TYPES):
        return obj
    raise SandboxRefusal(f"writing into {type(obj).__name__} is not allowed")


MODULES: dict[str, types.ModuleType] = {
    "math": math,
    "torch": torch,
    "torch.nn": torch.nn,
    "torch.nn.functional": torch.nn.functional,
    "torch.linalg": torch.linalg,
    "torch.special": torch.special,
    "torch.fft": torch.fft,
    "torch.distributions": torch.distributions,
    "numpy": numpy,
    "numpy.linalg": numpy.linalg,
    "numpy.fft": numpy.fft,
    "numpy.random": numpy.random,
}
assert set(MODULES) == ALLOWED_MODULES  # one list, two views (names for the static gate, objects here)
