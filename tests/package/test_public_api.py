"""The public names: importable from the package root, documented, and cheap to import."""

import inspect
import re
import subprocess
import sys

import pytest

import torchrl_ahrs


@pytest.mark.parametrize("name", [n for n in torchrl_ahrs.__all__ if n != "__version__"])
def test_every_public_name_imports_from_the_root_and_has_a_doctest(name):
    obj = getattr(torchrl_ahrs, name)
    assert name in dir(torchrl_ahrs)
    doc = inspect.getdoc(obj) or ""
    assert doc.strip(), f"{name} has no docstring"
    if inspect.isclass(obj) and name not in ("ConstantSelector",):
        assert ">>>" in doc, f"{name}'s docstring has no runnable example"


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        torchrl_ahrs.Nope  # noqa: B018


def test_importing_the_package_loads_neither_torch_nor_litellm():
    code = "import sys, torchrl_ahrs; print('torch' in sys.modules, 'litellm' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]


def documented_args(doc: str) -> set[str]:
    """Names listed in a Google-style ``Args:`` section (``a, b: text`` lists two)."""
    match = re.search(r"^Args:\n((?:    .*\n|\n)+)", doc + "\n", flags=re.M)
    if not match:
        return set()
    names = set()
    for line in match.group(1).splitlines():
        entry = re.match(r"^    (\*{0,2}[\w, *]+?)(?: \(.*\))?:", line)
        if entry and not line.startswith("     "):
            names |= {name.strip().lstrip("*") for name in entry.group(1).split(",")}
    return names


@pytest.mark.parametrize("name", [n for n in torchrl_ahrs.__all__ if n != "__version__"])
def test_documented_arguments_exist_in_the_signature(name):
    obj = getattr(torchrl_ahrs, name)
    documented = documented_args(inspect.getdoc(obj) or "")
    parameters = set(inspect.signature(obj).parameters)
    assert documented <= parameters, f"{name} documents {sorted(documented - parameters)} it does not take"
