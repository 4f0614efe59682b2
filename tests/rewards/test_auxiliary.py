"""Auxiliary reward: the transform, the shipped rewards on real batches, refusal of broken or hostile code,
the three methods that use it, and the sandbox's command line on aux files. The generator is tested in
``tests/app/test_generate_aux.py``."""

import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import FAST, make_cfg
from omegaconf import OmegaConf
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from torchrl_ahrs.app.shared.auxiliary import collect_aux_inputs, validate_aux_file
from torchrl_ahrs.app.shared.config import resolve_components, validate_config
from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.settings import load_task_config, task_settings
from torchrl_ahrs.app.train.runs import read_scalar as read_scalar_file
from torchrl_ahrs.envs.registry import available_tasks, make_env
from torchrl_ahrs.rewards.auxiliary import (
    AUX,
    TOTAL_AUX,
    AuxiliaryReward,
    AuxiliaryRewardError,
    aux_inputs,
    file_digest,
    load_aux_function,
    shipped_aux_path,
)
from torchrl_ahrs.sandbox import check_source
from torchrl_ahrs.sandbox import validate as validate_in_process
from torchrl_ahrs.train import train


def task_dict(name, **extra):
    return {**OmegaConf.to_container(load_task_config(name), resolve=True), **extra}


def read_scalar(run_dir, name):
    return read_scalar_file(run_dir / "metrics" / "scalars" / f"{name}.csv")[1].tolist()


# ---------------------------------------------------------------------------------------------------
# shipped auxiliary rewards
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("task", available_tasks())
def test_shipped_aux_reward_runs_on_a_real_batch(task):
    path = shipped_aux_path(task)
    verdict = check_source(path.read_text(), str(path))
    assert verdict.ok, verdict.reasons
    inputs = collect_aux_inputs(task_dict(task), num_envs=3, steps=4)  # 12 real transitions
    aux = load_aux_function(path)(inputs)
    assert aux.shape == (12,) and aux.dtype == torch.float32
    assert torch.isfinite(aux).all()
    assert aux.abs().max() <= 5.0, "an auxiliary reward should stay on the scale of the task's terms"
    assert path.read_text().split('"""')[1].strip(), "each shipped reward documents its intent"


def _point_reach_obs(velocity, to_target):
    observation = torch.tensor([[0.0, 0.0, *velocity, *to_target]])
    return {"observation": observation, "action": torch.zeros(1, 2)}


def test_point_reach_aux_pays_for_moving_towards_the_target():
    fn = load_aux_function(shipped_aux_path("point_reach"))
    towards = fn(_point_reach_obs([0.5, 0.0], [1.0, 0.0])).item()
    away = fn(_point_reach_obs([-0.5, 0.0], [1.0, 0.0])).item()
    sideways = fn(_point_reach_obs([0.0, 0.5], [1.0, 0.0])).item()
    on_target = fn(_point_reach_obs([0.5, 0.0], [0.0, 0.0])).item()
    assert towards > 0 > away and sideways == pytest.approx(0.0, abs=1e-6)
    assert on_target == pytest.approx(0.0, abs=1e-6)  # no push through the target


PILOT_AUX = Path(__file__).parents[2] / "benchmarks" / "pilots" / "aux"
CASSIE_PROGRESS_AUX = [shipped_aux_path("cassie"), PILOT_AUX / "cassie_progress_upright.py"]


def test_cassie_pilot_aux_pays_for_an_upright_pelvis():
    """The term Cassie shipped until round 37 (benchmarks/RESULTS.md), kept as a pilot: dt x (1 - sin^2 tilt)."""
    fn = load_aux_function(PILOT_AUX / "cassie_upright.py")
    observation = torch.zeros(2, 42)
    observation[0, 6:9] = torch.tensor([0.0, 0.0, -1.0])  # upright: gravity along -z
    observation[1, 6:9] = torch.tensor([1.0, 0.0, 0.0])  # lying on its side
    aux = fn({"observation": observation})
    torch.testing.assert_close(aux, torch.tensor([0.02, 0.0]))  # at most one dt-scaled unit


@pytest.mark.parametrize("path", CASSIE_PROGRESS_AUX, ids=[path.stem for path in CASSIE_PROGRESS_AUX])
def test_cassie_aux_pays_for_progress_along_the_command(path):
    """Oracle: command 1 m/s along x (observed x 2); the progress term pays dt x the share of the commanded speed
    achieved along it, clamped to [0, 1]: 0.02 at 1 m/s, 0.01 at 0.5 m/s, 0.02 at 1.5 m/s, 0 backwards or sideways,
    0 without a planar command. The upright variant pays the same upright and nothing lying on its side."""
    assert check_source(path.read_text(), str(path)).ok
    fn = load_aux_function(path)
    velocities = [[1.0, 0.0], [0.5, 0.0], [1.5, 0.0], [-0.5, 0.0], [0.0, 0.5], [0.5, 0.0]]
    commands = [[1.0, 0.0]] * 5 + [[0.0, 0.0]]
    observation = torch.zeros(len(velocities), 42)
    observation[:, 0:2] = 2.0 * torch.tensor(velocities)  # the observation scale of the base velocity
    observation[:, 6:9] = torch.tensor([0.0, 0.0, -1.0])  # upright
    observation[:, 9:11] = 2.0 * torch.tensor(commands)  # the observation scale of the planar command
    expected = torch.tensor([0.02, 0.01, 0.02, 0.0, 0.0, 0.0])
    torch.testing.assert_close(fn({"observation": observation}), expected)
    inputs = collect_aux_inputs(task_dict("cassie"), num_envs=3, steps=4)  # 12 real transitions
    aux = fn(inputs)
    assert aux.shape == (12,) and torch.isfinite(aux).all() and (aux >= 0).all() and (aux <= 0.02 + 1e-6).all()
    if "upright" in path.stem:
        observation[:, 6:9] = torch.tensor([1.0, 0.0, 0.0])  # lying on its side
        torch.testing.assert_close(fn({"observation": observation}), torch.zeros(len(velocities)))


# ---------------------------------------------------------------------------------------------------
# the transform
# ---------------------------------------------------------------------------------------------------


def test_transform_writes_aux_and_total_aux_next_to_the_native_reward():
    path = shipped_aux_path("point_reach")
    env = make_env(
        task_settings(task_dict("point_reach")),
        num_envs=4,
        seed=0,
        components=["distance", "arrival", "ctrl", AUX],
        transforms=[lambda: AuxiliaryReward.from_file(path, scale=2.0, expected_digest=file_digest(path))],
    )
    check_env_specs(env)
    # the component leaves are declared next to the total, which stays the env's only reward
    assert env.reward_key == ("reward", "total")
    assert {AUX, TOTAL_AUX} <= set(env.full_observation_spec["reward"].keys())
    rollout = env.rollout(5, break_when_any_done=False)
    reward = rollout["next", "reward"]
    assert reward[AUX].shape == (4, 5, 1) and reward[AUX].dtype == torch.float32
    torch.testing.assert_close(reward[TOTAL_AUX], reward["total"] + reward[AUX])
    # differential: the transform's value equals the file's function called on the same step, times the scale
    fn = load_aux_function(path)
    step = rollout[:, 2]
    direct = fn({key: value for key, value in aux_inputs(step["action"], step["next"]).items() if key != "reward.aux"})
    torch.testing.assert_close(reward[AUX][:, 2, 0], 2.0 * direct)
    # the episode return of the aux component is tracked like every other component's
    torch.testing.assert_close(rollout["next", "episode_reward", AUX][:, 0], reward[AUX][:, 0])


def test_transform_stops_on_wrong_shape_or_nan():
    step = TensorDict({"observation": torch.zeros(3, 2), "reward": {"total": torch.zeros(3, 1)}}, [3])
    action = TensorDict({"action": torch.zeros(3, 1)}, [3])
    with pytest.raises(AuxiliaryRewardError, match="shape"):
        AuxiliaryReward(lambda obs: obs["observation"])._step(action, step.clone())
    with pytest.raises(AuxiliaryRewardError, match="not finite"):
        AuxiliaryReward(lambda obs: obs["reward.total"] / 0.0)._step(action, step.clone())


def test_a_file_changed_after_validation_is_not_loaded(tmp_path):
    path = tmp_path / "aux.py"
    path.write_text(shipped_aux_path("point_reach").read_text())
    digest = file_digest(path)
    path.write_text(path.read_text() + "\nEXTRA = 1\n")
    with pytest.raises(ValueError, match="changed after it was validated"):
        AuxiliaryReward.from_file(path, expected_digest=digest)


# ---------------------------------------------------------------------------------------------------
# broken and hostile code
# ---------------------------------------------------------------------------------------------------

HEAD = "import torch\n\ndef compute_aux_reward(obs):\n"
STATICALLY_REFUSED = {
    "import os": "import os\n" + HEAD + "    os.system('true')\n    return obs['reward.total']\n",
    "from subprocess": "from subprocess import run\n" + HEAD + "    return obs['reward.total']\n",
    "open a file": HEAD + "    open('/etc/passwd').read()\n    return obs['reward.total']\n",
    "write a file": HEAD + "    torch.save(obs, '/tmp/stolen.pt')\n    return obs['reward.total']\n",
    "socket via __import__": HEAD + "    s = __import__('socket')\n    return obs['reward.total']\n",
    "dunder class walk": HEAD + "    k = ().__class__.__bases__[0].__subclasses__()\n    return obs['reward.total']\n",
    "dunder globals": HEAD + "    g = compute_aux_reward.__globals__\n    return obs['reward.total']\n",
    "getattr string": HEAD + "    f = getattr(torch, 'lo' + 'ad')\n    return obs['reward.total']\n",
    "eval": HEAD + "    return eval(\"obs['reward.total']\")\n",
    "exec": HEAD + "    exec('x = 1')\n    return obs['reward.total']\n",
    "while loop": HEAD + "    while True:\n        pass\n    return obs['reward.total']\n",
    "unbounded range": HEAD + "    for i in range(10**12):\n        pass\n    return obs['reward.total']\n",
    "lambda": HEAD + "    f = lambda x: x\n    return f(obs['reward.total'])\n",
    "class": "class Evil:\n    pass\n" + HEAD + "    return obs['reward.total']\n",
    "try/except": HEAD
    + "    try:\n        x = 1\n    except Exception:\n        x = 2\n    return obs['reward.total']\n",
    "torch.hub": HEAD + "    m = torch.hub.load('x', 'y')\n    return obs['reward.total']\n",
    "network via torch.utils": HEAD
    + "    torch.utils.model_zoo.load_url('http://x')\n    return obs['reward.total']\n",
    "huge power": HEAD + "    x = 10 ** 100000000\n    return obs['reward.total']\n",
    "no function": "import torch\nAUX = 1\n",
    "wrong function name": "import torch\n\ndef reward(obs):\n    return obs['reward.total']\n",
    "syntax error": HEAD + "    return obs[\n",
}


@pytest.mark.parametrize("label", sorted(STATICALLY_REFUSED))
def test_hostile_or_broken_code_is_refused_with_a_reason(label, tmp_path):
    path = tmp_path / "aux.py"
    path.write_text(STATICALLY_REFUSED[label])
    verdict = validate_aux_file(path, task_dict("point_reach"))
    assert not verdict.ok and verdict.reasons and all(reason.strip() for reason in verdict.reasons), label


RUNTIME_REFUSED = {
    "wrong shape": (HEAD + "    return obs['observation']\n", "output shape"),
    "scalar": (HEAD + "    return obs['observation'].sum()\n", "output shape"),
    "NaN": (HEAD + "    return obs['reward.total'] * float('nan')\n", "not finite"),
    "division by zero on the all-zero batch": (
        HEAD + "    return obs['reward.total'] / obs['reward.total']\n",
        "not finite",
    ),
    "missing key": (HEAD + "    return obs['pelvis_height']\n", "KeyError"),
    "index out of range": (HEAD + "    return obs['observation'][:, 100]\n", "raised IndexError"),
}


@pytest.mark.parametrize("label", sorted(RUNTIME_REFUSED))
def test_code_that_fails_on_real_transitions_is_refused(label):
    source, reason = RUNTIME_REFUSED[label]
    inputs = collect_aux_inputs(task_dict("point_reach"), num_envs=4, steps=4)
    report = validate_in_process(source, "aux", inputs)
    assert not report["ok"] and reason in " ".join(report["reasons"]), report


def test_huge_allocation_is_stopped_by_the_memory_limit_in_the_child(tmp_path):
    path = tmp_path / "aux.py"
    path.write_text(
        HEAD
        + "    a = obs['reward.total'].reshape(-1, 1) * obs['reward.total'].reshape(1, -1)\n"
        + "    b = a.reshape(-1, 1) * a.reshape(1, -1)\n"
        + "    c = b.reshape(-1, 1) * b.reshape(1, -1)\n"  # 4 * 16^8 bytes = 17 GB for 16 rows
        + "    return c.sum() + obs['reward.total']\n"
    )
    verdict = validate_aux_file(path, task_dict("point_reach"), num_envs=4, steps=4)
    assert not verdict.ok and ("memory" in " ".join(verdict.reasons) or "allocate" in " ".join(verdict.reasons))


@pytest.mark.slow
def test_endless_loop_is_stopped_by_the_cpu_limit_in_the_child(tmp_path):
    path = tmp_path / "aux.py"
    path.write_text(
        HEAD
        + "    x = obs['reward.total']\n    m = torch.rand(300, 300)\n    for i in range(100000):\n"
        + "        m = torch.tanh(m @ m)\n    return x + m.sum()\n"  # heavy steps: the CPU limit, not the loop budget
    )
    verdict = validate_aux_file(path, task_dict("point_reach"), num_envs=2, steps=2)
    assert not verdict.ok and "CPU-time limit" in " ".join(verdict.reasons)


def test_training_never_starts_with_refused_code(tmp_path):
    hostile = tmp_path / "hostile.py"
    hostile.write_text(STATICALLY_REFUSED["import os"])
    cfg = make_cfg(*FAST, "method=ahrs", f"aux.path={hostile}")
    with pytest.raises(ConfigError, match="refused by the sandbox"):
        train(cfg, tmp_path / "run")
    assert not (tmp_path / "run" / "metrics").exists() and not (tmp_path / "run" / "checkpoint.pt").exists()
    with pytest.raises(ConfigError, match="no file"):
        train(make_cfg(*FAST, "method=ahrs", f"aux.path={tmp_path / 'missing.py'}"), tmp_path / "run2")


@pytest.mark.slow
def test_cli_exits_with_status_2_and_the_reason(tmp_path):
    hostile = tmp_path / "hostile.py"
    hostile.write_text(STATICALLY_REFUSED["dunder class walk"])
    finished = subprocess.run(
        [
            sys.executable,
            "-m",
            "torchrl_ahrs.train",
            *FAST,
            "method=hdppo_a",
            f"aux.path={hostile}",
            f"hydra.run.dir={tmp_path / 'run'}",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert finished.returncode == 2, finished.stderr[-2000:]
    assert "refused by the sandbox" in finished.stderr and "__class__" in finished.stderr
    assert not (tmp_path / "run" / "metrics").exists()


# ---------------------------------------------------------------------------------------------------
# methods
# ---------------------------------------------------------------------------------------------------


def test_methods_resolve_their_components():
    assert resolve_components(make_cfg("task=point_reach", "method=ahrs")) == ["distance", "arrival", "ctrl", AUX]
    assert resolve_components(make_cfg("task=point_reach", "method=hdppo_a")) == ["distance", "arrival", "ctrl", AUX]
    assert resolve_components(make_cfg("task=point_reach", "method=ppo_a")) == [TOTAL_AUX]
    with pytest.raises(ConfigError, match="aux"):  # only methods with the auxiliary reward may name its leaves
        validate_config(make_cfg("task=point_reach", "method=hdppo", "method.components=[distance,aux]"))


@pytest.mark.parametrize("method", ["ahrs", "hdppo_a", pytest.param("ppo_a", marks=pytest.mark.slow)])
def test_method_trains_on_point_reach(method, tmp_path):
    metrics = train(make_cfg(*FAST, f"method={method}"), tmp_path)
    assert "return/total" in metrics  # the native return, comparable across methods
    if method == "ppo_a":
        assert metrics["weight/total_aux"] == 1.0 and "return/total_aux" in metrics
        assert "weight/aux" not in metrics
    else:
        assert "return/aux" in metrics and "weight/aux" in metrics
        assert len([key for key in metrics if key.startswith("weight/")]) == 4  # K + 1


@pytest.mark.slow
def test_cassie_cli_logs_k_plus_one_returns_and_weights(tmp_path):
    run_dir = tmp_path / "run"
    finished = subprocess.run(
        [
            sys.executable,
            "-m",
            "torchrl_ahrs.train",
            "task=cassie",
            "method=ahrs",
            "trainer.total_frames=4096",
            "trainer.num_envs=16",
            "trainer.frames_per_batch=1024",
            "trainer.mini_batch_size=256",
            "trainer.progress_bar=false",
            "scheduler.interval=1",
            "task.episode_length_s=0.5",
            f"hydra.run.dir={run_dir}",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert finished.returncode == 0, finished.stderr[-3000:]
    log = finished.stdout + finished.stderr  # Hydra's console log handler writes to stdout
    assert "auxiliary reward:" in log and "aux_rewards/cassie.py" in log and "sha256" in log
    assert "selector=bandit" in log
    components = list(load_task_config("cassie").components) + [AUX]
    for name in components:
        assert read_scalar(run_dir, f"weight/{name}"), name
        assert read_scalar(run_dir, f"return/{name}"), name


# ---------------------------------------------------------------------------------------------------
# sandbox command line
# ---------------------------------------------------------------------------------------------------


def test_sandbox_cli_refuses_hostile_aux_code(tmp_path):
    hostile = tmp_path / "aux.py"
    hostile.write_text(HEAD + "    f = obs['observation'].storage\n    return type(f)(obs['reward.total'])\n")
    finished = subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.sandbox", "check", str(hostile), "--kind", "aux", "--task", "point_reach"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert finished.returncode == 1 and "refused" in finished.stdout and "'type'" in finished.stdout, finished.stdout


@pytest.mark.slow
def test_sandbox_cli_accepts_a_shipped_aux_reward_on_its_task():
    finished = subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.sandbox", "check", str(shipped_aux_path("quadcopter")), "--kind", "aux"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert finished.returncode == 0 and "accepted" in finished.stdout, finished.stdout + finished.stderr
