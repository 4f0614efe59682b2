"""Shared fixtures: a scripted local OpenAI-compatible server and a loopback-only network guard; and
``make_cfg``, the one way tests compose the packaged Hydra config (``from conftest import make_cfg``)."""

import socket

import pytest
from hydra import compose, initialize_config_module
from llm_server import ScriptedServer


def make_cfg(*overrides: str, hydra: bool = False):
    """``conf/config.yaml`` composed with ``overrides`` as on the command line; ``hydra=True`` keeps the
    ``hydra`` section (launcher, callbacks, run dir)."""
    with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides), return_hydra_config=hydra)


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
