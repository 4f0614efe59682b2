"""The sandbox refuses hostile code (statically and in the limited child) and accepts the shipped rules."""

import subprocess
import sys
import textwrap

import pytest
import torch

from torchrl_ahrs.llm.sandbox import check_file, check_source, load_functions, validate_in_child
from torchrl_ahrs.llm.sandbox_worker import validate
from torchrl_ahrs.scheduling.rules import DEFAULT_REPOSITORY

HEAD = "def rule(mean_returns, var_returns, history, previous_weights):\n"

# Each body must be refused by the static gate, with a reason containing the given text.
STATIC_HOSTILE = {
    "import os": ("import os\n" + HEAD + "    return mean_returns\n", "import of 'os'"),
    "from-import": ("from subprocess import run\n" + HEAD + "    return mean_returns\n", "import from 'subprocess'"),
    "relative import": ("from . import x\n" + HEAD + "    return mean_returns\n", "import from None"),
    "__import__": (HEAD + "    return __import__('os').getcwd()\n", "'__import__' starts with '_'"),
    "dunder walk": (HEAD + "    return mean_returns.__class__.__mro__[-1].__subclasses__()\n", "starts with '_'"),
    "open": (HEAD + "    data = open('/etc/passwd')\n    return mean_returns\n", "name 'open' is not allowed"),
    "exec": (HEAD + "    exec('import os')\n    return mean_returns\n", "expression statements"),
    "eval": (HEAD + "    return eval('mean_returns')\n", "name 'eval' is not allowed"),
    "getattr": (HEAD + "    return getattr(mean_returns, 'numpy')()\n", "name 'getattr' is not allowed"),
    "globals": (HEAD + "    g = globals()\n    return mean_returns\n", "name 'globals' is not allowed"),
    "torch.load": ("import torch\n" + HEAD + "    return torch.load('x.pt')\n", "attribute 'load'"),
    "torch.hub": ("import torch\n" + HEAD + "    return torch.hub.load('a', 'b')\n", "attribute 'hub'"),
    "numpy file": ("import numpy as np\n" + HEAD + "    return np.fromfile('x')\n", "attribute 'fromfile'"),
    "tensor method escape": (HEAD + "    return mean_returns.numpy().tofile('x')\n", "attribute 'numpy'"),
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
    "huge power": (HEAD + "    return mean_returns * 10 ** 100000\n", "exponent 100000"),
    "data-dependent loop": (
        HEAD + "    for i in range(int(mean_returns[0])):\n        pass\n    return mean_returns\n",
        "range() bound",
    ),
    "triple loop": (
        HEAD
        + "    for i in range(3):\n        for j in range(3):\n            for k in range(3):\n                pass\n    return mean_returns\n",
        "nested deeper",
    ),
    "star args": (HEAD + "    return max(*mean_returns)\n", "Starred"),
    "yield": (HEAD + "    x = yield mean_returns\n    return x\n", "Yield"),
    "top-level call": ("print('hi')\n" + HEAD + "    return mean_returns\n", "top-level Expr"),
    "syntax": (HEAD + "    return (\n", "syntax error"),
    "no function": ("x = 1\n", "no function defined"),
}


@pytest.mark.parametrize("label", sorted(STATIC_HOSTILE))
def test_static_gate_refuses_hostile_code(label):
    source, reason = STATIC_HOSTILE[label]
    verdict = check_source(source)
    assert not verdict.ok
    assert any(reason in text for text in verdict.reasons), verdict.reasons
    with pytest.raises(ValueError, match="sandbox refused"):
        load_functions(source)


def test_restricted_execution_has_no_dangerous_builtins():
    fns = load_functions(HEAD + "    return mean_returns * 2\n")
    namespace = fns["rule"].__globals__
    assert "open" not in namespace["__builtins__"] and "eval" not in namespace["__builtins__"]
    with pytest.raises(ImportError):
        namespace["__builtins__"]["__import__"]("os")
    assert fns["rule"](torch.tensor([1.0, -2.0]), None, None, None).tolist() == [2.0, -4.0]


RUNTIME_HOSTILE = textwrap.dedent(
    """
    import torch

    def wrong_shape(mean_returns, var_returns, history, previous_weights):
        return history

    def not_finite(mean_returns, var_returns, history, previous_weights):
        return mean_returns / (var_returns - var_returns)

    def raises(mean_returns, var_returns, history, previous_weights):
        return history[10]

    def huge_allocation(mean_returns, var_returns, history, previous_weights):
        block = [0.0] * 10 ** 9
        return mean_returns

    def fine(mean_returns, var_returns, history, previous_weights):
        return torch.sqrt(var_returns) - mean_returns
    """
)


def test_child_refuses_wrong_shape_nan_errors_and_huge_allocations(tmp_path):
    path = tmp_path / "hostile.py"
    path.write_text(RUNTIME_HOSTILE)
    assert check_source(RUNTIME_HOSTILE).ok  # the static gate lets these through ...
    verdict = check_file(path, "rule")  # ... the child's calls do not
    assert not verdict.ok
    reasons = "\n".join(verdict.reasons)
    assert "wrong_shape: output shape (5, 1), expected (1,)" in reasons
    assert "not_finite: output is not finite" in reasons
    assert "raises: raised IndexError" in reasons
    assert "huge_allocation: memory limit exceeded" in reasons
    assert "fine:" not in reasons and len(verdict.reasons) == 4


def test_child_cpu_limit_stops_a_long_loop(tmp_path):
    path = tmp_path / "slow.py"
    path.write_text(
        HEAD
        + "    total = 0.0\n    for i in range(10000):\n        for j in range(10000):\n            total = total + i * j\n"
        + "    return mean_returns + total\n"
    )
    verdict = validate_in_child(path, "rule", cpu_seconds=1)
    assert not verdict.ok and "CPU-time limit exceeded" in verdict.reasons[0]


def test_cli_accepts_shipped_rules_and_refuses_hostile_file(tmp_path):
    accepted = subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.sandbox", "check", str(DEFAULT_REPOSITORY), "--kind", "rule"],
        capture_output=True,
        text=True,
    )
    assert accepted.returncode == 0, accepted.stdout + accepted.stderr
    assert "accepted" in accepted.stdout and "hdpg" in accepted.stdout
    hostile = tmp_path / "hostile.py"
    hostile.write_text(STATIC_HOSTILE["dunder walk"][0].replace("rule(", "a(") + STATIC_HOSTILE["import os"][0])
    refused = subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.sandbox", "check", str(hostile), "--kind", "rule"],
        capture_output=True,
        text=True,
    )
    assert refused.returncode == 1 and refused.stdout.count("  - ") >= 3, refused.stdout


def test_aux_kind_validates_reward_shape():
    good = "import torch\ndef compute_aux_reward(obs):\n    return -torch.square(obs['action']).sum(-1)\n"
    bad = "def compute_aux_reward(obs):\n    return obs['observation']\n"
    assert validate(good, "aux")["ok"]
    report = validate(bad, "aux")
    assert not report["ok"] and "output shape" in report["reasons"][0]
    assert "no function named compute_aux_reward" in validate(HEAD + "    return mean_returns\n", "aux")["reasons"][0]


def test_tensor_literals_work_inside_the_sandbox(tmp_path):
    # torch.tensor([...]) imports torch submodules from C through the frame's __import__
    path = tmp_path / "rules.py"
    path.write_text(
        textwrap.dedent(
            '''
            import torch


            def literal_offset(mean_returns, var_returns, history, previous_weights):
                """Literal Offset

                Adds a constant built from a literal.

                math: s_k = mu_k + 1
                """
                return mean_returns + torch.tensor([1.0])
            '''
        )
    )
    verdict = check_file(path, "rule")
    assert verdict.ok, verdict.reasons
    (rule,) = load_functions(path.read_text()).values()
    assert rule(torch.tensor([1.0, 2.0]), None, None, None).tolist() == [2.0, 3.0]
