"""Evaluating a trained run: the logged reward structure comes back, clips are real, bad runs fail clearly.

Rendering tests run the command line in a subprocess: ``MUJOCO_GL`` is read once, when ``mujoco`` is
first imported, and by then this pytest process has imported it (for the other test modules).
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import torch
from conftest import make_cfg
from PIL import Image

from torchrl_ahrs.app.evaluate.policy import EvaluationError, load_policy
from torchrl_ahrs.app.shared.config import save_config
from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.evaluate import evaluate
from torchrl_ahrs.train import train

TINY_RUN = [
    "task=point_reach",
    "method=hdppo",
    "trainer.total_frames=4096",
    "trainer.num_envs=32",
    "trainer.frames_per_batch=1024",
    "trainer.mini_batch_size=256",
    "trainer.num_epochs=2",
    "trainer.progress_bar=false",
    "model.hidden_sizes=[32,32]",
]
POINT_REACH_EPISODE_STEPS = 100  # conf/task/point_reach.yaml: max_episode_steps, and it never terminates early


def run_cli(*args, timeout=300):
    environment = {key: value for key, value in os.environ.items() if key not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    return subprocess.run(
        [sys.executable, "-m", "torchrl_ahrs.evaluate", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=environment,
    )


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("point_reach_run")
    train(make_cfg(*TINY_RUN), run_dir)
    return run_dir


@pytest.mark.slow
def test_evaluation_reproduces_the_logged_component_structure(trained_run):
    summary = evaluate(trained_run, episodes=4, seed=3)
    logged = {path.stem for path in (trained_run / "metrics" / "scalars" / "return").glob("*.csv")}
    assert set(summary["return"]) == logged == {"distance", "arrival", "ctrl", "total"}
    assert summary["episodes"] == 4
    per_episode = summary["per_episode"]["return"]
    components_sum = np.sum([per_episode[name] for name in ("distance", "arrival", "ctrl")], axis=0)
    np.testing.assert_allclose(components_sum, per_episode["total"], rtol=1e-4, atol=1e-3)
    assert summary["per_episode"]["length"] == [POINT_REACH_EPISODE_STEPS] * 4
    # per episode too: the distance return is -(steps x that episode's mean distance)
    np.testing.assert_allclose(
        per_episode["distance"],
        -POINT_REACH_EPISODE_STEPS * np.asarray(summary["per_episode"]["metrics"]["distance"]),
        rtol=1e-4,
        atol=1e-4,
    )
    # the distance component pays -d every step, so its return is -(steps x mean distance metric)
    np.testing.assert_allclose(
        summary["return"]["distance"]["mean"],
        -POINT_REACH_EPISODE_STEPS * summary["metrics"]["distance"]["mean"],
        rtol=1e-4,
    )
    assert json.loads((trained_run / "evaluation.json").read_text()) == json.loads(json.dumps(summary))


@pytest.mark.slow
def test_mean_action_is_reproducible_and_sampling_is_not_the_mean(trained_run):
    first = evaluate(trained_run, episodes=3, seed=5, output=None)
    again = evaluate(trained_run, episodes=3, seed=5, output=None)
    sampled = evaluate(trained_run, episodes=3, seed=5, deterministic=False, output=None)
    assert first["per_episode"] == again["per_episode"]
    assert sampled["per_episode"]["return"]["ctrl"] != first["per_episode"]["return"]["ctrl"]


@pytest.mark.slow
def test_task_overrides_change_the_evaluated_task_only(trained_run):
    config_before = (trained_run / "config.yaml").read_text()
    shortened = evaluate(trained_run, episodes=2, seed=5, output=None, task_overrides={"max_episode_steps": 40})
    assert shortened["per_episode"]["length"] == [40, 40]  # point_reach never ends early: the limit is the length
    assert shortened["task_overrides"] == {"max_episode_steps": 40}
    assert (trained_run / "config.yaml").read_text() == config_before  # the run keeps its own task
    as_trained = evaluate(trained_run, episodes=2, seed=5, output=None)
    assert as_trained["per_episode"]["length"] == [POINT_REACH_EPISODE_STEPS] * 2
    assert as_trained["task_overrides"] == {}
    with pytest.raises(EvaluationError, match=r"^task.max_steps is not a setting of task 'point_reach'$"):
        load_policy(trained_run, {"max_steps": 40})

    result = run_cli(f"run={trained_run}", "episodes=2", "output=", "+task.max_episode_steps=30")
    assert result.returncode == 0, result.stderr
    assert "length 30.0 ± 0.0" in result.stdout
    assert 'task changed for this evaluation: {"max_episode_steps": 30}' in result.stdout
    code, stderr = run_main(f"run={trained_run}", "output=", "+task.arrival_radus=0.2")
    assert code == 2 and stderr.strip() == "error: task.arrival_radus is not a setting of task 'point_reach'"


@pytest.mark.slow
def test_rendered_clip_has_the_requested_frames_and_is_not_blank(trained_run):
    frames, fps = 12, 50  # point_reach control dt is 0.02 s: real-time playback at 50 frames/s
    result = run_cli(
        f"run={trained_run}", "episodes=2", "video=true", f"video_frames={frames}", "video_width=64", "video_height=48",
        "video_format=gif",
    )  # fmt: skip
    if result.returncode == 3 and "no video" in result.stderr:
        pytest.skip(f"no offscreen GL backend on this machine: {result.stderr.strip()}")
    assert result.returncode == 0, result.stderr
    assert "return total" in result.stdout
    clip = Image.open(trained_run / "videos" / "point_reach.gif")
    assert clip.size == (64, 48)
    delays, images = [], []
    for index in range(clip.n_frames):
        clip.seek(index)
        delays.append(clip.info["duration"])
        images.append(np.asarray(clip.convert("RGB"), dtype=np.float64))
    # GIF merges identical consecutive frames into one longer frame, so count frames by playback time
    assert sum(delays) == frames * round(1000 / fps)
    assert all(image.std() > 5.0 for image in images), [round(image.std(), 2) for image in images]


@pytest.mark.slow
def test_default_clip_is_a_640x480_mp4_that_follows_the_robot(trained_run):
    pytest.importorskip("imageio_ffmpeg", reason="the video extra is not installed")
    import imageio.v2 as imageio

    result = run_cli(f"run={trained_run}", "episodes=1", "output=null", "video=true", "video_frames=8")
    if result.returncode == 3 and "no video" in result.stderr:
        pytest.skip(f"no offscreen GL backend on this machine: {result.stderr.strip()}")
    assert result.returncode == 0, result.stderr
    assert "camera tracking body 1" in result.stdout
    frames = np.stack(imageio.mimread(str(trained_run / "videos" / "point_reach.mp4"), format="FFMPEG"))
    assert frames.shape == (8, 480, 640, 3)
    assert frames[:, :80].mean() > 60  # a sky above the horizon, not MuJoCo's black background


@pytest.mark.slow
def test_training_video_hook_writes_gif_and_tensorboard_video(trained_run):
    script = (
        "from torchrl_ahrs.evaluation.render import select_gl_backend; select_gl_backend()\n"
        "import sys\n"
        "from torchrl_ahrs.app.evaluate.policy import load_policy\n"
        "from torchrl_ahrs.app.train.video import VideoLog\n"
        "from tensorboard.backend.event_processing.event_accumulator import EventAccumulator\n"
        f"policy = load_policy({str(trained_run)!r})\n"
        f"hook = VideoLog(policy.make_envs, policy.actor, {str(trained_run)!r}, interval=2, "
        "num_frames=6, width=48, height=32)\n"
        "for _ in range(4): hook()\n"
        "print(sorted(path.name for path in hook.logger.written))\n"
        f"accumulator = EventAccumulator({str(trained_run / 'metrics')!r}); accumulator.Reload()\n"
        "print([event.step for event in accumulator.Images('policy')])\n"
    )
    environment = {key: value for key, value in os.environ.items() if key not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300, env=environment
    )
    if "RenderUnavailable" in result.stderr:
        pytest.skip(f"no offscreen GL backend on this machine: {result.stderr.strip().splitlines()[-1]}")
    assert result.returncode == 0, result.stderr
    written, steps = result.stdout.strip().splitlines()[-2:]
    assert written == "['policy_2.gif', 'policy_4.gif']"  # iterations 2 and 4 of interval 2
    assert steps == "[2, 4]"


def run_main(*args):
    """The command line in a subprocess: Hydra's logging set-up in the test process would write to
    streams that earlier tests' output capture has closed."""
    result = run_cli(*args)
    return result.returncode, result.stderr


def test_missing_checkpoint_is_one_clear_error_line(tmp_path):
    run = RunDirectory(tmp_path)
    save_config(make_cfg(*TINY_RUN), run.config)
    code, stderr = run_main(f"run={tmp_path}")
    assert code == 2
    assert stderr.strip() == (
        f"error: no checkpoint at {run.checkpoint}: the run has not reached its first checkpoint "
        "(every checkpoint.interval iterations, and at the end)"
    )


def test_missing_run_argument_and_directory_fail_clearly(tmp_path):
    with pytest.raises(EvaluationError, match="no run directory at"):
        load_policy(tmp_path / "absent")
    code, stderr = run_main()
    assert code == 2 and stderr.strip() == (
        "error: give the training run directory: python -m torchrl_ahrs.evaluate run=<run dir>"
    )


def test_incompatible_checkpoint_names_both_files(tmp_path):
    save_config(make_cfg(*TINY_RUN), tmp_path / "config.yaml")
    torch.save({"actor": {"module.0.weight": torch.zeros(3, 3)}}, tmp_path / "checkpoint.pt")
    with pytest.raises(EvaluationError, match="does not fit the actor described by .*config.yaml"):
        load_policy(tmp_path)
    (tmp_path / "checkpoint.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(EvaluationError, match="cannot read checkpoint"):
        load_policy(tmp_path)


def test_envs_without_a_renderer_say_so():
    from torchrl_ahrs.evaluation.render import RenderUnavailable, make_frame_source

    class NotMujoco:
        pass

    with pytest.raises(RenderUnavailable, match="NotMujoco has no renderer"):
        make_frame_source(NotMujoco(), 8, 8)


@pytest.mark.slow
def test_trainer_task_overrides_change_the_training_environments_and_evaluate_scores_the_task(tmp_path):
    # 4 batches of 32 steps per environment: 128 steps, so 40-step episodes end 3 times per environment, 100-step once
    train(make_cfg(*TINY_RUN, "+trainer.task_overrides.max_episode_steps=40"), tmp_path)
    episodes = np.loadtxt(tmp_path / "metrics" / "scalars" / "episodes.csv", delimiter=",", skiprows=1, ndmin=2)
    assert episodes[:, 1].sum() == 32 * (128 // 40)
    saved = (tmp_path / "config.yaml").read_text()
    assert f"max_episode_steps: {POINT_REACH_EPISODE_STEPS}" in saved  # `task` as defined, the change apart
    summary = evaluate(tmp_path, episodes=2, seed=5, output=None)
    assert summary["per_episode"]["length"] == [POINT_REACH_EPISODE_STEPS] * 2
    assert summary["trained_with_task_overrides"] == {"max_episode_steps": 40}
    with pytest.raises(ConfigError, match=r"^task.max_steps is not a setting of task 'point_reach'$"):
        train(make_cfg(*TINY_RUN, "+trainer.task_overrides.max_steps=40"), tmp_path / "refused")
    assert not (tmp_path / "refused").exists()  # refused before anything is written
