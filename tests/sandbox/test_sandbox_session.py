"""Accepted code gets the check's protection at time of use: every hostile file of the sandbox's corpus,
held back past the check by a call counter, is stopped when training calls it in its worker; the benign
corpus runs there as it does in-process; the check and training apply one output contract."""

import textwrap
import time

import pytest
import torch
from conftest import FAST, make_cfg
from test_sandbox_accepts import ORDINARY_AUX, ORDINARY_RULES, TASK_K
from test_sandbox_refuses import HEAD, RUNTIME_HOSTILE, UNRESTRICTED_HOSTILE

from torchrl_ahrs.rewards.auxiliary import AuxiliaryReward, AuxiliaryRewardError, load_aux_function
from torchrl_ahrs.sandbox import (
    SandboxCallError,
    SandboxSession,
    check,
    check_source,
    isolated_functions,
    load_functions,
    validate_source,
)
from torchrl_ahrs.sandbox.guards import SandboxRefusal, guarded_getattr
from torchrl_ahrs.scheduling.rules import load_repository
from torchrl_ahrs.train import train

CHECK_CALLS = 20  # more calls than a check makes: the hostile part runs only at time of use
RULE_ARGS = (torch.tensor([1.0, 2.0, 3.0]), torch.ones(3), torch.ones(5, 3), torch.full((3,), 0.5))


def deferred(hostile_source: str) -> str:
    """``hostile_source``'s rule renamed ``hostile``, called by a well-behaved ``rule`` after CHECK_CALLS calls."""
    return (
        # five parameters: a helper, not a rule, so the check never calls it directly
        hostile_source.replace(HEAD, HEAD.replace("def rule(", "def hostile(").replace("):", ", deferred=0):"))
        + "\ncalls = [0]\n\n"
        + HEAD
        + "    calls[0] = calls[0] + 1\n"
        + f"    if calls[0] > {CHECK_CALLS}:\n"
        + "        return hostile(mean_returns, var_returns, history, previous_weights)\n"
        + "    return mean_returns\n"
    )


def stopped_for(reason: str, message: str) -> bool:
    """``reason`` is in ``message``; a CPU-time bound may be met by the wall clock first on a loaded machine."""
    return reason in message or ("CPU-time" in reason and "of wall time; its worker was killed" in message)


def call_until_it_fails(session: SandboxSession) -> tuple[str, float]:
    rule = isolated_functions(session, "rule")["rule"]
    for _ in range(CHECK_CALLS):
        assert rule(*RULE_ARGS).tolist() == [1.0, 2.0, 3.0]
    started = time.perf_counter()
    with pytest.raises(SandboxCallError) as caught:
        rule(*RULE_ARGS)
    return str(caught.value), time.perf_counter() - started


@pytest.mark.parametrize("label", sorted(RUNTIME_HOSTILE))
def test_runtime_hostile_corpus_deferred_past_the_check_is_stopped_at_time_of_use(label):
    source, reason = RUNTIME_HOSTILE[label]
    source = deferred(source)
    assert check(source, "rule", num_components=3).ok  # held back: the check cannot see it
    session = SandboxSession(source, "deferred.py", wall_seconds=5.0)
    try:
        message, _ = call_until_it_fails(session)
        assert stopped_for(reason, message) and message.startswith("deferred.py: rule") and "\n" not in message
    finally:
        session.close()


@pytest.mark.parametrize("label", sorted(UNRESTRICTED_HOSTILE))
def test_isolation_alone_holds_at_time_of_use(label, tmp_path):
    source, reason = UNRESTRICTED_HOSTILE[label]
    source = deferred(source)
    assert validate_source(source, "rule", num_components=3, restricted=False).ok
    session = SandboxSession(source, "deferred.py", wall_seconds=5.0, restricted=False)
    try:
        message, _ = call_until_it_fails(session)
        assert stopped_for(reason, message), message
    finally:
        session.close()
    import os

    assert not os.path.exists("/tmp/torchrl_ahrs_sandbox_probe")


NEW_ATTACKS = {  # time-of-use attacks not in the corpus above (unrestricted: the process alone must hold)
    "hang on a future": ("import torch\n" + HEAD + "    torch.Future([]).wait()\n", "wall time"),
    "native library": ("import ctypes\n" + HEAD + "    ctypes.CDLL('libc.so.6')\n", "ctypes.dlopen is refused"),
    "sleep": ("import time\n" + HEAD + "    time.sleep(60)\n", "wall time"),
    "grow memory over calls": (
        "kept = []\n" + HEAD + "    kept.append(bytearray(10 ** 8))\n    return mean_returns\n",
        "memory limit exceeded",
    ),
    "crash the worker": ("import os\n" + HEAD + "    os.abort()\n", "os.abort is refused"),
}


@pytest.mark.parametrize("label", sorted(NEW_ATTACKS))
def test_new_time_of_use_attacks_are_bounded(label):
    source, reason = NEW_ATTACKS[label]
    session = SandboxSession(deferred(source), "attack.py", wall_seconds=2.0, restricted=False)
    rule = isolated_functions(session, "rule")["rule"]
    try:
        for _ in range(CHECK_CALLS):
            rule(*RULE_ARGS)
        messages = []
        for _ in range(30):  # "grow memory" needs several calls to reach the cap
            started = time.perf_counter()
            try:
                rule(*RULE_ARGS)
            except SandboxCallError as error:
                messages.append(str(error))
                assert time.perf_counter() - started < 10  # no run hangs beyond its bound
                break
        assert messages and (reason in messages[0] or "worker died" in messages[0]), messages
        assert messages[0].startswith("attack.py: ")
    finally:
        session.close()


def test_the_worker_has_no_api_key(monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-session-key")
    source = "import os\n" + HEAD + "    return mean_returns * 0 + len(os.environ.get('OPENAI_API_KEY', ''))\n"
    session = SandboxSession(source, "env.py", restricted=False)
    try:
        assert isolated_functions(session, "rule")["rule"](*RULE_ARGS).tolist() == [0.0, 0.0, 0.0]
    finally:
        session.close()


REFUSED_REACH = {  # item 2: what reaches outside the sandbox is refused, one line with the reason
    "module returned by a call": ("torch.get_device_module('cuda').CUDAPluggableAllocator", "device_module"),
    "dispatch guard": ("torch.ExcludeDispatchKeyGuard(torch.DispatchKeySet(1))", "guard"),
    "dispatch key set": ("torch.DispatchKeySet", "dispatch"),
    "pybind future": ("torch.Future([])", "pybind11 class"),
    "KL registry": ("torch.distributions.register_kl", "register"),
    "numpy buffer size": ("np.setbufsize(8192)", "setbufsize"),
}


@pytest.mark.parametrize("label", sorted(REFUSED_REACH))
def test_calls_that_reach_outside_are_refused_with_a_reason(label):
    expression, reason = REFUSED_REACH[label]
    source = (
        "import numpy as np\nimport torch\nkept = []\n"
        + HEAD
        + f"    kept.append({expression})\n    return mean_returns\n"
    )
    verdict = check_source(source)
    assert not verdict.ok and any(reason in line.lower() for line in verdict.reasons), verdict.reasons
    assert all("\n" not in line for line in verdict.reasons)


def test_a_module_reached_through_a_call_gives_nothing():
    import types

    with pytest.raises(SandboxRefusal, match="outside the sandbox"):
        guarded_getattr(types.ModuleType("torch.cuda"), "CUDAPluggableAllocator")


NUMPY_STATISTICS = """
    import numpy as np
    import torch

    def compute_aux_reward(obs):
        x = obs["observation"].numpy()
        spread = np.percentile(x, 75, axis=1) - np.quantile(x, 0.25, axis=1)
        distinct = np.array([len(np.unique(row)) for row in x], dtype=np.float32)
        return torch.as_tensor(np.median(x, axis=1) + spread + 0.0 * distinct)
"""


def test_numpy_statistics_with_lazy_imports_are_accepted_and_agree_in_both():
    source = textwrap.dedent(NUMPY_STATISTICS).lstrip()
    inputs = {"observation": torch.randn(32, 9), "action": torch.randn(32, 4)}
    verdict = check(source, "aux", inputs=inputs)
    assert verdict.ok, verdict.reasons
    session = SandboxSession(source, "stats.py")
    try:
        isolated = isolated_functions(session, "aux")["compute_aux_reward"](inputs)
    finally:
        session.close()
    torch.testing.assert_close(isolated, load_functions(source)["compute_aux_reward"](inputs).float())


@pytest.mark.parametrize("label", sorted(ORDINARY_RULES))
def test_benign_rules_give_the_same_scores_in_the_worker(label):
    source = textwrap.dedent(ORDINARY_RULES[label]).lstrip()
    generator = torch.Generator().manual_seed(0)
    arguments = (
        torch.randn(TASK_K, generator=generator),
        torch.rand(TASK_K, generator=generator),
        torch.randn(5, TASK_K, generator=generator),
        torch.full((TASK_K,), 0.5),
    )
    in_process = load_functions(source)
    session = SandboxSession(source, "benign.py")
    try:
        for name, fn in isolated_functions(session, "rule").items():
            if len(fn.__signature__.parameters) == 4:
                expected = torch.as_tensor(in_process[name](*arguments), dtype=torch.float32).reshape(TASK_K)
                torch.testing.assert_close(fn(*arguments), expected)
    finally:
        session.close()


def test_benign_aux_rewards_give_the_same_rewards_in_the_worker():
    inputs = {
        "observation": torch.randn(16, 9),
        "action": torch.randn(16, 4),
        "reward.total": torch.randn(16),
        "info.success": torch.zeros(16),
    }
    for label, text in ORDINARY_AUX.items():
        source = textwrap.dedent(text).lstrip()
        session = SandboxSession(source, "benign.py")
        try:
            isolated = isolated_functions(session, "aux")["compute_aux_reward"](inputs)
        finally:
            session.close()
        expected = torch.as_tensor(load_functions(source)["compute_aux_reward"](inputs), dtype=torch.float32)
        torch.testing.assert_close(isolated, expected.reshape(16), msg=label)


def test_the_check_calls_at_the_training_batch_size():
    source = (
        "import torch\n\ndef compute_aux_reward(obs):\n    x = obs['observation']\n"
        "    return x[:8, 0] if x.shape[0] == 16 else x[:, 0]\n"
    )
    inputs = {"observation": torch.randn(32, 3)}
    assert check(source, "aux", inputs=inputs).ok  # never called at N = 16 ...
    verdict = validate_source(source, "aux", inputs=inputs, batch_size=16)
    assert not verdict.ok and "N=16" in verdict.reasons[0]  # ... now it is


def test_an_array_returning_aux_reward_is_accepted_by_the_check_and_trains(tmp_path):
    path = tmp_path / "array_aux.py"
    path.write_text("import numpy as np\n\ndef compute_aux_reward(obs):\n    return np.zeros(obs['action'].shape[0])\n")
    assert check(path.read_text(), "aux").ok
    latest = train(make_cfg(*FAST, "method=hdppo_a", f"aux.path={path}"), tmp_path / "run")
    assert latest and "reward/aux" in latest


def test_an_isolated_rule_that_fails_at_time_of_use_names_its_file(tmp_path):
    path = tmp_path / "rules.py"
    path.write_text(deferred(RUNTIME_HOSTILE["memory bomb (tensor)"][0]))
    repository = load_repository(path, validate=True, num_components=3)
    rule = repository[1]
    for _ in range(CHECK_CALLS):
        rule.scores(*RULE_ARGS)
    for _ in range(2):  # and again at the next decision: the worker is still there, still bounded
        with pytest.raises(SandboxCallError, match=f"{path}: rule: memory limit exceeded"):
            rule.scores(*RULE_ARGS)


def test_an_aux_reward_failing_at_time_of_use_stops_training_with_a_checkpoint(tmp_path):
    path = tmp_path / "late_aux.py"
    path.write_text(
        "import torch\ncalls = [0]\n\ndef compute_aux_reward(obs):\n    calls[0] = calls[0] + 1\n"
        "    if calls[0] > 40:\n        return obs['no such key']\n    return obs['reward.total'] * 0.0\n"
    )
    cfg = make_cfg(*FAST, "method=hdppo_a", f"aux.path={path}", "checkpoint.interval=1000")
    with pytest.raises(AuxiliaryRewardError, match=f"auxiliary reward {path}.*KeyError: 'no such key'"):
        train(cfg, tmp_path / "run")
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)
    assert state["actor"] is not None and state["optimizer"] is not None


def test_a_huge_finite_aux_reward_stops_the_update_naming_it(tmp_path):
    path = tmp_path / "huge_aux.py"
    path.write_text("import torch\n\ndef compute_aux_reward(obs):\n    return obs['reward.total'] * 0.0 + 1e30\n")
    with pytest.raises(FloatingPointError, match="non-finite .*'aux'"):
        train(make_cfg(*FAST, "method=hdppo_a", f"aux.path={path}"), tmp_path / "run")


def test_aux_reward_from_a_file_runs_in_the_worker_and_a_shipped_one_in_process(tmp_path):
    from torchrl_ahrs.rewards.auxiliary import shipped_aux_path
    from torchrl_ahrs.sandbox.session import IsolatedFunction

    copy = tmp_path / "point_reach.py"
    copy.write_text(shipped_aux_path("point_reach").read_text())
    isolated = load_aux_function(copy)
    assert isinstance(isolated, IsolatedFunction)
    assert not isinstance(load_aux_function(shipped_aux_path("point_reach")), IsolatedFunction)
    step = {"observation": torch.randn(4, 6), "action": torch.zeros(4, 2), "reward.total": torch.zeros(4)}
    shipped = load_aux_function(shipped_aux_path("point_reach"))
    torch.testing.assert_close(isolated(step), torch.as_tensor(shipped(step), dtype=torch.float32))
    assert isinstance(AuxiliaryReward.from_file(copy).fn, IsolatedFunction)
    isolated.session.close()
