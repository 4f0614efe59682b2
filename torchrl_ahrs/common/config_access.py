"""Reading optional settings from a composed config or from a plain nested dict."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from omegaconf import OmegaConf


def select(cfg: Any, key: str, default: Any = None) -> Any:
    """The value at dotted ``key``, or ``default`` when it, or a section on the way, is missing or null.

    ``cfg`` is an OmegaConf config (interpolations resolved) or a plain nested mapping (a config turned
    into a container); anything else has no settings and gives ``default``.

    Example:
        >>> cfg = OmegaConf.create({"aux": {"scale": 2.0, "path": None}})
        >>> select(cfg, "aux.scale", 1.0), select(cfg, "aux.path", "shipped"), select(cfg, "llm.model")
        (2.0, 'shipped', None)
        >>> select({"seed": 3}, "seed", 0), select(None, "seed", 0)
        (3, 0)
    """
    if OmegaConf.is_config(cfg):
        value = OmegaConf.select(cfg, key, default=None)
    else:
        value = cfg
        for part in key.split("."):
            value = value.get(part) if isinstance(value, Mapping) else None
    return default if value is None else value
