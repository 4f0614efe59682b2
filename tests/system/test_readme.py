"""The README's composition example runs as written."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"


def test_readme_python_example_runs(capsys):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "README has no python example"
    for block in blocks:
        exec(compile(block, str(README), "exec"), {})
    printed = capsys.readouterr().out
    assert "torch.Size([8, 32, 3]) torch.Size([8, 32, 1])" in printed


def test_readme_starts_with_the_two_commands_ci_runs():
    text = README.read_text()
    commands = re.findall(r"```bash\n(.*?)\n```", text, flags=re.S)[:2]
    assert "python -m torchrl_ahrs.train" in commands[0]
    ci = (README.parent / ".ci" / "run").read_text()
    assert commands[1] in ci
