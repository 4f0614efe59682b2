"""MJX backend (``task.backend=mjx``) against the threaded MuJoCo backend on CPU-JAX at N = 2.

Parity tolerance. Both backends run the same MJCF with the same solver (Newton, 100 iterations) and the
same contacts; the differences are MJX's float32 arithmetic (MuJoCo C is float64) and its own collision
and solver code. Measured over 6 control steps (Nov 30, float32): observations differ by ≤ 8e-6, reward
components by ≤ 3e-7 (they are scaled by dt or bounded kernels), contact flags and done flags not at all.
The tolerances below are about 10× those figures — tight enough that one differing action (the negative
control) or one missing substep fails them, loose enough for float32 rounding growing through contacts.

JAX compiles each task's step once per process (30-50 s per task on a loaded 2-core CPU); the persistent
compilation cache (``$JAX_COMPILATION_CACHE_DIR``, default a directory under the system temp dir) makes
later runs load them in a few seconds.
"""

from __future__ import annotations

import os
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")

import pytest  # noqa: E402
import torch  # noqa: E402
from tensordict import TensorDict  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

from torchrl_ahrs.app.shared.settings import load_task_settings  # noqa: E402
from torchrl_ahrs.envs.backends import mjx as mjx_backend  # noqa: E402
from torchrl_ahrs.envs.registry import get_builder, make_env  # noqa: E402

needs_jax = pytest.mark.skipif(
    not mjx_backend.mjx_available(), reason='JAX / mujoco-mjx absent: pip install -e ".[mjx]" runs these tests'
)
OBS_ATOL = 1e-4  # float32 rounding of O(1) observations grown over 6 contact-rich steps (measured 8e-6)
REWARD_ATOL = 3e-6  # components are dt-scaled or bounded kernels (measured 3e-7)
STEPS = 6


@pytest.fixture(scope="module", autouse=True)
def compilation_cache():
    """JAX's persistent compilation cache, so a second run skips the 30-50 s compiles."""
    if not mjx_backend.mjx_available():
        yield
        return
    import jax

    path = os.environ.get("JAX_COMPILATION_CACHE_DIR", os.path.join(tempfile.gettempdir(), "torchrl_ahrs_jax_cache"))
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    yield


def test_missing_jax_names_the_extra(monkeypatch):
    monkeypatch.setattr(mjx_backend, "mjx_available", lambda: False)
    with pytest.raises(ImportError, match=r"torchrl-ahrs\[mjx\]"):
        make_env(load_task_settings("quadcopter", ["task.backend=mjx"]), num_envs=2)


def test_backend_selection_is_checked():
    with pytest.raises(KeyError, match="no MJX|available mjx tasks"):
        get_builder("point_reach", "mjx")
    with pytest.raises(KeyError, match="unknown backend"):
        get_builder("ant", "warp")
    assert get_builder("ant", "cpu") is not get_builder("ant", "mjx")


def _pair(task: str, num_envs: int = 2, seed: int = 3):
    cpu = make_env(load_task_settings(task, ["task.num_threads=1"]), num_envs, seed=seed)
    mjx = make_env(load_task_settings(task, ["task.backend=mjx"]), num_envs, seed=seed)
    return cpu, mjx


def _assert_close(mjx_td, cpu_td, components, what):
    torch.testing.assert_close(mjx_td["observation"], cpu_td["observation"], atol=OBS_ATOL, rtol=0, msg=what)
    for c in components:
        for group in ("reward", "episode_reward"):
            torch.testing.assert_close(
                mjx_td[group, c], cpu_td[group, c], atol=REWARD_ATOL * (STEPS if group != "reward" else 1), rtol=0
            )
    assert torch.equal(mjx_td["done"], cpu_td["done"]), what


@needs_jax
@pytest.mark.parametrize("task", ["quadcopter", "ant", "cassie"])
def test_parity_with_cpu_backend(task):
    cpu, mjx = _pair(task)
    components = [*load_task_settings(task).components, "total"]
    assert type(mjx.base_env).__name__.endswith("MjxEnv")
    assert mjx.full_reward_spec == cpu.full_reward_spec and mjx.observation_spec == cpu.observation_spec
    generator = torch.Generator().manual_seed(0)
    actions = torch.rand(STEPS + 1, 2, cpu.action_spec.shape[-1], generator=generator) * 2 - 1
    td_cpu, td_mjx = cpu.reset(), mjx.reset()
    torch.testing.assert_close(td_mjx["observation"], td_cpu["observation"], atol=1e-6, rtol=0)  # same reset draw
    for t in range(STEPS):
        out_cpu, td_cpu = cpu.step_and_maybe_reset(td_cpu.set("action", actions[t]))
        out_mjx, td_mjx = mjx.step_and_maybe_reset(td_mjx.set("action", actions[t]))
        _assert_close(out_mjx["next"], out_cpu["next"], components, f"{task} step {t}")
    # negative control: one different action must break the tolerance, or the comparison above proves nothing
    out_cpu = cpu.step(td_cpu.set("action", actions[STEPS]))
    out_mjx = mjx.step(td_mjx.set("action", -actions[STEPS]))
    with pytest.raises(AssertionError):
        _assert_close(out_mjx["next"], out_cpu["next"], components, "negative control")
    check_env_specs(mjx)


@needs_jax
def test_partial_reset_touches_only_masked_envs():
    cpu, mjx = _pair("quadcopter")
    for env in (cpu, mjx):
        env.reset()
        env.rand_step()
    before = mjx.base_env.qpos.clone()
    mask = TensorDict({"_reset": torch.tensor([[True], [False]])}, batch_size=[2])
    obs_mjx, obs_cpu = mjx.reset(mask.clone())["observation"], cpu.reset(mask.clone())["observation"]
    after = mjx.base_env.qpos
    assert torch.equal(after[1], before[1])  # the unmasked env keeps its state exactly
    assert not torch.equal(after[0], before[0])
    torch.testing.assert_close(obs_mjx[0], obs_cpu[0], atol=1e-6, rtol=0)  # the same reset draw as the CPU backend
    assert mjx.base_env.episode_steps.tolist() == [0, 1]


# ---------------------------------------------------------------- devices (issue 16, item 5)
@needs_jax
@pytest.mark.parametrize("task", ["quadcopter", "ant", "cassie"])
def test_a_control_step_keeps_every_tensor_on_the_env_device(task):
    """The whole ``_step`` (the task's hooks, the base's bookkeeping, the output tensordict) on a device
    without host memory. torch's ``meta`` device holds shapes and no data, so on it every host copy
    (``.cpu()``, ``.numpy()``, ``.item()``, ``bool(tensor)``), every data-dependent sync (``nonzero``) and
    every tensor left on the CPU raises — what would cost a copy or a sync per step on a GPU. The physics
    runs for real (CPU-JAX); only ctrl's export to JAX is replaced by zeros of its shape, because a meta
    tensor has no memory for DLPack to share. (TorchRL's specs cannot live on ``meta``, so the env's device
    is switched without them: what ``env.to(device)`` does to the hooks' state.)"""
    import jax.numpy as jnp

    env = make_env(load_task_settings(task, ["task.backend=mjx"]), 2, seed=3)
    env.reset()
    base = env.base_env
    base.__dict__["_device"] = torch.device("meta")
    base._move_tensors()
    base._publish(base.data)
    exported = []

    def to_jax(tensor):
        exported.append((tensor.device.type, tuple(tensor.shape)))
        return jnp.zeros(tuple(tensor.shape), jnp.float32)

    base._to_jax = to_jax
    time_before = float(base.data.time[0])
    out = base._step(TensorDict({"action": torch.zeros(2, base.action_dim, device="meta")}, [2]))
    assert {leaf.device.type for leaf in out.values(True, True)} == {"meta"}
    assert exported == [("meta", (2, base.model.nu))]  # ctrl crossed to JAX once, from the env's device
    assert float(base.data.time[0]) > time_before  # and the physics stepped


@needs_jax
def test_a_control_step_sends_nothing_from_the_host_to_jax():
    """JAX's transfer guard refuses every host-to-device transfer (numpy arrays and Python numbers
    entering JAX) during a step; ctrl reaches JAX through DLPack, which the guard allows. Negative control:
    the backend's former export (``jnp.asarray`` of a numpy ctrl) trips it. On a CPU-only machine the guard
    cannot see device-to-host reads; the meta-device test above covers the torch side of those."""
    import jax
    import jax.numpy as jnp

    env = make_env(load_task_settings("quadcopter", ["task.backend=mjx"]), 2, seed=3)
    td = env.reset().set("action", torch.zeros(2, 4))
    with jax.transfer_guard("disallow_explicit"):
        env.step(td)
    base = env.base_env
    base._to_jax = lambda tensor: jnp.asarray(tensor.numpy(), jnp.float32)  # through a host array
    with pytest.raises(Exception, match="Disallowed host-to-device transfer"), jax.transfer_guard("disallow_explicit"):
        env.step(td)


@needs_jax
def test_a_loaded_twin_continues_an_mjx_episode_exactly():
    """The MJX env's snapshot (every leaf of the batched mjx.Data, counters, generator, task state) is a
    complete one: a twin built with another seed and loaded continues bit for bit."""
    cfg = load_task_settings("quadcopter", ["task.backend=mjx"])
    env = make_env(cfg, 2, seed=3)
    actions = torch.rand(6, 2, 4, generator=torch.Generator().manual_seed(0)) * 2 - 1
    td = env.reset()
    for action in actions[:3]:
        _, td = env.step_and_maybe_reset(td.set("action", action))
    snapshot, carried = env.state_dict(), td.clone()
    twin = make_env(cfg, 2, seed=99)
    twin.reset()
    twin.load_state_dict(snapshot)
    for action in actions[3:]:
        out, td = env.step_and_maybe_reset(td.set("action", action))
        out_twin, carried = twin.step_and_maybe_reset(carried.set("action", action))
        assert (out["next"].exclude("episode_reward") == out_twin["next"].exclude("episode_reward")).all()


def test_jax_devices_map_to_torch_devices():
    from types import SimpleNamespace

    assert mjx_backend.torch_device_of(SimpleNamespace(platform="cpu", id=0)) == torch.device("cpu")
    gpu = SimpleNamespace(platform="gpu", id=3, local_hardware_id=1)  # torch counts CUDA ordinals, as local ids
    assert mjx_backend.torch_device_of(gpu) == torch.device("cuda", 1)
    with pytest.raises(ValueError, match="torch has no device"):
        mjx_backend.torch_device_of(SimpleNamespace(platform="tpu", id=0))
