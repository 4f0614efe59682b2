"""What the client needs to know about litellm and the providers behind it: importing litellm quietly,
whether a failure means no key reached the provider, how long a failed response asks to wait, and the
exception at the bottom of litellm's chain."""

from __future__ import annotations

import logging
import time
from email.utils import parsedate_to_datetime
from typing import Any

__all__ = ["import_litellm", "is_missing_credentials", "retry_after", "root_cause"]


def import_litellm() -> Any:
    """litellm, imported on first use (slow, and offline runs never need it), quiet: no telemetry, no
    "Give Feedback" banner, its loggers at WARNING (our own log line per call says what happened)."""
    import litellm

    litellm.telemetry = False
    litellm.suppress_debug_info = True
    for name in ("LiteLLM", "LiteLLM Router", "LiteLLM Proxy", "httpx"):
        logging.getLogger(name).setLevel(logging.WARNING)
    return litellm


def is_missing_credentials(error: BaseException) -> bool:
    """True for a call that failed because no API key reached the provider: litellm raises the OpenAI SDK's
    "Missing credentials" as an ``InternalServerError`` (a 5xx, which would be retried), though no retry
    can supply a key.

    Example:
        >>> is_missing_credentials(RuntimeError("OpenAIException - Missing credentials. Please pass an `api_key`"))
        True
        >>> is_missing_credentials(RuntimeError("Connection error."))
        False
    """
    text = str(error)
    return "Missing credentials" in text or "api_key client option must be set" in text


def retry_after(error: BaseException) -> float | None:
    """Seconds a failed response asks the client to wait (``retry-after-ms`` or ``Retry-After`` as
    seconds or an HTTP date), from the headers litellm attaches to its exception; None if absent.

    Example:
        >>> class Limited(Exception):
        ...     litellm_response_headers = {"retry-after": "2"}
        >>> retry_after(Limited()), retry_after(ValueError())
        (2.0, None)
    """
    for source in (
        getattr(error, "litellm_response_headers", None),
        getattr(getattr(error, "response", None), "headers", None),
        getattr(error, "headers", None),
    ):
        if not source:
            continue
        headers = {str(key).lower(): str(value) for key, value in dict(source).items()}
        try:
            if "retry-after-ms" in headers:
                return max(0.0, float(headers["retry-after-ms"]) / 1000)  # ms -> s
            if "retry-after" in headers:
                value = headers["retry-after"].strip()
                if value.replace(".", "", 1).isdigit():
                    return float(value)
                moment = parsedate_to_datetime(value)  # an HTTP date: wait until then
                return max(0.0, moment.timestamp() - time.time())
        except (TypeError, ValueError, OverflowError):
            continue  # an unreadable header is no demand
    return None


def root_cause(error: BaseException) -> str:
    """`` [cause: <innermost exception>]`` when the chain under ``error`` ends in a different exception
    (litellm reports a refused connection, a reset and a truncated body all as "InternalServerError"),
    else ''.

    Example:
        >>> try:
        ...     try:
        ...         raise ConnectionResetError(104, "Connection reset by peer")
        ...     except OSError as inner:
        ...         raise RuntimeError("Connection error.") from inner
        ... except RuntimeError as outer:
        ...     print(root_cause(outer))
         [cause: ConnectionResetError: [Errno 104] Connection reset by peer]
    """
    innermost, seen = error, {id(error)}
    while True:
        below = innermost.__cause__
        if below is None and not innermost.__suppress_context__:  # as tracebacks do ("from None" hides it)
            below = innermost.__context__
        if below is None or id(below) in seen:
            break
        innermost = below
        seen.add(id(below))
    if innermost is error:
        return ""
    return f" [cause: {type(innermost).__name__}: {str(innermost)[:200]}]"
