"""What the generator commands (``generate_rules``, ``generate_aux``) share: the check that they have an LLM,
the code blocks of an answer, and where they write what the LLM produced (``torchrl_ahrs.app.shared.settings`` reads
these settings from the composed config)."""

from __future__ import annotations

import datetime
import re
from pathlib import Path

from torchrl_ahrs.llm.client import LLMConfig, credential_problem

_CODE_BLOCK = re.compile(r"```[ \t]*(?:python|py)?[ \t]*\n(.*?)```", re.DOTALL)


class GenerationError(RuntimeError):
    """A generator command that cannot ask its LLM; the message says why."""


def require_llm(llm: LLMConfig, command: str) -> LLMConfig:
    """``llm`` itself; refuses an LLM without a model or replay log (``llm=offline``), naming ``command`` and
    how to give one, and a provider whose key is not set (:func:`~torchrl_ahrs.llm.client.credential_problem`).

    Example:
        >>> require_llm(LLMConfig(model="openai/gpt-4o", api_base="http://127.0.0.1:8000/v1"), "generate_rules").model
        'openai/gpt-4o'
        >>> require_llm(LLMConfig(), "generate_rules")
        Traceback (most recent call last):
        ...
        torchrl_ahrs.llm.generation.GenerationError: generate_rules needs an LLM: pass llm=openai (or llm.model=... llm.api_base=...)
    """
    if not llm.model and not llm.replay_from:
        raise GenerationError(f"{command} needs an LLM: pass llm=openai (or llm.model=... llm.api_base=...)")
    problem = credential_problem(llm)  # a missing key would fail every attempt: say so once, before any
    if problem:
        raise GenerationError(problem)
    return llm


def extract_code_blocks(text: str) -> list[str]:
    r"""Fenced code blocks of an answer (```python ... ```); the whole text if there is no fence.

    Example:
        >>> extract_code_blocks("a\n```python\nx = 1\n```\nb\n```\ny = 2\n```"), extract_code_blocks("z = 3")
        (['x = 1\n', 'y = 2\n'], ['z = 3'])
    """
    blocks = _CODE_BLOCK.findall(text)
    return blocks if blocks else [text]


def generation_output_dir(output: str | Path | None, kind: str, task_name: str, model: str | None) -> Path:
    """``output`` if given, else ``outputs/<kind>/<task>-<model>-<time>``; created.

    Example:
        >>> import tempfile
        >>> out = Path(tempfile.mkdtemp()) / "here"
        >>> generation_output_dir(out, "rules", "ant", "openai/gpt-4o") == out and out.is_dir()
        True
    """
    if output is None:
        model_text = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(model))  # a model string may hold "/" or ":"
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        output = Path("outputs") / kind / f"{task_name}-{model_text}-{stamp}"
    output_dir = Path(output)
    output_dir.mkdir(parents=True, exist_ok=True)
    return output_dir
