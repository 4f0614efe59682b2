"""Issue 25's measure: the package files a reader of one iteration of ``learn()`` opens (``tools/iteration_files.py``,
direct from learn()'s frame, besides the task's environment: ``envs/`` and what only its step runs) stay few."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parents[2] / "tools"))
from iteration_files import split, trace_cassie_ahrs  # noqa: E402

GOAL = 8  # issue 25: "the files it touches are <= 8 besides the task's environment"; 8 since session 13


@pytest.fixture(scope="module")
def direct():
    files = trace_cassie_ahrs()  # one tiny cassie ahrs run: its second iteration traced
    _, rest = split(files.direct, files)
    return rest


def test_the_iteration_touches_at_most_eight_files_besides_the_environment(direct):
    assert len(direct) <= GOAL, f"{len(direct)} package files besides the environment from learn(): {direct}"


def test_only_what_the_env_step_reaches_counts_as_the_environment(direct):
    # learn() calls finished_episode_returns itself: a reader opens rewards/components.py, so it counts; the
    # auxiliary reward runs only inside the env's step (a transform of the task's TransformedEnv)
    assert "rewards/components.py" in direct and "training/loop.py" in direct
    assert "rewards/auxiliary.py" not in direct
