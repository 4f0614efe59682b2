"""Parsers for LLM answers. Each returns the decision or raises ``ValueError`` saying what is wrong.

The rule-selection answer is a serial number between tildes, ``~[N]~``. Models wrap it in markdown
(``**~[3]~**``, backticks), add spaces (``~ [ 3 ] ~``) or drop the brackets (``~3~``); all of these
are read. When several appear (reasoning first, answer last) the last one counts.
"""

from __future__ import annotations

import math
import re

_NUMBER = r"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?"
_RULE_ANSWER = re.compile(r"~\s*\[?\s*([-+]?\d+)\s*\]?\s*~")
_WEIGHTS_ANSWER = re.compile(r"~\s*\[([^\]~]*)\]\s*~")


def _strip_markdown(text: str) -> str:
    return re.sub(r"[*_`]", "", text)  # emphasis and code marks never carry the answer


def parse_rule_answer(text: str, num_rules: int) -> int:
    """The rule id in ``text`` (``~[N]~``), checked to be in ``1..num_rules``.

    Example:
        >>> parse_rule_answer("I pick **~[ 3 ]~**.", 8)
        3
        >>> parse_rule_answer("~[9]~", 8)
        Traceback (most recent call last):
        ...
        ValueError: rule 9 is out of range 1..8
    """
    matches = _RULE_ANSWER.findall(_strip_markdown(text))
    if not matches:
        raise ValueError("no answer of the form ~[N]~ found")
    rule_id = int(matches[-1])
    if not 1 <= rule_id <= num_rules:
        raise ValueError(f"rule {rule_id} is out of range 1..{num_rules}")
    return rule_id


def parse_weights_answer(text: str, num_components: int) -> list[float]:
    """K non-negative finite weights with a positive sum from ``~[w1, ..., wK]~`` (AHRS-D).

    Example:
        >>> parse_weights_answer("weights: ~[0.5, 1, 2e-1]~", 3)
        [0.5, 1.0, 0.2]
    """
    matches = _WEIGHTS_ANSWER.findall(_strip_markdown(text))
    if not matches:
        raise ValueError(f"no answer of the form ~[w1, ..., w{num_components}]~ found")
    fields = [field.strip() for field in matches[-1].split(",") if field.strip()]
    values = []
    for field in fields:
        if not re.fullmatch(_NUMBER, field):
            raise ValueError(f"{field!r} is not a number")
        values.append(float(field))
    if len(values) != num_components:
        raise ValueError(f"expected {num_components} weights, got {len(values)}")
    if not all(math.isfinite(value) and value >= 0 for value in values):
        raise ValueError(f"weights must be finite and non-negative, got {values}")
    if sum(values) <= 0:
        raise ValueError("weights must not all be zero")
    return values
