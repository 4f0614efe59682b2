"""What the generator commands (``generate_rules``, ``generate_aux``) share: their LLM and task from the
config, the code blocks of an answer, and where they write what the LLM produced."""

from __future__ import annotations

import datetime
import re
from pathlib import Path
from typing import Any, cast

from omegaconf import OmegaConf

from torchrl_ahrs.llm.client import LLMConfig, credential_problem

_CODE_BLOCK = re.compile(r"```[ \t]*(?:python|py)?[ \t]*\n(.*?)```", re.DOTALL)


class GenerationError(RuntimeError):
    """A generator command that cannot ask its LLM; the message says why."""


def llm_and_task(cfg: Any, command: str) -> tuple[LLMConfig, dict[str, Any]]:
    """The LLM settings and the resolved task section of a composed config; refuses a config without an
    LLM (``llm=offline``), naming ``command`` and how to give one."""
    llm_cfg = LLMConfig.from_cfg(OmegaConf.to_container(cfg.llm, resolve=True))
    if not llm_cfg.model and not llm_cfg.replay_from:
        raise GenerationError(f"{command} needs an LLM: pass llm=openai (or llm.model=... llm.api_base=...)")
    problem = credential_problem(llm_cfg)  # a missing key would fail every attempt: say so once, before any
    if problem:
        raise GenerationError(problem)
    return llm_cfg, cast(dict[str, Any], OmegaConf.to_container(cfg.task, resolve=True))


def extract_code_blocks(text: str) -> list[str]:
    r"""Fenced code blocks of an answer (```python ... ```); the whole text if there is no fence.

    Example:
        >>> extract_code_blocks("a\n```python\nx = 1\n```\nb\n```\ny = 2\n```"), extract_code_blocks("z = 3")
        (['x = 1\n', 'y = 2\n'], ['z = 3'])
    """
    blocks = _CODE_BLOCK.findall(text)
    return blocks if blocks else [text]


def generation_output_dir(cfg: Any, kind: str) -> Path:
    """``cfg.output`` if given, else ``outputs/<kind>/<task>-<model>-<time>``; created.

    Example:
        >>> import tempfile
        >>> out = Path(tempfile.mkdtemp()) / "here"
        >>> generation_output_dir(OmegaConf.create({"output": str(out)}), "rules") == out and out.is_dir()
        True
    """
    output = OmegaConf.select(cfg, "output")
    if output is None:
        model = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(cfg.llm.model))  # a model string may hold "/" or ":"
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        output = Path("outputs") / kind / f"{cfg.task.name}-{model}-{stamp}"
    output_dir = Path(output)
    output_dir.mkdir(parents=True, exist_ok=True)
    return output_dir
