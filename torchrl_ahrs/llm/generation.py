"""Where the generator commands (``generate_rules``, ``generate_aux``) write what an LLM produced."""

from __future__ import annotations

import datetime
import re
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf


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
