"""One run of a sweep as the report sees it: a plain record, with the paper's method order.

Reading run directories into these records is :mod:`torchrl_ahrs.app.train.runs`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

# the paper's column order; other methods follow alphabetically
METHOD_ORDER = ("ppo", "hdppo", "ahrs_wo_a", "ahrs", "ahrs_r", "ahrs_d", "ppo_a", "hdppo_a", "mcppo")


@dataclass
class Run:
    """One run directory of a sweep and what the report needs from it.

    ``curves`` maps a scalar name (``return/total``, ``return/<c>``, ``weight/<c>``, ``share/<c>``) to (steps [R], values
    [R]); ``final`` maps ``return/total`` and ``return/<c>`` to the final return, and ``reward/total`` to the final
    reward per step (NaN when unavailable).

    Example:
        >>> run = Run(None, "point_reach", "ppo", 2, "missing", "no run directory for this seed")
        >>> run.ok, run.final_return
        (False, nan)
    """

    path: Path | None
    task: str
    method: str
    seed: int
    status: str
    reason: str = ""
    total_frames: int = 0
    collected_frames: int = 0
    components: list[str] = field(default_factory=list)
    curves: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    final: dict[str, float] = field(default_factory=dict)
    decisions: list[dict[str, Any]] = field(default_factory=list)
    llm_calls: list[dict[str, Any]] = field(default_factory=list)
    llm_name: str = "offline"
    where: str = ""  # <sweep dir name>/<path inside it>, for the report (absolute paths do not travel)

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def scheduled(self) -> bool:
        """Whether a selector changed the weights during training (not PPO's constant weights)."""
        return any(d.get("selector") not in (None, "constant") for d in self.decisions)

    @property
    def final_return(self) -> float:
        return self.final.get("return/total", math.nan)


def method_label(config: dict[str, Any]) -> str:
    """The method's name, plus who chose the weights when the method asks an LLM: ``[bandit]`` where the offline
    stand-in chose (no LLM was called), else the LLM backend, e.g. ``ahrs_wo_a[openai]``."""
    method = config.get("method", {}) or {}
    llm = (config.get("llm", {}) or {}).get("name", "offline")
    uses_llm = method.get("selector") in ("llm", "direct")
    if not uses_llm:
        return str(method.get("name", "?"))
    return f"{method.get('name', '?')}[{'bandit' if llm == 'offline' else llm}]"


def method_rank(method: str) -> tuple[int, str]:
    """Sort key putting methods in the paper's order."""
    base = method.split("[", 1)[0]
    return (METHOD_ORDER.index(base) if base in METHOD_ORDER else len(METHOD_ORDER), method)
