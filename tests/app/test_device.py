"""``trainer.device``: where the learner lives, and where the environments live with it.

On this CPU-only machine ``trainer.device=cpu`` must be today's run exactly; the placement of every
learner part is checked on torch's ``meta`` device, which has no memory, so a part left behind on the CPU
shows up as a CPU tensor. (The MJX env's step on the device: ``tests/envs/test_mjx.py``.)"""

import json

import pytest
import torch
from conftest import differences, make_cfg

from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.app.train.build import RunDevices, build_networks, env_factory, resolve_devices
from torchrl_ahrs.app.train.iteration import train

SHORT_RUN = [
    "task=point_reach",
    "method=ahrs",  # K = 4 heads with the auxiliary reward, a rule decision every 2 iterations
    "task.max_episode_steps=20",
    "trainer.num_envs=16",
    "trainer.frames_per_batch=256",
    "trainer.mini_batch_size=64",
    "trainer.total_frames=1024",
    "trainer.progress_bar=false",
    "model.hidden_sizes=[32,32]",
    "ppo.value_norm=running",
    "scheduler.interval=2",
]


def run_files(run_dir):
    run = RunDirectory(run_dir)
    metrics = {
        path.relative_to(run.metrics): path.read_text()
        for path in sorted(run.metrics.rglob("*.csv"))
        if "frames_per_second" not in path.name  # the machine's speed, not the run
    }
    decisions = [
        {k: v for k, v in json.loads(line).items() if k != "time"} for line in run.decisions.read_text().splitlines()
    ]
    return torch.load(run.checkpoint, weights_only=False), metrics, decisions


def test_explicit_cpu_is_the_default_bit_for_bit(tmp_path):
    """``trainer.device=cpu`` and the default (null → the CPU backend's device) train the same run: every
    checkpoint tensor (networks, Adam, environments, scheduler, generators), every metric row and decision.
    (Both also equal the run before ``trainer.device`` existed: compared by hand when it was added.)"""
    train(make_cfg(*SHORT_RUN), tmp_path / "default")
    train(make_cfg(*SHORT_RUN, "trainer.device=cpu"), tmp_path / "cpu")
    default, explicit = run_files(tmp_path / "default"), run_files(tmp_path / "cpu")
    assert differences(default[0], explicit[0]) == []
    assert default[1] == explicit[1] and len(default[1]) > 20
    assert default[2] == explicit[2] and any(d["applied"] for d in default[2])


def test_null_device_is_the_simulations():
    assert resolve_devices(make_cfg("task=point_reach")) == RunDevices(torch.device("cpu"), torch.device("cpu"))
    # a CPU backend keeps its environments on the CPU whatever the learner's device (the collector moves data)
    cfg = make_cfg("task=point_reach", "trainer.device=cuda:1")
    assert resolve_devices(cfg) == RunDevices(torch.device("cuda:1"), torch.device("cpu"))


def test_mjx_environments_follow_the_learner(monkeypatch):
    """For ``task.backend=mjx`` null resolves to JAX's device (faked here as GPU 0) and the environments
    are built on the learner's device: the simulation's state never leaves it."""
    import torchrl_ahrs.envs.registry as registry

    monkeypatch.setattr(registry, "simulation_device", lambda backend: torch.device("cuda:0"))
    monkeypatch.setattr("torchrl_ahrs.app.train.build.simulation_device", registry.simulation_device)
    cuda = torch.device("cuda:0")
    mjx = make_cfg("task=quadcopter", "task.backend=mjx")
    cfg = make_cfg("task=quadcopter", "task.backend=mjx", "trainer.device=cpu")
    assert resolve_devices(cfg) == RunDevices(torch.device("cpu"), torch.device("cpu"))
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)  # JAX on a GPU beside a CPU build of torch
    with pytest.raises(ConfigError, match="torch sees no CUDA device: install torch with CUDA, or set trainer.device"):
        resolve_devices(mjx)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_devices(mjx) == RunDevices(cuda, cuda)
    with pytest.raises(ConfigError, match="needs trainer.collector=sync"):
        resolve_devices(make_cfg("task=quadcopter", "task.backend=mjx", "trainer.collector=multi"))


@pytest.mark.parametrize("task", ["point_reach", "quadcopter"])
def test_networks_are_built_on_the_device(task):
    """Every parameter and buffer of actor and critic (observation normalisers included) and the policy's
    action bounds end up on the device; initialised on the CPU first, so the weights equal the CPU build's."""
    cfg = make_cfg(
        f"task={task}",
        "method=ahrs",
        "model.hidden_sizes=[8,8]",
        "+task.num_threads=1",
        "model.distribution=tanh_normal",
    )  # the squashed policy carries its bounds as tensors
    make_envs = env_factory(cfg, check_aux=False)
    torch.manual_seed(0)
    cpu = build_networks(cfg, make_envs)
    torch.manual_seed(0)
    meta = build_networks(cfg, make_envs, device="meta")
    for module in (meta.actor, meta.critic):
        tensors = [*module.parameters(), *module.buffers()]
        assert tensors and {t.device.type for t in tensors} == {"meta"}
    assert meta.critic_norm.mean.device.type == "meta"
    bounds = meta.actor.module[-1].distribution_kwargs  # TanhNormal's low/high, from the action spec
    assert {bounds["low"].device.type, bounds["high"].device.type} == {"meta"}
    assert meta.actor.spec.device.type == "meta"
    for (name, a), (_, b) in zip(cpu.actor.named_parameters(), meta.actor.named_parameters(), strict=True):
        assert a.shape == b.shape, name
