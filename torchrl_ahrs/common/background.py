"""A call in a daemon thread, as a ``Future``: a background LLM decision that never answers cannot hold up the
interpreter's exit (``ThreadPoolExecutor`` joins its threads at exit, however long the call takes)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any


def in_daemon_thread(fn: Callable[..., Any], *args: Any, name: str = "background") -> Future:
    """``fn(*args)`` in a daemon thread; its result (or exception) in the returned Future.

    Example:
        >>> in_daemon_thread(sum, [1, 2, 3]).result(timeout=5)
        6
    """
    future: Future = Future()

    def run() -> None:
        try:
            future.set_result(fn(*args))
        except BaseException as error:  # noqa: BLE001 (handed to whoever collects the future)
            future.set_exception(error)

    threading.Thread(target=run, name=name, daemon=True).start()
    return future
