"""The sandbox refuses hostile code: statically (before anything runs, with the reason), while running (the guards
in the training process and the isolated child), and by process isolation alone (RestrictedPython switched off)."""

import subprocess
import sys
import time

import pytest
import torch

from torchrl_ahrs.sandbox import (
    SandboxRefusal,
    check,
    check_source,
    load_functions,
    validate_source,
)
from torchrl_ahrs.scheduling.rules import DEFAULT_REPOSITORY

HEAD = "def rule(mean_returns, var_returns, history, previous_weights):\n"


STATIC_HOSTILE = {
    "import os": ("import os\n" + HEAD + "    return mean_returns\n", "import of 'os'"),
    "import sys": ("import sys\n" + HEAD + "    return mean_returns\n", "import of 'sys'"),
    "import socket": ("import socket\n" + HEAD + "    return mean_returns\n", "import of 'socket'"),
    "import operator (attrgetter)": ("import operator\n" + HEAD + "    return mean_returns\n", "import of 'operator'"),
    "import importlib": ("import importlib\n" + HEAD + "    return mean_returns\n", "import of 'importlib'"),
    "from-import": ("from subprocess import run\n" + HEAD + "    return mean_returns\n", "import from 'subprocess'"),
    "relative import": ("from . import x\n" + HEAD + "    return mean_returns\n", "import from None"),
    "torch submodule outside the set": ("import torch.utils\n" + HEAD + "    return mean_returns\n", "torch.utils"),
    "from torch import os": (
        "from torch import os\n" + HEAD + "    return mean_returns\n",
        "'os' of torch is a module",
    ),
    "__import__": (HEAD + "    return __import__('os').getcwd()\n", '"__import__" is an invalid variable name'),
    "dunder walk": (HEAD + "    return mean_returns.__class__.__mro__[-1].__subclasses__()\n", 'starts with "_"'),
    "dunder globals": (HEAD + "    return rule.__globals__\n", '"__globals__" is an invalid attribute'),
    "dunder builtins": (HEAD + "    return __builtins__\n", '"__builtins__" is an invalid variable name'),
    "generator frame": (HEAD + "    g = (x for x in [1])\n    return g.gi_frame\n", '"gi_frame" is a restricted name'),
    "open": (HEAD + "    data = open('/etc/passwd')\n    return mean_returns\n", "name 'open' is not allowed"),
    "exec": (HEAD + "    exec('import os')\n    return mean_returns\n", "name 'exec' is not allowed"),
    "eval": (HEAD + "    return eval('mean_returns')\n", "name 'eval' is not allowed"),
    "compile": (HEAD + "    c = compile('1', 'x', 'eval')\n    return mean_returns\n", "name 'compile' is not allowed"),
    "getattr": (HEAD + "    return getattr(mean_returns, 'numpy')()\n", "name 'getattr' is not allowed"),
    "vars": (HEAD + "    return vars(mean_returns)\n", "name 'vars' is not allowed"),
    "type": (HEAD + "    return type(mean_returns)\n", "name 'type' is not allowed"),
    "globals": (HEAD + "    g = globals()\n    return mean_returns\n", "name 'globals' is not allowed"),
    "torch.load": ("import torch\n" + HEAD + "    return torch.load('x.pt')\n", "attribute 'load'"),
    "torch.save (file write)": (
        "import torch\n" + HEAD + "    torch.save(mean_returns, '/tmp/x')\n    return mean_returns\n",
        "attribute 'save'",
    ),
    "numpy save (file write)": (
        "import numpy as np\n" + HEAD + "    np.save('/tmp/x', 1)\n    return mean_returns\n",
        "attribute 'save'",
    ),
    "torch.hub": ("import torch\n" + HEAD + "    return torch.hub.load('a', 'b')\n", "attribute 'hub'"),
    "torch.os.system": (
        "import torch\n" + HEAD + "    torch.os.system('true')\n    return mean_returns\n",
        "'os' of torch is a module",
    ),
    "torch.ops.load_library": (
        "import torch\n" + HEAD + "    torch.ops.load_library('x.so')\n    return mean_returns\n",
        "attribute 'load_library'",
    ),
    "torch.ops.import_module": (
        "import torch\n" + HEAD + "    torch.ops.import_module('antigravity')\n    return mean_returns\n",
        "attribute 'import_module'",
    ),
    "torch.manual_seed": (
        "import torch\n" + HEAD + "    torch.manual_seed(0)\n    return mean_returns\n",
        "attribute 'manual_seed'",
    ),
    "numpy ctypeslib": ("import numpy as np\n" + HEAD + "    return np.ctypeslib\n", "attribute 'ctypeslib'"),
    "numpy file": ("import numpy as np\n" + HEAD + "    return np.fromfile('x')\n", "attribute 'fromfile'"),
    "tensor method escape": (HEAD + "    return mean_returns.numpy().tofile('x')\n", "attribute 'tofile'"),
    "storage from file": (
        HEAD + "    return mean_returns.untyped_storage().from_file('x')\n",
        "attribute 'untyped_storage'",
    ),
    "while": (HEAD + "    while True:\n        pass\n    return mean_returns\n", "While is not allowed"),
    "lambda": (HEAD + "    f = lambda x: x\n    return f(mean_returns)\n", "Lambda is not allowed"),
    "class": ("class A:\n    pass\n" + HEAD + "    return mean_returns\n", "ClassDef"),
    "try": (HEAD + "    try:\n        x = 1\n    except Exception:\n        x = 2\n    return mean_returns\n", "Try"),
    "with": (HEAD + "    with mean_returns:\n        pass\n    return mean_returns\n", "With"),
    "nested def": (HEAD + "    def g():\n        return 1\n    return mean_returns\n", "nested functions"),
    "decorator": ("@staticmethod\n" + HEAD + "    return mean_returns\n", "decorators"),
    "global": (HEAD + "    global x\n    return mean_returns\n", "Global"),
    "f-string": (HEAD + "    s = f'{mean_returns}'\n    return mean_returns\n", "JoinedStr"),
    "format trick": (
        HEAD + "    s = '{0.__class__}'.format(mean_returns)\n    return mean_returns\n",
        "attribute 'format'",
    ),
    "attribute assignment": (
        "import torch\n" + HEAD + "    torch.zeros = None\n    return mean_returns\n",
        "assigning to attribute 'zeros'",
    ),
    "huge power": (HEAD + "    return mean_returns * 10 ** 100000\n", "exponent 100000"),
    "power tower": (HEAD + "    return mean_returns * 2 ** 10 ** 10\n", "tower of exponents"),
    "huge repetition": (HEAD + "    x = [0.0] * 100000000000\n    return mean_returns\n", "integer constant too large"),
    "star args": (HEAD + "    return max(*mean_returns)\n", "Starred"),
    "yield": (HEAD + "    x = yield mean_returns\n    return x\n", "Yield"),
    "top-level call": ("print('hi')\n" + HEAD + "    return mean_returns\n", "top-level Expr"),
    "top-level loop": ("for i in range(3):\n    pass\n" + HEAD + "    return mean_returns\n", "top-level For"),
    "syntax": (HEAD + "    return (\n", "syntax error"),
    "no function": ("x = 1\n", "no function defined"),
}


@pytest.mark.parametrize("label", sorted(STATIC_HOSTILE))
def test_static_gate_refuses_hostile_code(label):
    source, reason = STATIC_HOSTILE[label]
    verdict = check_source(source)
    assert not verdict.ok
    assert any(reason in text for text in verdict.reasons), verdict.reasons
    assert all("\n" not in text for text in verdict.reasons)  # one line per reason
    with pytest.raises(ValueError, match="sandbox refused"):
        load_functions(source)
    assert not check(source, "rule").ok  # and the full gate never reaches the child


def test_a_variable_named_like_a_builtin_is_not_the_builtin():
    assert check_source(HEAD + "    input = mean_returns\n    return input * 2\n").ok
    assert not check_source(HEAD + "    return input()\n").ok


RUNTIME_HOSTILE = {
    "data-dependent loop bound": (
        HEAD + "    for i in range(int(mean_returns.abs().max()) * 10 ** 9):\n        pass\n    return mean_returns\n",
        "exceeds the sandbox's",
    ),
    "huge constant range": (
        HEAD + "    for i in range(10 ** 12):\n        pass\n    return mean_returns\n",
        "range of",
    ),
    "triple loop": (
        HEAD
        + "    t = 0\n    for i in range(1000):\n        for j in range(1000):\n            for k in range(1000):\n"
        + "                t = t + 1\n    return mean_returns + t\n",
        "more than 1000000 loop iterations",
    ),
    "list of a huge range": (HEAD + "    x = list(range(10 ** 10))\n    return mean_returns\n", "range of"),
    "memory bomb (tensor)": (
        "import torch\n" + HEAD + "    x = torch.ones(10 ** 6, 10 ** 5)\n    return mean_returns\n",
        "memory limit exceeded",
    ),
    "memory bomb (list)": (HEAD + "    block = [0.0] * 10 ** 9\n    return mean_returns\n", "memory limit exceeded"),
    "write into a module": (
        "import torch\n" + HEAD + "    m = torch\n    m['zeros'] = 1\n    return mean_returns\n",
        "writing into module",
    ),
    "module reached through a value": (
        "import torch.nn.functional as F\n" + HEAD + "    t = F.torch\n    return t.os.getcwd()\n",
        "'os' of torch is a module outside the sandbox",
    ),
    "CPU-bound loop": (
        "import torch\n"
        + HEAD
        + "    x = torch.rand(300, 300)\n    for i in range(100000):\n        x = torch.tanh(x @ x)\n    return mean_returns\n",
        "CPU-time limit exceeded",
    ),
}


@pytest.mark.parametrize("label", sorted(RUNTIME_HOSTILE))
def test_running_hostile_code_is_stopped_in_the_child(label):
    source, reason = RUNTIME_HOSTILE[label]
    assert check_source(source).ok  # the static gate lets these through ...
    verdict = check(source, "rule", num_components=3)  # ... the guards and the child do not
    assert not verdict.ok and reason in " ".join(verdict.reasons), verdict.reasons
    assert all("\n" not in text for text in verdict.reasons)


def test_loop_budget_also_holds_in_the_training_process():
    (rule,) = load_functions(HEAD + "    for i in range(10 ** 7):\n        pass\n    return mean_returns\n").values()
    with pytest.raises(SandboxRefusal, match="exceeds"):
        rule(torch.ones(3), None, None, None)
    (rule,) = load_functions(
        HEAD
        + "    t = 0\n    for i in range(2000):\n        for j in range(2000):\n            t = t + 1\n    return t\n"
    ).values()
    with pytest.raises(SandboxRefusal, match="loop iterations"):
        rule(None, None, None, None)


def test_sandboxed_code_cannot_change_its_callers_tensors_or_shared_library_state():
    source = (
        "import numpy as np\n"
        "import torch\n"
        "def compute_aux_reward(obs):\n"
        "    obs['observation'][:, 0] = 100.0\n"
        "    obs['action'].mul_(0.0)\n"
        "    codes = np.typecodes\n"
        "    codes['All'] = 'broken'\n"
        "    normal = torch.distributions.Normal(0.0, 1.0)\n"
        "    normal.arg_constraints.clear()\n"
        "    return obs['observation'][:, 0]\n"
    )
    (aux,) = load_functions(source).values()
    obs = {"observation": torch.zeros(3, 2), "action": torch.ones(3, 1)}
    reward = aux(obs)
    assert reward.tolist() == [100.0, 100.0, 100.0]
    assert obs["observation"].abs().sum() == 0 and obs["action"].sum() == 3  # the caller's tensors are untouched
    import numpy

    assert numpy.typecodes["All"] != "broken"
    assert torch.distributions.Normal.arg_constraints  # the class's dict is untouched
    reward[0] = -1.0
    assert obs["observation"][0, 0] == 0  # and the output does not alias the input


def test_one_function_called_from_two_threads_counts_each_call_alone():
    import threading

    (rule,) = load_functions(
        HEAD + "    t = 0\n    for i in range(600000):\n        t = t + 1\n    return t\n", loop_budget=1_000_000
    ).values()  # long enough for the threads to interleave: a shared count would pass the budget
    results = []
    threads = [threading.Thread(target=lambda: results.append(rule(None, None, None, None))) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert results == [600000] * 4


def test_budget_is_per_call():
    fns = load_functions(
        HEAD + "    t = 0\n    for i in range(600):\n        t = t + 1\n    return t\n", loop_budget=1000
    )
    assert fns["rule"](None, None, None, None) == 600 and fns["rule"](None, None, None, None) == 600


UNRESTRICTED_HOSTILE = {
    "write a file": (
        HEAD + "    with open('/tmp/torchrl_ahrs_sandbox_probe', 'w') as handle:\n        handle.write('x')\n"
        "    return mean_returns\n",
        "open for writing is refused",
    ),
    "read a secret": (
        HEAD + "    open('/etc/passwd').read()\n    return mean_returns\n",
        "open outside the Python installation",
    ),
    "socket": (
        # socket.socket, not create_connection: the latter resolves the address first, whose lazy imports
        # may meet the file-system refusals before any socket exists (refused, but not for this reason)
        "import socket\n" + HEAD + "    socket.socket().connect(('127.0.0.1', 9))\n    return mean_returns\n",
        "socket.",
    ),
    "os.system": (
        "import os\n" + HEAD + "    os.system('touch /tmp/torchrl_ahrs_sandbox_probe')\n    return mean_returns\n",
        "os.system is refused",
    ),
    "subprocess": (
        "import subprocess\n" + HEAD + "    subprocess.run(['true'])\n    return mean_returns\n",
        "subprocess.Popen is refused",
    ),
    "fork": ("import os\n" + HEAD + "    os.fork()\n    return mean_returns\n", "os.fork is refused"),
    "delete a file": (
        "import os\n" + HEAD + "    os.remove('/tmp/torchrl_ahrs_sandbox_probe')\n    return mean_returns\n",
        "os.remove is refused",
    ),
    "raise the limits": (
        "import resource\n" + HEAD + "    resource.setrlimit(resource.RLIMIT_CPU, (-1, -1))\n    return mean_returns\n",
        "resource.setrlimit is refused",
    ),
    "infinite loop": (HEAD + "    while True:\n        pass\n", "CPU-time limit exceeded"),
    "memory bomb": (HEAD + "    block = bytearray(10 ** 11)\n    return mean_returns\n", "memory limit exceeded"),
}


@pytest.mark.parametrize("label", sorted(UNRESTRICTED_HOSTILE))
def test_isolation_alone_refuses_file_network_process_and_resource_abuse(label, tmp_path):
    source, reason = UNRESTRICTED_HOSTILE[label]
    verdict = validate_source(source, "rule", num_components=3, restricted=False)
    assert not verdict.ok and reason in " ".join(verdict.reasons), verdict.reasons
    import os

    assert not os.path.exists("/tmp/torchrl_ahrs_sandbox_probe")


def test_wall_clock_deadline_kills_a_sleeping_child():
    source = "import time\n" + HEAD + "    time.sleep(60)\n    return mean_returns\n"
    started = time.perf_counter()
    verdict = validate_source(source, "rule", num_components=3, restricted=False, wall_seconds=1.0)
    assert not verdict.ok and "wall time" in verdict.reasons[0]
    assert time.perf_counter() - started < 10


def test_worker_environment_has_no_credentials(monkeypatch):
    from torchrl_ahrs.sandbox.isolation import _worker_environment

    monkeypatch.setenv("OPENAI_API_KEY", "sk-test")
    monkeypatch.setenv("HF_TOKEN", "hf-test")
    environment = _worker_environment()
    assert "OPENAI_API_KEY" not in environment and "HF_TOKEN" not in environment
    assert environment["OMP_NUM_THREADS"] == "1"


def test_cli_accepts_shipped_rules_and_refuses_hostile_file(tmp_path):
    accepted = subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.sandbox", "check", str(DEFAULT_REPOSITORY), "--kind", "rule"],
        capture_output=True,
        text=True,
    )
    assert accepted.returncode == 0, accepted.stdout + accepted.stderr
    assert "accepted" in accepted.stdout and "mean_returns_only" in accepted.stdout
    hostile = tmp_path / "hostile.py"
    hostile.write_text(STATIC_HOSTILE["dunder walk"][0].replace("rule(", "a(") + STATIC_HOSTILE["import os"][0])
    refused = subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.sandbox", "check", str(hostile), "--kind", "rule"],
        capture_output=True,
        text=True,
    )
    assert refused.returncode == 1 and refused.stdout.count("  - ") >= 3, refused.stdout
