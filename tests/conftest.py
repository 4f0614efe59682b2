"""Shared fixtures: a scripted local OpenAI-compatible server and a loopback-only network guard."""

import socket

import pytest
from llm_server import ScriptedServer


@pytest.fixture
def llm_server():
    """A :class:`llm_server.ScriptedServer` on 127.0.0.1, closed after the test."""
    instance = ScriptedServer()
    yield instance
    instance.close()


@pytest.fixture
def loopback_only(monkeypatch):
    """Fails the test if anything in this process connects to a host other than loopback."""
    real_connect = socket.socket.connect
    attempts = []

    def guarded(self, address):
        host = address[0] if isinstance(address, tuple) else address
        if host not in ("127.0.0.1", "localhost", "::1"):
            attempts.append(address)  # recorded: a library could swallow the exception below
            raise OSError(f"network access attempted: {address}")
        return real_connect(self, address)

    monkeypatch.setattr(socket.socket, "connect", guarded)
    yield
    assert attempts == [], f"network access attempted: {attempts}"
