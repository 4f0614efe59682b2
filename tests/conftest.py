"""Shared fixtures: a scripted local OpenAI-compatible server and a loopback-only network guard; and what
tests in several folders use (``from conftest import ...``): ``make_cfg``, the one way tests compose the
packaged Hydra config, ``FAST``, the overrides of a tiny point_reach run, and ``differences``, where two
checkpoints differ bit for bit."""

import socket

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_module
from llm_server import ScriptedServer
from tensordict import TensorDictBase

FAST = [  # a tiny point_reach run: seconds on one core
    "task=point_reach",
    "trainer.total_frames=2048",
    "trainer.num_envs=16",
    "trainer.frames_per_batch=512",
    "trainer.mini_batch_size=128",
    "trainer.num_epochs=2",
    "trainer.progress_bar=false",
    "scheduler.interval=1",
    "model.hidden_sizes=[32,32]",
]


def make_cfg(*overrides: str, hydra: bool = False):
    """``conf/config.yaml`` composed with ``overrides`` as on the command line; ``hydra=True`` keeps the
    ``hydra`` section (launcher, callbacks, run dir)."""
    with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides), return_hydra_config=hydra)


def differences(a, b, path="checkpoint"):
    """Where two checkpoints differ (bit for bit), as a list of paths into them."""
    if isinstance(a, TensorDictBase) and isinstance(b, TensorDictBase):
        keys = set(a.keys(True, True))
        if keys != set(b.keys(True, True)):
            return [f"{path}: keys {sorted(map(str, keys ^ set(b.keys(True, True))))}"]
        return [f"{path}/{key}" for key in sorted(keys, key=str) if not torch.equal(a[key], b[key])]
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [f"{path}: keys {sorted(map(str, set(a) ^ set(b)))}"]
        return [d for key in a for d in differences(a[key], b[key], f"{path}/{key}")]
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        if len(a) != len(b):
            return [f"{path}: lengths {len(a)} != {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in differences(x, y, f"{path}[{i}]")]
    if isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor):
        same = a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b)
        return [] if same else [path]
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        return [] if a.dtype == b.dtype and np.array_equal(a, b) else [path]
    return [] if type(a) is type(b) and a == b else [f"{path}: {a!r} != {b!r}"]


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
