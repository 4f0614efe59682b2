"""The sandbox's restricted execution (no dangerous builtins), the child's validation of outputs (shape, NaN,
errors, allocations, CPU), the command line, and its place below the rest of the package. The corpora are in
``test_sandbox_accepts.py`` (ordinary code) and ``test_sandbox_refuses.py`` (hostile code)."""

import inspect
import subprocess
import sys
import textwrap

import pytest
import torch

from torchrl_ahrs.sandbox import (
    check,
    check_file,
    check_source,
    load_functions,
    validate,
    validate_in_child,
)
from torchrl_ahrs.sandbox.__main__ import main as cli_main

HEAD = "def rule(mean_returns, var_returns, history, previous_weights):\n"


def test_restricted_execution_has_no_dangerous_builtins():
    fns = load_functions(HEAD + "    return mean_returns * 2\n")
    namespace = inspect.unwrap(fns["rule"]).__globals__
    assert "open" not in namespace["__builtins__"] and "eval" not in namespace["__builtins__"]
    assert "getattr" not in namespace["__builtins__"] and "type" not in namespace["__builtins__"]
    with pytest.raises(ImportError):
        namespace["__builtins__"]["__import__"]("os")
    assert fns["rule"](torch.tensor([1.0, -2.0]), None, None, None).tolist() == [2.0, -4.0]
    assert list(inspect.signature(fns["rule"]).parameters) == [
        "mean_returns",
        "var_returns",
        "history",
        "previous_weights",
    ]


RUNTIME_BROKEN = textwrap.dedent(
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
    path.write_text(RUNTIME_BROKEN)
    assert check_source(RUNTIME_BROKEN).ok  # the static gate lets these through ...
    verdict = check_file(path, "rule")  # ... the child's calls do not
    assert not verdict.ok
    reasons = "\n".join(verdict.reasons)
    assert "wrong_shape: output shape (5, 1), expected (1,)" in reasons
    assert "not_finite: output is not finite" in reasons
    assert "raises: raised IndexError" in reasons
    assert "huge_allocation: memory limit exceeded" in reasons
    assert "fine:" not in reasons and len(verdict.reasons) == 4


def test_child_cpu_limit_stops_a_long_computation(tmp_path):
    path = tmp_path / "slow.py"
    path.write_text(
        "import torch\n"
        + HEAD
        + "    x = torch.rand(300, 300)\n    for i in range(100000):\n        x = torch.tanh(x @ x)\n"
        + "    return mean_returns + x.sum()\n"
    )
    verdict = validate_in_child(path, "rule", cpu_seconds=1)
    assert not verdict.ok and "CPU-time limit exceeded" in verdict.reasons[0]


def test_cli_validates_aux_on_given_inputs_or_a_provider(tmp_path, capsys):
    path = tmp_path / "aux.py"
    path.write_text("def compute_aux_reward(obs):\n    return obs['height'] - 1.0\n")
    inputs = tmp_path / "inputs.pt"
    torch.save({"height": torch.ones(8)}, inputs)
    command = ["check", str(path), "--kind", "aux"]
    assert cli_main([*command, "--inputs", str(inputs)]) == 0, capsys.readouterr().out
    asked = []

    def provider(file, task):
        asked.append((file, task))
        return {"height": torch.ones(4)}

    assert cli_main([*command, "--task", "somewhere"], provider=provider) == 0
    assert asked == [(str(path), "somewhere")]
    assert cli_main(command, provider=lambda file, task: None) == 1  # synthetic inputs have no "height"
    assert "KeyError" in capsys.readouterr().out


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


def test_the_sandbox_imports_nothing_above_it():
    # The sandbox is a leaf: it must not import the task, config, LLM or reward layers (no cycles).
    code = (
        "import sys, torchrl_ahrs.sandbox, torchrl_ahrs.sandbox.server, torchrl_ahrs.sandbox.__main__\n"
        "bad = [m for m in sys.modules if m.startswith('torchrl_ahrs.') and not m.startswith('torchrl_ahrs.sandbox')]\n"
        "print(bad)\n"
    )
    finished = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert finished.stdout.strip() == "[]", finished.stdout + finished.stderr


def _check_in_forked_process() -> bool:
    return check(HEAD + "    return mean_returns * 3\n", "rule", num_components=2).ok


def test_a_forked_process_starts_its_own_worker_and_leaves_the_parents_alone():
    import multiprocessing

    assert check(HEAD + "    return mean_returns\n", "rule", num_components=2).ok  # the parent's worker runs
    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.apply(_check_in_forked_process)
    assert check(HEAD + "    return mean_returns * 2\n", "rule", num_components=2).ok
