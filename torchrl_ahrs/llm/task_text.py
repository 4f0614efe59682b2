"""What the prompts say about a task, read from the task config and from our own implementation.

A task config (``conf/task/<task>.yaml``) carries:

- ``description``: the task in a few sentences;
- ``component_descriptions``: ``{component: one-line meaning}``;
- ``reward_code``: ``{component: reference}`` or a list of references shared by every component, each
  ``"module"`` or ``"module:qualified.name"`` inside ``torchrl_ahrs``; the prompts show
  ``inspect.getsource`` of the reference, so the text is the code that runs and cannot drift from it
  (null: the terms are computed inside a simulator, e.g. EnvPool's C++, and only meanings are shown);
- ``environment_code``: a reference to the code that assembles the observation.

The auxiliary component ``aux`` (methods with ``auxiliary: branch``) is described by
:data:`AUX_MEANING`, and its code is the auxiliary reward file itself.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

PACKAGE = "torchrl_ahrs"
AUX = "aux"
AUX_MEANING = (
    "auxiliary reward written by an LLM before training (Eureka-style) to help the agent learn the task; "
    "computed from the observation and action at every step, learnt by its own value head"
)


def source_of(reference: str) -> str | None:
    """``inspect.getsource`` of ``"module"`` or ``"module:qualified.name"`` inside the package.

    Returns None when the reference does not exist.

    Raises:
        ValueError: the reference points outside ``torchrl_ahrs``.

    Example:
        >>> source_of("torchrl_ahrs.llm.task_text:source_of").splitlines()[0]
        'def source_of(reference: str) -> str | None:'
        >>> source_of("torchrl_ahrs.llm.task_text:missing") is None
        True
    """
    module_name, _, qualname = str(reference).partition(":")
    if module_name != PACKAGE and not module_name.startswith(PACKAGE + "."):
        raise ValueError(f"reward/environment code reference {reference!r} must name a module inside {PACKAGE}")
    try:
        target: Any = importlib.import_module(module_name)
        for part in filter(None, qualname.split(".")):
            target = getattr(target, part)
        return inspect.getsource(target)
    except (ImportError, AttributeError, OSError, TypeError):
        return None


def component_meanings(task: Mapping[str, Any], components: Sequence[str]) -> dict[str, str]:
    """``{component: meaning}`` in K order ('' when the task gives none; ``aux`` is always explained).

    Example:
        >>> component_meanings({"component_descriptions": {"a": "forward speed"}}, ["a", "b", "aux"])["a"]
        'forward speed'
    """
    descriptions = task.get("component_descriptions") or {}
    meanings = {}
    for name in components:
        meaning = descriptions.get(name, "") if hasattr(descriptions, "get") else ""
        meanings[name] = str(meaning or (AUX_MEANING if name == AUX else "")).strip()
    return meanings


def reward_code_blocks(
    task: Mapping[str, Any], components: Sequence[str], aux_path: str | Path | None = None
) -> list[tuple[list[str], str]]:
    """``[(components, source)]``: each piece of reward code with the components it computes.

    A list-valued ``task.reward_code`` is one block for every task component; a mapping gives each
    component its reference (components sharing a reference share the block). ``aux`` gets the
    auxiliary reward file's text when ``aux_path`` is given.

    Example:
        >>> task = {"reward_code": {"a": "torchrl_ahrs.llm.task_text:source_of"}}
        >>> [names for names, _ in reward_code_blocks(task, ["a", "b"])]
        [['a']]
    """
    references = task.get("reward_code") or []
    blocks: list[tuple[list[str], str]] = []
    native = [name for name in components if name != AUX]
    if isinstance(references, Mapping):
        by_reference: dict[str, list[str]] = {}
        for name in native:
            reference = references.get(name)
            if reference:
                by_reference.setdefault(str(reference), []).append(name)
        for reference, names in by_reference.items():
            source = source_of(reference)
            if source:
                blocks.append((names, source))
    else:
        sources = [source_of(str(reference)) for reference in references]
        text = "\n\n".join(source for source in sources if source)
        if text:
            blocks.append((native, text))
    if AUX in components and aux_path is not None and Path(aux_path).is_file():
        blocks.append(([AUX], Path(aux_path).read_text()))
    return blocks


def environment_code(task: Mapping[str, Any]) -> str | None:
    """The source of ``task.environment_code`` (the observation), or None."""
    reference = task.get("environment_code")
    return source_of(str(reference)) if reference else None
