"""tools/check_dependencies.py refuses known-compromised releases; requirements.lock is hashed and
agrees with pyproject.toml."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[2]
TOOL = ROOT / "tools" / "check_dependencies.py"
FAKE_HASH = "--hash=sha256:" + "0" * 64


def check(*args, env=None):
    return subprocess.run([sys.executable, str(TOOL), *map(str, args)], capture_output=True, text=True, env=env)


def write_lock(folder, *lines):
    path = folder / "requirements.lock"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    "line",
    [
        f"litellm==1.82.7 \\\n    {FAKE_HASH}",
        f"litellm==1.82.8 {FAKE_HASH}",
        f"LiteLLM[proxy]==1.82.7.0 ; python_version >= '3.10' {FAKE_HASH}",  # spelling, extras, marker
        "litellm>=1.80,<1.83",  # a range that admits a compromised release
        "litellm",
    ],
)
def test_a_lock_with_a_compromised_litellm_is_refused(tmp_path, line):
    lock = write_lock(tmp_path, "# locked", f"numpy==2.4.6 {FAKE_HASH}", line)
    done = check(lock)
    assert done.returncode == 1, done.stdout
    assert "litellm==1.82." in done.stderr and "known-compromised release" in done.stderr
    assert "requirements.lock:3" in done.stderr and "credential stealer" in done.stderr


def test_an_include_is_followed(tmp_path):
    (tmp_path / "extra.txt").write_text("litellm==1.82.8\n")
    done = check(write_lock(tmp_path, "-r extra.txt"))
    assert done.returncode == 1 and "extra.txt:1: litellm==1.82.8" in done.stderr


@pytest.mark.parametrize("line", ["litellm==1.102.4", "litellm==1.82.6", "litellm>=1.83,<2", "litellm-proxy==1.82.7"])
def test_safe_pins_pass(tmp_path, line):
    done = check(write_lock(tmp_path, line))
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("ok:")


def test_require_hashes_refuses_an_unhashed_line(tmp_path):
    done = check(write_lock(tmp_path, f"numpy==2.4.6 {FAKE_HASH}", "tqdm==4.67.1"), "--require-hashes")
    assert done.returncode == 1 and "requirements.lock:2: tqdm has no --hash" in done.stderr


def test_installed_compromised_distribution_is_refused(tmp_path):
    info = tmp_path / "site" / "litellm-1.82.8.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: litellm\nVersion: 1.82.8\n")
    environment = dict(os.environ, PYTHONPATH=str(tmp_path / "site"))
    done = check("--installed", env=environment)
    assert done.returncode == 1 and "installed: litellm==1.82.8" in done.stderr
    assert check("--installed").returncode == 0  # this test environment itself is clean


def test_a_malformed_deny_list_is_an_input_error(tmp_path):
    deny = tmp_path / "deny.txt"
    deny.write_text("litellm 1.82.7\n")
    done = check(write_lock(tmp_path, "litellm==1.0"), "--deny-list", deny)
    assert done.returncode == 2 and "deny.txt:1: expected 'name==version" in done.stderr


def locked_versions():
    versions = {}
    for line in (ROOT / "requirements.lock").read_text().splitlines():
        if line and not line[0].isspace() and not line.startswith("#") and "==" in line:
            name, version = line.split(" ")[0].split("==")
            versions[name] = version
    return versions


def test_the_repository_lock_is_clean_fully_hashed_and_matches_pyproject():
    done = check(ROOT / "requirements.lock", "--require-hashes")
    assert done.returncode == 0, done.stderr
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11 (the lock's Python)
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    locked = locked_versions()
    for text in project["dependencies"] + project["optional-dependencies"]["test"]:
        requirement = Requirement(text)
        name = requirement.name.lower().replace("_", "-")
        assert name in locked, f"{name} is in pyproject.toml but not in requirements.lock"
        assert requirement.specifier.contains(locked[name], prereleases=True), (name, locked[name])
