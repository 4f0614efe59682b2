"""One LLM client over litellm: timeouts, retries with backoff, a JSONL call log, a disk cache, replay.

Every :meth:`LLMClient.complete` call writes one JSON line to the calls log its caller names (a run's
``llm_calls.jsonl``, see :mod:`torchrl_ahrs.app.shared.run_dir`):
time, purpose, model, prompt hash, prompt (the messages), response, parsed decision, parse error,
latency, tokens, cost, attempts, error, and whether the answer came from the cache or a replay. The
API key comes from the environment variable named by ``llm.api_key_env`` (preferred) or from
``llm.api_key``; it is never written, and both are masked in error texts.

* **Retries**: timeouts, connection errors, HTTP 429/5xx and unreadable bodies are retried
  ``llm.max_retries`` times with doubling backoff; a 429/503 ``Retry-After`` (or ``retry-after-ms``)
  header is honoured up to ``llm.max_retry_after`` seconds; a longer demand ends the call at once (the
  selector falls back) instead of stalling training. Bad requests (e.g. a prompt over the model's
  context window), authentication errors and a missing key (which litellm reports as a server error,
  :func:`is_missing_credentials`) are not retried; ``train`` refuses a missing key at start
  (:mod:`torchrl_ahrs.app.train.preflight`, ``litellm.validate_environment``).

  Why these retries are ours and not litellm's ``num_retries`` (checked against litellm 1.102): litellm
  retries inside one ``completion`` call with its own (or the OpenAI SDK's) backoff, so (1) the decision's
  budget (``llm.decision_budget``), which shrinks each attempt's timeout and refuses a backoff that would
  overrun it, cannot bound the attempts; (2) the calls log would record one outcome where it now records
  every attempt's error and the attempt count; (3) the SDK honours a ``Retry-After`` of up to a minute,
  past ``llm.max_retry_after``. The request itself (provider routing, the timeout of each attempt, token
  usage and cost) is litellm's.

* **Cache** (``llm.cache_dir``): answers keyed by model + messages; a rerun with the same prompts is free.
* **Replay** (``llm=replay llm.replay_from=<run dir>``; the application layer turns a run directory into
  its calls log): answers come only from that log, matched
  by prompt hash in the order they were recorded; a miss raises :class:`ReplayMiss`, which stops the
  run (a replay that silently diverged would be worse).

``LITELLM_LOCAL_MODEL_COST_MAP=True`` is set before litellm is imported (else it downloads a price
map at import); litellm itself is imported on first use so runs without an LLM never load it.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import threading
import time
from collections import defaultdict, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from torchrl_ahrs.common.text import LOGGED_ANSWER_CHARS, cap_text, one_line

os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")

from torchrl_ahrs.llm.provider import import_litellm, is_missing_credentials, retry_after, root_cause  # noqa: E402

__all__ = [
    "FatalSelectorError",
    "LLMClient",
    "LLMConfig",
    "LLMReply",
    "ReplayMiss",
    "credential_problem",
    "prompt_hash",
    "retry_after",
    "root_cause",
]

log = logging.getLogger(__name__)
Messages = list[dict[str, str]]
# errors that a retry cannot fix
_NON_RETRYABLE = (
    "AuthenticationError",
    "BadRequestError",
    "NotFoundError",
    "PermissionDeniedError",
    "ContextWindowExceededError",
)


class FatalSelectorError(RuntimeError):
    """An error that must stop training instead of being absorbed by the scheduler's guards."""


class ReplayMiss(FatalSelectorError):
    """Replay mode was asked a prompt that the recorded run never asked (or asked fewer times)."""


@dataclass
class LLMConfig:
    """The ``llm`` config group as a typed record (see ``conf/llm/*.yaml`` for each field)."""

    name: str = "offline"
    model: str | None = None
    api_base: str | None = None
    api_key_env: str | None = None
    api_key: str | None = field(default=None, repr=False)  # discouraged (use api_key_env); never printed
    temperature: float = 0.0
    max_tokens: int = 1024
    timeout: float = 60.0
    decision_budget: float | None = None  # seconds for one decision: every attempt, backoff and correction
    max_retries: int = 3
    backoff: float = 2.0
    max_retry_after: float = 30.0
    cache_dir: str | None = None
    replay_from: str | None = None

    @classmethod
    def from_cfg(cls, cfg: Mapping[str, Any] | Any) -> LLMConfig:
        keys = cls.__dataclass_fields__
        return cls(**{key: cfg[key] for key in keys if key in cfg and cfg[key] is not None})


@dataclass
class LLMReply:
    """The outcome of one :meth:`LLMClient.complete` call (``text`` is None when every attempt failed)."""

    text: str | None
    parsed: Any = None
    parse_error: str | None = None
    error: str | None = None
    attempts: int = 0
    latency: float = 0.0
    tokens: dict[str, int] = field(default_factory=dict)
    cost: float | None = None
    source: str = "llm"  # llm | cache | replay


def prompt_hash(messages: Messages) -> str:
    """sha256 of the messages (model-independent: replay matches recorded prompts across models)."""
    return hashlib.sha256(json.dumps(messages, sort_keys=True).encode()).hexdigest()


class LLMClient:
    """Sends chat messages to any litellm model; logs, caches and replays.

    Args:
        config: model, endpoint, sampling, timeout/retry settings, cache and replay locations.
        calls_path: the JSONL file each call is appended to (None = no log).
        sleep: the backoff sleep (tests pass a no-op).

    Example:
        >>> client = LLMClient(LLMConfig(model="openai/test", api_base="http://127.0.0.1:9/v1",
        ...                              timeout=0.5, max_retries=0))
        >>> reply = client.complete([{"role": "user", "content": "hi"}], purpose="doc")  # doctest: +SKIP
        >>> reply.text is None, reply.error.startswith("APIConnectionError")  # doctest: +SKIP
        (True, True)
    """

    def __init__(
        self, config: LLMConfig, calls_path: str | Path | None = None, sleep: Callable[[float], None] = time.sleep
    ):
        self.config = config
        self.calls_path = Path(calls_path) if calls_path is not None else None
        self.sleep = sleep
        self._lock = threading.Lock()
        self._replay: dict[str, deque[dict]] | None = None
        if config.replay_from:
            self._replay = self._load_replay(Path(config.replay_from))
        elif not config.model:
            raise ValueError("LLMClient needs llm.model (or llm.replay_from for replay)")

    # ---------------------------------------------------------------- public
    def complete(
        self,
        messages: Messages,
        purpose: str,
        parser: Callable[[str], Any] | None = None,
        deadline: float | None = None,
    ) -> LLMReply:
        """Asks the model (or cache / replay); parses the answer with ``parser`` (which raises ValueError
        on a bad answer); logs one line. Never raises for network or parse problems; they are in the reply.
        ``deadline`` (``time.monotonic()`` seconds) bounds every attempt and backoff together."""
        digest = prompt_hash(messages)
        if self._replay is not None:
            reply = self._answer_from_replay(digest)
        else:
            reply = self._answer_from_cache(digest) or self._ask(messages, deadline)
            if reply.text is not None and reply.source == "llm":
                self._store_in_cache(digest, reply.text)
        if reply.text is not None and parser is not None:
            try:
                reply.parsed = parser(reply.text)
            except ValueError as error:
                reply.parse_error = one_line(error)  # a parser may quote the whole answer
        self._log(purpose, digest, messages, reply)
        return reply

    # ---------------------------------------------------------------- the model
    def _api_key(self) -> str | None:
        if self.config.api_key:
            return self.config.api_key
        if self.config.api_key_env and os.environ.get(self.config.api_key_env):
            return os.environ[self.config.api_key_env]
        return "not-needed" if self.config.api_base else None  # local servers ignore it; the SDK wants one

    def _mask(self, text: str) -> str:
        secrets = [self.config.api_key, os.environ.get(self.config.api_key_env or "")]
        for secret in secrets:
            if secret and len(secret) > 3:
                text = text.replace(secret, "***")
        return text

    def _ask(self, messages: Messages, deadline: float | None = None) -> LLMReply:
        litellm = import_litellm()
        errors: list[str] = []
        started = time.monotonic()
        server_wait: float | None = None  # the last Retry-After demand
        for attempt in range(self.config.max_retries + 1):
            delay = max(self.config.backoff * 2 ** (attempt - 1), server_wait or 0.0) if attempt else 0.0
            left = deadline - time.monotonic() if deadline is not None else None  # the decision's budget
            if left is not None and left <= delay:
                errors.append(f"decision budget spent after {attempt} attempt(s) (llm.decision_budget)")
                return LLMReply(None, error="; ".join(errors), attempts=attempt, latency=time.monotonic() - started)
            if attempt:
                self.sleep(delay)  # backoff doubling per retry; the server's demand wins when longer
            timeout = self.config.timeout if left is None else max(0.1, min(self.config.timeout, left - delay))
            try:
                response = litellm.completion(
                    model=self.config.model,
                    messages=messages,
                    api_base=self.config.api_base,
                    api_key=self._api_key(),
                    temperature=self.config.temperature,
                    max_tokens=self.config.max_tokens,
                    timeout=timeout,
                    num_retries=0,  # retries are ours (logged, with our backoff)
                    max_retries=0,
                )
            except Exception as error:  # noqa: BLE001 (every failure is recorded, then retried or returned)
                name = type(error).__name__
                errors.append(self._mask(f"{name}: {str(error)[:300]}{root_cause(error)}"))
                log.warning("LLM call attempt %d failed: %s", attempt + 1, errors[-1])
                if name in _NON_RETRYABLE or is_missing_credentials(error):
                    break
                server_wait = retry_after(error)
                if server_wait is not None and server_wait > self.config.max_retry_after:
                    errors[-1] += (
                        f" (server asks to retry after {server_wait:g} s > llm.max_retry_after="
                        f"{self.config.max_retry_after:g} s: not retried)"
                    )
                    break
                continue
            text = self._mask(response.choices[0].message.content or "")  # an answer echoing the key keeps none of it
            usage = getattr(response, "usage", None)
            tokens = {
                key: int(getattr(usage, key, 0) or 0) for key in ("prompt_tokens", "completion_tokens", "total_tokens")
            }
            try:
                cost = float(litellm.completion_cost(completion_response=response))
            except Exception:  # noqa: BLE001 (unknown models have no price)
                cost = None
            return LLMReply(
                text,
                error="; ".join(errors) or None,
                attempts=attempt + 1,
                latency=time.monotonic() - started,
                tokens=tokens,
                cost=cost,
            )
        return LLMReply(None, error="; ".join(errors), attempts=len(errors), latency=time.monotonic() - started)

    # ---------------------------------------------------------------- cache and replay
    def _cache_path(self, digest: str) -> Path | None:
        if not self.config.cache_dir:
            return None
        key = hashlib.sha256(f"{self.config.model}\n{digest}".encode()).hexdigest()
        return Path(self.config.cache_dir) / f"{key}.json"

    def _answer_from_cache(self, digest: str) -> LLMReply | None:
        path = self._cache_path(digest)
        if path is None or not path.exists():
            return None
        try:
            return LLMReply(json.loads(path.read_text())["response"], source="cache", attempts=0)
        except (OSError, ValueError, KeyError):
            return None  # a damaged cache entry is a miss

    def _store_in_cache(self, digest: str, text: str) -> None:
        path = self._cache_path(digest)
        if path is None:
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_suffix(".tmp")
        temporary.write_text(json.dumps({"model": self.config.model, "prompt_hash": digest, "response": text}))
        temporary.replace(path)

    @staticmethod
    def _load_replay(path: Path) -> dict[str, deque[dict]]:
        if not path.is_file():
            raise FileNotFoundError(f"replay: no calls log at {path}")
        recorded: dict[str, deque[dict]] = defaultdict(deque)
        for line in path.read_text().splitlines():
            if line.strip():
                entry = json.loads(line)
                recorded[entry["prompt_hash"]].append(entry)
        return recorded

    def _answer_from_replay(self, digest: str) -> LLMReply:
        queue = self._replay.get(digest) if self._replay is not None else None
        if not queue:
            raise ReplayMiss(f"replay: prompt {digest[:12]} was not recorded (or was asked more often than recorded)")
        entry = queue.popleft()
        return LLMReply(
            entry["response"], error=entry.get("error"), attempts=int(entry.get("attempts", 0)), source="replay"
        )

    # ---------------------------------------------------------------- the log
    def _log(self, purpose: str, digest: str, messages: Messages, reply: LLMReply) -> None:
        if self.calls_path is None:
            return
        entry = {
            "time": time.time(),
            "purpose": purpose,
            "model": self.config.model,
            "api_base": self.config.api_base,
            "prompt_hash": digest,
            "prompt": messages,
            "response": cap_text(reply.text, LOGGED_ANSWER_CHARS) if reply.text is not None else None,
            "parsed": reply.parsed,
            "parse_error": reply.parse_error,
            "latency": round(reply.latency, 4),
            "tokens": reply.tokens,
            "cost": reply.cost,
            "attempts": reply.attempts,
            "error": reply.error,
            "source": reply.source,
        }
        with self._lock:
            self.calls_path.parent.mkdir(parents=True, exist_ok=True)
            with open(self.calls_path, "a") as handle:
                handle.write(self._mask(json.dumps(entry, default=str)) + "\n")  # the key never reaches the file


def credential_problem(config: LLMConfig) -> str | None:
    """One line naming the environment variable when the provider of ``config.model`` needs a key that is not
    set (``litellm.validate_environment``: no request is sent), else None. Replay and a config without a model
    call no provider; with ``api_base`` (a local server) the placeholder key the client sends is enough.

    Example:
        >>> credential_problem(LLMConfig(model="openai/local", api_base="http://127.0.0.1:8000/v1")) is None
        True
    """
    if not config.model or config.replay_from or config.name == "replay":
        return None
    key = LLMClient(config)._api_key()
    found = import_litellm().validate_environment(model=config.model, api_key=key, api_base=config.api_base)
    missing = list(found.get("missing_keys") or [])
    if not missing:
        return None
    variable = config.api_key_env or missing[0]
    return (
        f"llm.model={config.model} needs the {variable} environment variable, which is not set: "
        f"export {variable}=..., or use llm=offline (the bandit stands in for the LLM)"
    )
