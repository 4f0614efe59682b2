"""The API reference builds from the docstrings with warnings as errors (a broken docstring fails CI)."""

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("sphinx")
DOCS = Path(__file__).resolve().parents[2] / "docs" / "api"


def test_api_reference_builds_without_warnings(tmp_path):
    command = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", str(DOCS), str(tmp_path)]
    result = subprocess.run(command, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-3000:]
    page = (tmp_path / "index.html").read_text()
    assert "WeightedMultiGAE" in page and "Writes the K component advantages" in page  # forward's own docstring
