"""Exporting a trained policy: the TorchScript and ONNX files give the trained policy's actions on real
observations, in a fresh interpreter that cannot import torchrl_ahrs, torchrl or tensordict."""

import json
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch
from conftest import make_cfg
from tensordict import TensorDict
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_ahrs.app.evaluate.export import ExportError, actor_actions, export, reference_observations
from torchrl_ahrs.app.evaluate.policy import load_policy
from torchrl_ahrs.train import train
from torchrl_ahrs.training.deploy import DeterministicPolicy
from torchrl_ahrs.training.models import RunningNorm, build_actor

TINY_QUADCOPTER = [
    "task=quadcopter",
    "method=hdppo",
    "trainer.total_frames=2048",
    "trainer.num_envs=16",
    "trainer.frames_per_batch=1024",
    "trainer.mini_batch_size=512",
    "trainer.num_epochs=1",
    "trainer.progress_bar=false",
    "model.hidden_sizes=[32,32]",
]

# Run with `python -I` (no PYTHONPATH, no working directory on sys.path) and an import hook that refuses the
# packages a deployment target does not have, so a file that needed them fails here.
FRESH_PROCESS = textwrap.dedent(
    """
    import sys
    BLOCKED = ("torchrl_ahrs", "torchrl", "tensordict")

    class Refuse:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"{name} is not available in this process")

    sys.meta_path.insert(0, Refuse())
    import numpy as np
    import onnxruntime
    import torch

    directory = sys.argv[1]
    observations = np.load(f"{directory}/observations.npy")
    scripted = torch.jit.load(f"{directory}/policy.pt")
    np.save(f"{directory}/actions_torchscript.npy", scripted(torch.from_numpy(observations)).numpy())
    session = onnxruntime.InferenceSession(f"{directory}/policy.onnx", providers=["CPUExecutionProvider"])
    np.save(f"{directory}/actions_onnx.npy", session.run(["action"], {"observation": observations})[0])
    assert not [name for name in sys.modules if name.split(".")[0] in BLOCKED]
    """
)


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("quadcopter_run")
    train(make_cfg(*TINY_QUADCOPTER), run_dir)
    return run_dir


@pytest.mark.slow
def test_exported_files_act_like_the_trained_policy_without_the_package(trained_run):
    result = export(trained_run, check_envs=4, check_steps=5)
    assert set(result.files) == {"torchscript", "onnx"}
    assert result.directory == trained_run / "export"
    metadata = json.loads((result.directory / "policy.json").read_text())
    assert (metadata["task"], metadata["obs_dim"], metadata["act_dim"]) == ("quadcopter", 13, 4)

    policy = load_policy(trained_run)
    observations = reference_observations(policy, num_envs=8, steps=30, seed=7)  # not the export's own check
    expected = actor_actions(policy.actor, observations).numpy()
    assert expected.std(0).min() > 1e-4, "the check needs observations that move the actions"
    np.save(result.directory / "observations.npy", observations.numpy())
    done = subprocess.run(
        [sys.executable, "-I", "-c", FRESH_PROCESS, str(result.directory)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    for name in ("torchscript", "onnx"):
        actions = np.load(result.directory / f"actions_{name}.npy")
        assert actions.shape == (observations.shape[0], 4)
        np.testing.assert_allclose(actions, expected, rtol=0, atol=1e-5, err_msg=name)


@pytest.mark.slow
def test_a_bfloat16_run_exports_float32_files_and_says_how_far_they_are_from_its_arithmetic(trained_run, tmp_path):
    run = tmp_path / "bf16_run"
    shutil.copytree(trained_run, run, ignore=shutil.ignore_patterns("export"))
    config = run / "config.yaml"
    config.write_text(config.read_text().replace("precision: float32", "precision: bfloat16"))
    result = export(run, formats=["torchscript"], check_envs=4, check_steps=5)
    assert result.max_difference["torchscript"] <= 1e-5  # the file is the float32 reading of the weights
    metadata = json.loads((result.directory / "policy.json").read_text())
    assert (metadata["trained_precision"], metadata["exported_precision"]) == ("bfloat16", "float32")
    assert 0 < metadata["max_abs_difference_from_trained_precision"] < 0.05  # bfloat16's rounding, no more


@pytest.mark.parametrize("distribution", ["tanh_normal", "normal"])
def test_deterministic_policy_is_the_actors_mean_action_in_the_bounds(distribution):
    torch.manual_seed(0)
    norm = RunningNorm(3)
    norm.update(torch.randn(256, 3) * 3 + 1)  # normalisation that matters
    spec = Bounded(torch.tensor([-2.0, 0.0]), torch.tensor([1.0, 0.5]), (2,))  # asymmetric bounds
    actor = build_actor(norm, 3, spec, [16], distribution=distribution)
    for parameter in actor.parameters():
        parameter.data.normal_()  # large means: the squash and the clip are exercised
    observations = torch.randn(64, 3) * 4
    policy = DeterministicPolicy.from_actor(actor)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        mean_action = actor(TensorDict({"observation": observations}, [64]))["action"]
    actions = policy(observations)
    assert ((actions >= spec.space.low) & (actions <= spec.space.high)).all()
    torch.testing.assert_close(actions, actor_actions(actor, observations), rtol=0, atol=1e-6)
    if distribution == "normal":  # the rollout keeps the unclipped mean; the env (and the export) clip it
        assert not torch.equal(actions, mean_action)
    norm.update(torch.randn(256, 3) + 50)  # training goes on: the exported copy keeps its statistics
    torch.testing.assert_close(policy(observations), actions)


def test_export_refuses_an_unknown_format_before_loading_anything(tmp_path):
    with pytest.raises(ExportError, match="formats must be"):
        export(tmp_path, formats=["tflite"])


def test_export_command_says_in_one_line_what_is_missing(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.export", f"run={tmp_path}"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f"error: no config.yaml in {tmp_path}: not a training run directory"]
