"""What a run logs besides its scalars: CSV headers (old header-less files still read), TensorBoard's
hyperparameters, the config as text and the learning rate."""

from pathlib import Path

import numpy as np
import pytest
from conftest import make_cfg
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.app.train.checkpoint import truncate_metrics
from torchrl_ahrs.app.train.runs import read_scalar
from torchrl_ahrs.train import train
from torchrl_ahrs.training.loggers import CSV_HEADER

ROOT = Path(__file__).resolve().parents[2]
FRAMES, ITERATIONS = 512, 3
TINY_RUN = [
    "task=point_reach",
    "method=hdppo",
    f"trainer.total_frames={FRAMES * ITERATIONS}",
    "trainer.num_envs=8",
    f"trainer.frames_per_batch={FRAMES}",
    "trainer.mini_batch_size=256",
    "trainer.num_epochs=1",
    "trainer.lr=0.001",
    "trainer.progress_bar=false",
    "model.hidden_sizes=[16]",
    "logger.backends=[csv,tensorboard]",
]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    directory = tmp_path_factory.mktemp("logged_run")
    train(make_cfg(*TINY_RUN), directory)
    return RunDirectory(directory)


@pytest.mark.slow
def test_every_metric_csv_has_a_header_and_reads_back(run):
    files = sorted(run.scalars.rglob("*.csv"))
    assert len(files) > 10
    for path in files:
        assert path.read_text().splitlines()[0] == CSV_HEADER, path
    steps, values = read_scalar(run.scalar("train/learning_rate"))
    assert steps.tolist() == [FRAMES * (i + 1) for i in range(ITERATIONS)]
    # trainer.anneal_lr (on by default): lr_i = lr_0 (1 - frames_{i-1} / total); the logged rate is the one used
    np.testing.assert_allclose(values, [1e-3 * (1 - i / ITERATIONS) for i in range(ITERATIONS)], rtol=1e-6)


@pytest.mark.slow
def test_truncating_keeps_the_header(run, tmp_path):
    copy = tmp_path / "total.csv"
    copy.write_text(run.scalar("reward/total").read_text())  # one row per iteration
    dropped = truncate_metrics(tmp_path, FRAMES)
    assert dropped == ITERATIONS - 1
    assert copy.read_text().splitlines()[0] == CSV_HEADER
    assert read_scalar(copy)[0].tolist() == [FRAMES]


def test_header_less_files_of_earlier_runs_still_read():
    committed = ROOT / "benchmarks/results/faithful/runs/ant/hdppo/seed_3/metrics/scalars/return/total.csv"
    assert not committed.read_text().startswith("step")  # written before the header
    steps, values = read_scalar(committed)
    assert len(steps) > 10 and steps[0] > 0 and np.isfinite(values).all()


@pytest.mark.slow
def test_tensorboard_gets_hparams_config_text_and_learning_rate(run):
    events = EventAccumulator(str(run.metrics), size_guidance={"tensors": 0, "scalars": 0}).Reload()
    assert "train/learning_rate" in events.Tags()["scalars"]
    assert len(events.Scalars("train/learning_rate")) == ITERATIONS
    text = events.Tensors("config/text_summary")[0].tensor_proto.string_val[0].decode()
    assert "point_reach" in text and "hidden_sizes" in text
    hparams = events.PluginTagToContent("hparams")
    assert {"_hparams_/experiment", "_hparams_/session_start_info"} <= set(hparams)
    from tensorboard.plugins.hparams import plugin_data_pb2

    start = plugin_data_pb2.HParamsPluginData.FromString(hparams["_hparams_/session_start_info"]).session_start_info
    assert start.hparams["trainer.lr"].number_value == pytest.approx(1e-3)
    assert start.hparams["task.name"].string_value == "point_reach"
