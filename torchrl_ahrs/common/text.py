"""Text that reaches logs, decision files and LLM requests: one line, capped.

An exception's message or a model's answer is written by code or a model this project does not control; a
rule raising a 1 MB message would otherwise copy it into ``train.log``, stderr and
``scheduler_decisions.jsonl`` at every decision, and a 2 MB answer would be sent back whole in the
correction request.
"""

from __future__ import annotations

ERROR_CHARS = 500  # an exception's text in a log line or a decision record
ANSWER_CHARS = 4000  # a model's answer quoted back to it (correction requests)
LOGGED_ANSWER_CHARS = 65536  # a model's answer stored in llm_calls.jsonl


def cap_text(text: object, limit: int = ERROR_CHARS) -> str:
    """``text`` cut to ``limit`` characters, saying how long it was.

    Example:
        >>> cap_text("x" * 10, 4)
        'xxxx... [10 chars, cut at 4]'
        >>> cap_text("short", 10)
        'short'
    """
    text = str(text)
    return text if len(text) <= limit else f"{text[:limit]}... [{len(text)} chars, cut at {limit}]"


def one_line(text: object, limit: int = ERROR_CHARS) -> str:
    """``text`` with its whitespace runs collapsed to one space, capped (:func:`cap_text`).

    Example:
        >>> one_line("KeyError:\\n  'height'")
        "KeyError: 'height'"
    """
    text = str(text)
    return cap_text(" ".join(text[: 4 * limit].split()) + (" ..." if len(text) > 4 * limit else ""), limit)


def error_line(error: BaseException, limit: int = ERROR_CHARS) -> str:
    """``"<type>: <message>"`` on one line, capped.

    Example:
        >>> error_line(KeyError("height"))
        "KeyError: 'height'"
    """
    return one_line(f"{type(error).__name__}: {error}", limit)
