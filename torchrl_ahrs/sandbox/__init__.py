"""Code safety for everything an LLM writes: weight rules and auxiliary rewards.

Code is data until it passes two gates, each built on a kept mechanism rather than on a list of
names this project would have to grow by hand:

1. **RestrictedPython** (compile time and run time, :mod:`~torchrl_ahrs.sandbox.policy`,
   :mod:`~torchrl_ahrs.sandbox.runtime`). The library compiles the code with a policy that refuses
   ``_`` names and attributes (every dunder escape: ``__class__``, ``__subclasses__``,
   ``__globals__``, ``__import__``), ``exec``/``eval``, frame attributes; it rewrites every attribute
   read, item access, loop and in-place operator into guard calls. Our policy adds the imports
   (torch, numpy, math and a few numeric submodules), refuses builtins such as ``open``/``getattr``
   and constructs numeric code has no use for (``while``, ``try``, classes...). Our guards refuse
   modules outside the allowed set (``torch.os``, ``torch.hub``) and file/state functions on any object
   (``torch.load``, ``np.fromfile``, ``torch.manual_seed``), and count loop steps per call, so
   ``for i in range(k)`` with a computed ``k`` is accepted and bounded. Everything in torch and numpy
   that is neither a module outside the set nor a file/state function is allowed: no list of
   allowed functions to keep up to date (the previous allow-list refused ``torch.zeros``).
2. **Process isolation** (:mod:`~torchrl_ahrs.sandbox.isolation`, :mod:`~torchrl_ahrs.sandbox.server`).
   The functions are called on the inputs they will see — rules at the task's own K, auxiliary
   rewards on real transitions the caller passes in — in a forked child with ``resource.setrlimit``
   limits (CPU seconds, address space, ``RLIMIT_FSIZE = 0``, few file descriptors), a PEP 578 audit
   hook refusing sockets, subprocesses, ``os.system``, file writes and reads outside the Python
   installation, and a wall-clock deadline; the report comes back as JSON. One worker process per
   parent forks the children, so a check costs milliseconds after the worker's ~1 s start.

3. **The same protection at time of use** (:mod:`~torchrl_ahrs.sandbox.session`,
   :mod:`~torchrl_ahrs.sandbox.serving`). Code that holds back until after the check's few calls (a call
   counter, a trigger on input values) must meet the same limits when training calls it: an accepted
   file's functions are served by a :class:`SandboxSession`, a key-free process with the check's rlimits
   and audit hook, a CPU timer and a wall clock per call; tensors cross in shared memory. Rules from a
   file (``scheduler.rules``) and auxiliary rewards from a file (``aux.path``) are used this way; the
   shipped, hand-written ones run in-process.

Why all three: RestrictedPython decides what code may *say*; it cannot bound CPU, memory or what torch's
C code does. The processes bound those, in the check and for every later call. Both apply one output
contract (:func:`output_contract`: dtype, shape at the training batch size, finite values).

This package depends on the standard library, torch, numpy and RestrictedPython only; task knowledge
(K, transitions) is passed in by the caller. Command line: ``python -m torchrl_ahrs.sandbox check FILE
--kind rule|aux`` (:mod:`torchrl_ahrs.sandbox.__main__`).

Example:
    >>> from torchrl_ahrs.sandbox import check
    >>> rule = "import torch\\ndef rule(m, v, h, w):\\n    return torch.zeros(m.shape[0]) + m / (m.shape[0] - 1)\\n"
    >>> check(rule, "rule", num_components=11).ok, check(rule, "rule", num_components=1).ok
    (True, False)
"""

from torchrl_ahrs.sandbox.cases import (
    AUX_FUNCTION,
    RULE_ARITY,
    aux_cases,
    check_output,
    output_contract,
    rule_cases,
    validate,
)
from torchrl_ahrs.sandbox.guards import ALLOWED_MODULES, SandboxRefusal
from torchrl_ahrs.sandbox.isolation import check, check_file, start_worker, validate_in_child, validate_source
from torchrl_ahrs.sandbox.policy import Verdict, check_source
from torchrl_ahrs.sandbox.runtime import LoopBudget, load_functions
from torchrl_ahrs.sandbox.session import SandboxCallError, SandboxSession, isolated_functions

__all__ = [
    "ALLOWED_MODULES",
    "AUX_FUNCTION",
    "RULE_ARITY",
    "LoopBudget",
    "SandboxCallError",
    "SandboxRefusal",
    "SandboxSession",
    "Verdict",
    "aux_cases",
    "check",
    "check_file",
    "check_output",
    "check_source",
    "isolated_functions",
    "load_functions",
    "output_contract",
    "rule_cases",
    "start_worker",
    "validate",
    "validate_in_child",
    "validate_source",
]
