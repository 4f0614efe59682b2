"""A scripted OpenAI-compatible ``/v1/chat/completions`` server on 127.0.0.1 for tests (no network).

Each request takes the next step of ``server.script`` (the last step repeats when the script runs out):

* ``("ok", text)``: a valid chat completion whose answer is ``text``;
* ``("status", code)``: HTTP ``code`` with an OpenAI-style error body;
* ``("http", code, headers, body)``: any status, extra headers (e.g. ``{"Retry-After": "1"}``) and raw body;
* ``("slow", seconds)``: waits, then answers ``~[1]~`` (past a client timeout);
* ``("garbage", body)``: HTTP 200 with a non-JSON body;
* ``("truncated", text)``: HTTP 200 with the first half of a valid completion (a correct Content-Length);
* ``("reset", text)``: headers and part of the body, then a TCP reset (RST) in the middle of the response;
* ``("echo_key", status)``: an error that quotes the request's API key back (as OpenAI's HTTP 401 does).

``free_port()`` is a port with no listener (the "server down" case).

Example:
    >>> server = ScriptedServer()
    >>> server.script = [("ok", "~[3]~")]
    >>> server.port > 0
    True
    >>> server.close()
"""

from __future__ import annotations

import json
import socket
import struct
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


def completion_body(text: str, model: str = "test") -> bytes:
    """An OpenAI chat-completion JSON body answering ``text``."""
    return json.dumps(
        {
            "id": "chatcmpl-test",
            "object": "chat.completion",
            "created": 0,
            "model": model,
            "choices": [{"index": 0, "message": {"role": "assistant", "content": text}, "finish_reason": "stop"}],
            "usage": {"prompt_tokens": 100, "completion_tokens": 5, "total_tokens": 105},
        }
    ).encode()


def context_length_error(limit: int = 8192, asked: int = 9000) -> bytes:
    """The body OpenAI sends (HTTP 400) when the prompt does not fit the model's context window."""
    message = (
        f"This model's maximum context length is {limit} tokens. However, your messages resulted in "
        f"{asked} tokens. Please reduce the length of the messages."
    )
    error = {
        "message": message,
        "type": "invalid_request_error",
        "param": "messages",
        "code": "context_length_exceeded",
    }
    return json.dumps({"error": error}).encode()


def free_port() -> int:
    """A loopback port nobody listens on (bound, then released)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


class ScriptedServer:
    """The scripted server (see the module docstring) on ``port`` (0 = any free one); ``requests`` records
    each body, auth header and arrival time (``time.monotonic()``)."""

    def __init__(self, port: int = 0):
        self.script: list[tuple] = [("ok", "~[1]~")]
        self.requests: list[dict] = []
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_POST(self):
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                server.requests.append(
                    {"body": body, "auth": self.headers.get("Authorization"), "time": time.monotonic()}
                )
                step = server.script.pop(0) if len(server.script) > 1 else server.script[0]
                try:
                    self._answer(step, body.get("model", "test"))
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the client gave up (timeout)

            def _answer(self, step: tuple, model: str) -> None:
                kind = step[0]
                if kind == "slow":
                    time.sleep(step[1])
                    kind, step = "ok", ("ok", "~[1]~")
                if kind == "status":
                    error = {"error": {"message": f"scripted {step[1]}", "type": "test"}}
                    return self._send(step[1], json.dumps(error).encode())
                if kind == "http":
                    return self._send(step[1], step[3], step[2])
                if kind == "echo_key":
                    key = (self.headers.get("Authorization") or "").removeprefix("Bearer ")
                    error = {"message": f"Incorrect API key provided: {key}.", "type": "invalid_request_error"}
                    return self._send(step[1], json.dumps({"error": {**error, "code": "invalid_api_key"}}).encode())
                if kind == "garbage":
                    return self._send(200, step[1].encode())
                payload = completion_body(step[1], model)
                if kind == "truncated":
                    return self._send(200, payload[: len(payload) // 2])
                if kind == "reset":
                    self.send_response(200)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(payload)))
                    self.end_headers()
                    self.wfile.write(payload[: len(payload) // 3])
                    self.wfile.flush()
                    # SO_LINGER with a zero timeout turns close() into a TCP RST: "connection reset by peer"
                    self.connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                    self.connection.close()
                    self.close_connection = True
                    return None
                return self._send(200, payload)

            def _send(self, status: int, payload: bytes, headers: dict | None = None) -> None:
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(payload)))
                for name, value in (headers or {}).items():
                    self.send_header(name, value)
                self.end_headers()
                self.wfile.write(payload)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", port), Handler)
        self.httpd.daemon_threads = True
        self.port = self.httpd.server_address[1]
        self.api_base = f"http://127.0.0.1:{self.port}/v1"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
