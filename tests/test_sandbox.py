"""The sandbox accepts ordinary numeric code (a held-out corpus written the way an LLM following our
prompts writes it) and refuses hostile code (statically, while running, and in the isolated child)."""

import inspect
import subprocess
import sys
import textwrap
import time

import pytest
import torch

from torchrl_ahrs.sandbox import (
    SandboxRefusal,
    check,
    check_file,
    check_source,
    load_functions,
    validate,
    validate_in_child,
    validate_source,
)
from torchrl_ahrs.sandbox.__main__ import main as cli_main
from torchrl_ahrs.scheduling.rules import DEFAULT_REPOSITORY

HEAD = "def rule(mean_returns, var_returns, history, previous_weights):\n"
TASK_K = 11  # Cassie + aux: the K the held-out rules are validated at

# ---------------------------------------------------------------------------------------------------
# Held-out corpus: ordinary rules and auxiliary rewards. Every one must be accepted.
# ---------------------------------------------------------------------------------------------------

ORDINARY_RULES = {
    "torch.zeros(k) filled in a loop": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            k = mean_returns.shape[0]
            scores = torch.zeros(k)
            for i in range(k):
                scores[i] = -mean_returns[i] + 0.1 * torch.sqrt(var_returns[i] + 1e-8)
            return scores
    """,
    "empty_like": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            out = torch.empty_like(mean_returns)
            for i in range(len(mean_returns)):
                out[i] = history[:, i].std() / (history[:, i].abs().mean() + 1e-6)
            return out
    """,
    "torch.nn.functional as F": """
        import torch
        import torch.nn.functional as F

        def rule(mean_returns, var_returns, history, previous_weights):
            scale = mean_returns.abs().max() + 1e-8
            return F.softmax(-mean_returns / scale, dim=0)
    """,
    "np.asarray and numpy functions": """
        import numpy as np
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            means = np.asarray(mean_returns)
            spread = np.sqrt(np.asarray(var_returns)) + 1e-8
            scores = np.clip(-means / spread, -10.0, 10.0)
            return torch.from_numpy(scores).float()
    """,
    "range over a computed history length": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            steps = history.shape[0]
            gains = torch.zeros_like(mean_returns)
            for t in range(1, steps):
                gains = gains + (history[t] - history[t - 1])
            return -gains / max(steps - 1, 1)
    """,
    "NaN only at K=1 (unbiased std)": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            z = (mean_returns - mean_returns.mean()) / (mean_returns.std() + 1e-8)
            return -z
    """,
    "ones_like and math": """
        import math
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            base = torch.ones_like(mean_returns)
            bonus = math.log(1.0 + len(mean_returns))
            return base * bonus - torch.tanh(mean_returns / 1000.0)
    """,
    "list comprehension into torch.tensor": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            stds = [float(v) ** 0.5 for v in var_returns]
            return torch.tensor(stds) / (sum(stds) + 1e-8)
    """,
    "top-level helper and constants": """
        import torch

        EPS = 1e-8
        TEMPERATURE = 2.0

        def normalise(x):
            return (x - x.min()) / (x.max() - x.min() + EPS)

        def rule(mean_returns, var_returns, history, previous_weights):
            return torch.exp(-normalise(mean_returns) / TEMPERATURE)
    """,
    "torch.where and clamp": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            deficit = torch.where(mean_returns < 0, -mean_returns, torch.zeros_like(mean_returns))
            return torch.clamp(deficit, min=0.0, max=1e6)
    """,
    "least-squares slope of the history": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            length = history.shape[0]
            t = torch.arange(length, dtype=torch.float32)
            t = t - t.mean()
            centred = history - history.mean(dim=0, keepdim=True)
            slope = (t[:, None] * centred).sum(dim=0) / (t.pow(2).sum() + 1e-8)
            return -slope
    """,
    "augmented item assignment": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            k = len(mean_returns)
            scores = torch.zeros(k)
            for i in range(k):
                scores[i] += previous_weights[i]
                scores[i] -= 0.01 * mean_returns[i]
            return scores
    """,
    "enumerate over zip with unpacking": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            scores = []
            for i, (m, v) in enumerate(zip(mean_returns.tolist(), var_returns.tolist())):
                scores.append(v / (abs(m) + 1.0) + 0.0 * i)
            return torch.tensor(scores, dtype=torch.float32)
    """,
    "rank with argsort": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            ranks = torch.argsort(torch.argsort(mean_returns)).float()
            return ranks.max() - ranks
    """,
    "momentum on previous weights, annotated": """
        import torch

        def rule(
            mean_returns: torch.Tensor,
            var_returns: torch.Tensor,
            history: torch.Tensor,
            previous_weights: torch.Tensor,
        ) -> torch.Tensor:
            target = torch.sigmoid(-mean_returns / (mean_returns.abs().mean() + 1e-8))
            return 0.9 * previous_weights + 0.1 * target
    """,
    "dict of statistics and print for debugging": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            stats = {"mean": mean_returns, "spread": var_returns.sqrt()}
            print("stats", stats["mean"].shape)
            return stats["spread"] - stats["mean"]
    """,
    "tuple unpacking of a shape, F.normalize": """
        import torch
        from torch.nn import functional as F

        def rule(mean_returns, var_returns, history, previous_weights):
            length, k = history.shape
            drift = (history[-1] - history[0]) / max(length, 1)
            return F.normalize(-drift.abs() - 1e-3, p=1, dim=0) * k
    """,
    "numpy loop with a variable bound": """
        import numpy as np
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            h = np.asarray(history)
            n_components = h.shape[1]
            out = np.zeros(n_components)
            for j in range(n_components):
                out[j] = np.polyfit(np.arange(h.shape[0]), h[:, j], 1)[0] if h.shape[0] > 1 else 0.0
            return torch.as_tensor(-out, dtype=torch.float32)
    """,
}

ORDINARY_AUX = {
    "action penalty": """
        import torch

        def compute_aux_reward(obs):
            return -torch.square(obs["action"]).sum(dim=-1)
    """,
    "F.relu of a height margin": """
        import torch
        import torch.nn.functional as F

        def compute_aux_reward(obs):
            height = obs["observation"][:, 0]
            return -F.relu(0.5 - height)
    """,
    "numpy on the batch": """
        import numpy as np
        import torch

        def compute_aux_reward(obs):
            x = np.asarray(obs["observation"])
            return torch.as_tensor(-np.linalg.norm(x, axis=1), dtype=torch.float32)
    """,
    "loop over the batch size": """
        import torch

        def compute_aux_reward(obs):
            n = obs["action"].shape[0]
            reward = torch.zeros(n)
            for i in range(n):
                reward[i] = -obs["action"][i].abs().max()
            return reward
    """,
    "optional key with a default": """
        import torch

        def compute_aux_reward(obs):
            n = obs["observation"].shape[0]
            total = obs.get("reward.total", torch.zeros(n))
            bonus = torch.ones_like(total) * 0.1 if "info.success" not in obs else obs["info.success"]
            return bonus - 0.01 * total.abs()
    """,
    "gaussian kernel with math": """
        import math
        import torch

        SIGMA = 0.5

        def compute_aux_reward(obs):
            distance = torch.linalg.norm(obs["observation"][:, :3], dim=-1)
            return torch.exp(-distance**2 / (2 * SIGMA**2)) / math.sqrt(2 * math.pi)
    """,
    "helper and torch.where": """
        import torch

        def smoothness(action):
            return -(action[:, 1:] - action[:, :-1]).pow(2).sum(dim=-1)

        def compute_aux_reward(obs):
            a = obs["action"]
            penalty = smoothness(a) if a.shape[1] > 1 else torch.zeros(a.shape[0])
            return torch.where(penalty < -10.0, torch.full_like(penalty, -10.0), penalty)
    """,
}

# Shapes of a task batch passed in by the caller (real transitions in production).
AUX_INPUTS = {
    "observation": torch.randn(32, 9),
    "action": torch.randn(32, 4),
    "reward.total": torch.randn(32),
    "info.success": torch.zeros(32),
}


def _source(text: str) -> str:
    return textwrap.dedent(text).lstrip()


@pytest.mark.parametrize("label", sorted(ORDINARY_RULES))
def test_ordinary_rule_is_accepted_at_the_tasks_k(label):
    verdict = check(_source(ORDINARY_RULES[label]), "rule", num_components=TASK_K)
    assert verdict.ok, verdict.reasons


@pytest.mark.parametrize("label", sorted(ORDINARY_AUX))
def test_ordinary_aux_reward_is_accepted_on_the_tasks_inputs(label):
    verdict = check(_source(ORDINARY_AUX[label]), "aux", inputs=AUX_INPUTS)
    assert verdict.ok, verdict.reasons


def test_held_out_corpus_acceptance_and_time_per_check():
    corpus = [(text, "rule", {"num_components": TASK_K}) for text in ORDINARY_RULES.values()]
    corpus += [(text, "aux", {"inputs": AUX_INPUTS}) for text in ORDINARY_AUX.values()]
    assert len(corpus) >= 18
    check(_source(ORDINARY_AUX["action penalty"]), "aux")  # the worker's one-time start is not a check
    started = time.perf_counter()
    accepted = sum(check(_source(text), kind, **options).ok for text, kind, options in corpus)
    per_check = (time.perf_counter() - started) / len(corpus)
    print(f"held-out corpus: {accepted} of {len(corpus)} accepted, {per_check * 1000:.0f} ms per check")
    assert accepted == len(corpus)
    assert per_check < 1.0


def test_the_k1_rule_is_refused_when_k1_is_what_it_is_validated_at():
    source = _source(ORDINARY_RULES["NaN only at K=1 (unbiased std)"])
    verdict = check(source, "rule", num_components=1)
    assert not verdict.ok and "not finite" in verdict.reasons[0] and "K=1" in verdict.reasons[0]


# ---------------------------------------------------------------------------------------------------
# Hostile corpus, static gate: refused before anything runs, with the reason.
# ---------------------------------------------------------------------------------------------------

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


# ---------------------------------------------------------------------------------------------------
# Hostile corpus, while running: accepted by the static gate, stopped by the guards or the child.
# ---------------------------------------------------------------------------------------------------

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


# ---------------------------------------------------------------------------------------------------
# Process isolation alone (RestrictedPython switched off): the second line of defence holds.
# ---------------------------------------------------------------------------------------------------

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


# ---------------------------------------------------------------------------------------------------
# Restricted execution, child validation of outputs, the command line (kept from the first sandbox)
# ---------------------------------------------------------------------------------------------------


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


def test_cli_validates_rules_at_the_given_k(tmp_path, capsys):
    path = tmp_path / "rule.py"
    path.write_text(_source(ORDINARY_RULES["NaN only at K=1 (unbiased std)"]))
    command = ["check", str(path), "--kind", "rule"]
    assert cli_main(command) == 1  # K = 1 is among the default sizes
    assert "not finite" in capsys.readouterr().out
    assert cli_main([*command, "--num-components", "11"]) == 0


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
