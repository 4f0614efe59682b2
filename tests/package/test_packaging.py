"""The built wheel carries the Hydra configs: train runs from a fresh venv outside the checkout."""

import importlib
import site
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_wheel_runs_training_outside_the_checkout(tmp_path):
    wheel_dir = tmp_path / "wheel"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", str(wheel_dir), str(ROOT)],
        check=True,
        capture_output=True,
    )
    (wheel,) = wheel_dir.glob("torchrl_ahrs-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "torchrl_ahrs/conf/config.yaml" in names
    assert "torchrl_ahrs/py.typed" in names  # users' type checkers read the annotations
    (entry_points,) = [name for name in names if name.endswith(".dist-info/entry_points.txt")]
    assert "torchrl-ahrs-train = torchrl_ahrs.train:main" in zipfile.ZipFile(wheel).read(entry_points).decode()
    assert any(name.startswith("torchrl_ahrs/conf/task/") for name in names)
    # every subpackage and every robot model of the checkout is in the wheel
    for init in (ROOT / "torchrl_ahrs").rglob("__init__.py"):
        assert init.relative_to(ROOT).as_posix() in names, f"{init.parent.name} missing from pyproject's packages"
    for asset in (ROOT / "torchrl_ahrs").rglob("*.xml"):
        assert asset.relative_to(ROOT).as_posix() in names

    # a fresh venv that gets only the wheel; its dependencies come from this interpreter's site-packages
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=False)
    python = env_dir / "bin" / "python"
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(purelib)
    dependency_dirs = [path for path in site.getsitepackages() if "site-packages" in path]
    (Path(purelib) / "deps.pth").write_text("\n".join(dependency_dirs) + "\n")

    workdir = tmp_path / "elsewhere"
    workdir.mkdir()
    result = subprocess.run(
        [
            str(python),
            "-m",
            "torchrl_ahrs.train",
            "task=point_reach",
            "method=ppo",
            "trainer.total_frames=512",
            "trainer.num_envs=4",
            "trainer.frames_per_batch=256",
            "trainer.mini_batch_size=64",
            "trainer.progress_bar=false",
            f"hydra.run.dir={workdir / 'run'}",
        ],
        cwd=workdir,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    imported_from = subprocess.run(
        [str(python), "-c", "import torchrl_ahrs; print(torchrl_ahrs.__file__)"],
        cwd=workdir,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert str(ROOT) not in imported_from
    assert (workdir / "run" / "config.yaml").exists()
    assert (workdir / "run" / "checkpoint.pt").exists()


def test_console_scripts_point_at_the_python_m_entry_points():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    scripts = project["scripts"]
    commands = {path.stem for path in (ROOT / "torchrl_ahrs").glob("*.py") if path.stem != "__init__"} | {"sandbox"}
    assert {name.removeprefix("torchrl-ahrs-").replace("-", "_") for name in scripts} == commands
    for name, target in scripts.items():
        module_name, function = target.split(":")
        module = importlib.import_module(module_name)
        assert callable(getattr(module, function)), name
        python_m = module_name.removesuffix(".__main__")
        assert name == "torchrl-ahrs-" + python_m.removeprefix("torchrl_ahrs.").replace("_", "-")


def test_the_package_is_marked_typed_and_its_extras_exist():
    tomllib = pytest.importorskip("tomllib")
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert (ROOT / "torchrl_ahrs" / "py.typed").is_file()
    assert "py.typed" in pyproject["tool"]["setuptools"]["package-data"]["torchrl_ahrs"]
    assert "Typing :: Typed" in pyproject["project"]["classifiers"]
    extras = pyproject["project"]["optional-dependencies"]
    assert {"wandb", "mlflow", "video", "onnx", "optuna"} <= set(extras)
    assert any(text.startswith("gymnasium") for text in pyproject["project"]["dependencies"])
