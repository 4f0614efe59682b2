"""The training loop's throughput options on real runs (point_reach, MuJoCo): advantages once per batch
(``ppo.advantage_pass``), the loss through ``torch.compile`` (``trainer.compile``), and the one finiteness test per
minibatch that still refuses a non-finite loss whose gradient is finite."""

from __future__ import annotations

import pytest
import torch
from conftest import make_cfg

from torchrl_ahrs.app.shared.errors import ConfigError
from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.app.train.build import build_networks, env_factory
from torchrl_ahrs.app.train.iteration import train
from torchrl_ahrs.app.train.runs import read_scalar
from torchrl_ahrs.envs.backends.mujoco_base import BatchedMujocoEnv
from torchrl_ahrs.training.loss import HybridClipPPOLoss
from torchrl_ahrs.training.run import LoopSettings
from torchrl_ahrs.value import WeightedMultiGAE

FRAMES, ITERATIONS = 64, 3


TINY = [
    "task=point_reach",
    "task.max_episode_steps=6",
    "method=hdppo",
    "trainer.num_envs=8",
    f"trainer.frames_per_batch={FRAMES}",
    "trainer.mini_batch_size=32",
    f"trainer.total_frames={ITERATIONS * FRAMES}",
    "trainer.progress_bar=false",
    "model.hidden_sizes=[16]",
    "scheduler.interval=1",
    "logger.backends=[csv]",
]


def run_once(tmp_path, name, *overrides):
    """Trains TINY + ``overrides`` into ``tmp_path / name``; returns the run directory and its checkpoint."""
    run = RunDirectory(tmp_path / name)
    train(make_cfg(*TINY, *overrides), run.path)
    return run, torch.load(run.checkpoint, weights_only=False)


def train_scalars(run: RunDirectory) -> dict[str, list[float]]:
    """Every ``train/*`` curve of a run (its values, one per iteration)."""
    return {path.stem: read_scalar(path)[1].tolist() for path in sorted((run.scalars / "train").glob("*.csv"))}


def counting_estimates(monkeypatch) -> list[int]:
    """Counts the calls of every WeightedMultiGAE's forward (each call appends the batch's number of frames)."""
    calls: list[int] = []
    forward = WeightedMultiGAE.forward

    def counted(self, tensordict, **kwargs):
        calls.append(tensordict.numel())
        return forward(self, tensordict, **kwargs)

    monkeypatch.setattr(WeightedMultiGAE, "forward", counted)
    return calls


def test_with_one_epoch_both_advantage_passes_give_the_same_run(tmp_path):
    every, every_state = run_once(tmp_path, "every", "trainer.num_epochs=1")
    once, once_state = run_once(tmp_path, "once", "trainer.num_epochs=1", "ppo.advantage_pass=once_per_batch")
    for part in ("actor", "critic", "estimator", "optimizer"):
        assert str(every_state[part]) == str(once_state[part]), part  # bit for bit (str: nested dicts of tensors)
    assert train_scalars(every) == train_scalars(once)


def test_once_per_batch_estimates_once_per_batch_and_its_statistics_absorb_each_batch_once(tmp_path, monkeypatch):
    calls = counting_estimates(monkeypatch)
    _, every_state = run_once(tmp_path, "every", "trainer.num_epochs=3")
    assert calls == [FRAMES] * (3 * ITERATIONS)  # the default: one estimate per epoch
    calls.clear()
    _, once_state = run_once(tmp_path, "once", "trainer.num_epochs=3", "ppo.advantage_pass=once_per_batch")
    assert calls == [FRAMES] * ITERATIONS
    for state in (every_state, once_state):  # the value-target statistics saw every frame exactly once
        counts = state["estimator"]["value_norm.count"]
        assert counts.flatten().tolist() == [float(ITERATIONS * FRAMES)] * counts.numel()
    # with three epochs the two passes train on different advantages after the first: different networks
    actor_every, actor_once = every_state["actor"], once_state["actor"]
    assert any(not torch.equal(actor_every[key], actor_once[key]) for key in actor_every)


def test_an_unknown_advantage_pass_is_refused_in_one_line(tmp_path):
    with pytest.raises(ConfigError, match="ppo.advantage_pass must be one of every_epoch, once_per_batch, got 'twice'"):
        train(make_cfg(*TINY, "ppo.advantage_pass=twice"), tmp_path / "run")
    assert not (tmp_path / "run" / "config.yaml").exists()  # refused before anything was written
    with pytest.raises(ValueError, match="advantage_pass must be one of"):
        LoopSettings(total_frames=64, advantage_pass="per_minibatch")
    with pytest.raises(ConfigError, match="trainer.compile must be true or false"):
        train(make_cfg(*TINY, "trainer.compile=yes"), tmp_path / "run")


def test_collection_threads_step_the_envs_and_the_update_keeps_torch_threads_with_the_same_numbers(
    tmp_path, monkeypatch
):
    """trainer.collection_threads=1 with torch_threads=2: every environment step of the collector sees one torch
    thread, every loss forward two, and the run afterwards is left with two. Oracle: the run with both phases on two
    threads; small networks and elementwise rewards compute the same numbers on one thread, so the two runs are the
    same bit for bit (what lets Cassie's preset take the option without a learning check)."""
    threads_at: dict[str, list[int]] = {"step": [], "loss": []}
    step, forward = BatchedMujocoEnv._step, HybridClipPPOLoss.forward

    def counted_step(self, tensordict):
        threads_at["step"].append(torch.get_num_threads())
        return step(self, tensordict)

    def counted_forward(self, tensordict):
        threads_at["loss"].append(torch.get_num_threads())
        return forward(self, tensordict)

    monkeypatch.setattr(BatchedMujocoEnv, "_step", counted_step)
    monkeypatch.setattr(HybridClipPPOLoss, "forward", counted_forward)
    one, one_state = run_once(tmp_path, "one", "trainer.torch_threads=2", "trainer.collection_threads=1")
    collected_steps = ITERATIONS * FRAMES // 8  # 8 environments; the start-up's reward check stepped before these
    assert threads_at["step"][-collected_steps:] == [1] * collected_steps
    assert set(threads_at["loss"]) == {2}
    assert torch.get_num_threads() == 2
    threads_at["step"].clear()
    two, two_state = run_once(tmp_path, "two", "trainer.torch_threads=2")  # null: the update's threads
    assert set(threads_at["step"]) == {2}
    for part in ("actor", "critic", "estimator", "optimizer"):
        assert str(one_state[part]) == str(two_state[part]), part  # bit for bit (str: nested dicts of tensors)
    assert train_scalars(one) == train_scalars(two)
    with pytest.raises(ConfigError, match="trainer.collection_threads must be a positive integer, got 0"):
        train(make_cfg(*TINY, "trainer.collection_threads=0"), tmp_path / "zero")


def test_a_loss_that_overflows_under_a_finite_gradient_is_refused_naming_it(tmp_path, monkeypatch):
    # ctrl_cost 4e18 without value normalisation: squared errors of ~1e19 targets overflow float32 (the critic loss
    # is inf) while the gradient, linear in the error, stays finite (~8e18): testing the clipped norm alone would
    # let the step through, so the loop tests the loss too
    norms: list[float] = []
    clip = torch.nn.utils.clip_grad_norm_

    def recorded_clip(*args, **kwargs):
        norm = clip(*args, **kwargs)
        norms.append(float(norm))
        return norm

    monkeypatch.setattr(torch.nn.utils, "clip_grad_norm_", recorded_clip)
    cfg = make_cfg(*TINY, "method=ppo", "task.ctrl_cost=4e18", "ppo.value_norm=null", "trainer.num_epochs=2")
    with pytest.raises(FloatingPointError, match=r"non-finite loss at optimiser step 1 in loss_critic \(reward comp"):
        train(cfg, tmp_path / "run")
    assert len(norms) == 1 and torch.isfinite(torch.tensor(norms[0])), norms


@pytest.mark.slow
def test_a_compiled_loss_trains_like_the_eager_one(tmp_path):
    # inductor generates and builds C++ for the loss's forward and backward at the first minibatch (seconds to a
    # minute, then cached); the kernels fuse and reorder float operations, so the runs agree to float tolerance
    from torch._dynamo.utils import counters  # what torch's own tests read to see that dynamo compiled

    eager, eager_state = run_once(tmp_path, "eager", "trainer.num_epochs=2")
    counters.clear()
    compiled, compiled_state = run_once(tmp_path, "compiled", "trainer.num_epochs=2", "trainer.compile=true")
    assert counters["stats"]["unique_graphs"] >= 1  # the loss ran through dynamo, not eagerly
    for part in ("actor", "critic"):
        for key, value in eager_state[part].items():
            torch.testing.assert_close(compiled_state[part][key], value, rtol=1e-4, atol=1e-5, msg=f"{part} {key}")
    eager_curves, compiled_curves = train_scalars(eager), train_scalars(compiled)
    assert eager_curves.keys() == compiled_curves.keys()
    for name, values in eager_curves.items():
        # explained variance divides by the targets' variance over a 32-transition minibatch: looser
        tolerance = 1e-2 if name == "explained_variance" else 1e-4
        torch.testing.assert_close(torch.tensor(compiled_curves[name]), torch.tensor(values), rtol=tolerance, atol=1e-5)


def test_compile_without_a_working_compiler_warns_and_trains_eagerly(tmp_path, monkeypatch, caplog):
    # inductor's C++ compiler made unusable for this test: without the probe the run stopped at its first minibatch
    import torch._dynamo
    import torch._functorch.config as functorch_config
    import torch._inductor.config as inductor_config

    # what an earlier compiled run built (in this process, or in the on-disk caches) would load without a compiler
    torch._dynamo.reset()
    monkeypatch.setattr(inductor_config, "fx_graph_cache", False)
    monkeypatch.setattr(functorch_config, "enable_autograd_cache", False)
    monkeypatch.setattr(inductor_config.cpp, "cxx", ("/nonexistent/g++",))
    eager, eager_state = run_once(tmp_path, "eager")
    with caplog.at_level("WARNING", logger="torchrl_ahrs.train"):
        fallen_back, fallen_back_state = run_once(tmp_path, "compile", "trainer.compile=true")
    (warning,) = [record.getMessage() for record in caplog.records if "trainer.compile" in record.getMessage()]
    assert "InvalidCxxCompiler" in warning and warning.endswith("the loss runs eagerly"), warning
    for part in ("actor", "critic"):  # eagerly means bit for bit the run without the option
        for key, value in eager_state[part].items():
            assert torch.equal(fallen_back_state[part][key], value), f"{part} {key}"


def test_with_kl_adapts_actor_the_kl_rule_sets_the_actors_rate_and_the_critic_keeps_trainer_lr(tmp_path):
    small_target = ("ppo.kl_target=1e-6", "trainer.lr=1e-3")  # every minibatch moves the policy past 2e-6: lr / 1.5
    _, shared = run_once(tmp_path, "all", *small_target)
    (group,) = shared["optimizer"]["param_groups"]  # rsl_rl's rule: one rate for actor and critic
    assert group["lr"] < 1e-3
    _, split = run_once(tmp_path, "actor", *small_target, "ppo.kl_adapts=actor")
    actor, critic = split["optimizer"]["param_groups"]
    assert actor["lr"] < 1e-3 and critic["lr"] == 1e-3 and critic["kl_adaptive"] is False
    critic_tensors = [key for key in split["critic"] if key.endswith(("weight", "bias"))]
    assert len(critic["params"]) == len(critic_tensors) > 0  # the critic's parameters and nothing else
    assert len(actor["params"]) + len(critic["params"]) == len(group["params"])
    with pytest.raises(ConfigError, match="ppo.kl_adapts must be one of all, actor, got 'critic'"):
        train(make_cfg(*TINY, "ppo.kl_adapts=critic"), tmp_path / "refused")


def test_an_unknown_mix_is_refused_in_one_line(tmp_path):
    with pytest.raises(ConfigError, match="ppo.mix must be one of sum, anchored, got 'mean'"):
        train(make_cfg(*TINY, "ppo.mix=mean"), tmp_path / "refused")


def test_a_kl_target_with_every_optimiser_group_flagged_is_refused_in_one_line(tmp_path, monkeypatch):
    # a hand-built optimiser in which no group follows the KL rule would leave the target without effect
    from torchrl_ahrs.app.train import iteration

    build = iteration.build_optimizer

    def all_flagged(*args, **kwargs):
        optimizer = build(*args, **kwargs)
        for group in optimizer.param_groups:
            group["kl_adaptive"] = False
        return optimizer

    monkeypatch.setattr(iteration, "build_optimizer", all_flagged)
    with pytest.raises(ValueError, match="every group is flagged: leave the actor's group unflagged"):
        train(make_cfg(*TINY, "ppo.kl_target=0.01"), tmp_path / "run")


def test_with_ppo_mirror_the_loss_sees_each_minibatch_followed_by_its_mirror_image(tmp_path, monkeypatch):
    """Cassie (a task with a mirror): every loss call gets 2 x the minibatch, its second half the first's image."""
    from torchrl_ahrs.app.shared.settings import task_settings
    from torchrl_ahrs.envs.registry import task_mirror
    from torchrl_ahrs.training.loss import HybridClipPPOLoss

    seen = []
    forward = HybridClipPPOLoss.forward

    def recorded(self, tensordict):
        seen.append(tensordict.select("observation", "action", "advantage").clone())
        return forward(self, tensordict)

    monkeypatch.setattr(HybridClipPPOLoss, "forward", recorded)
    cfg = make_cfg(
        "task=cassie", "method=ppo", "ppo.mirror=true", "trainer.num_envs=4", "trainer.frames_per_batch=32",
        "trainer.mini_batch_size=16", "trainer.num_epochs=2", "trainer.total_frames=64", "model.hidden_sizes=[16]",
        "trainer.progress_bar=false", "logger.backends=[csv]",
    )  # fmt: skip
    train(cfg, tmp_path / "run")
    maps = task_mirror(task_settings(cfg.task))
    assert len(seen) == 2 * 2 * 2  # 2 iterations x 2 epochs x 2 minibatches
    for minibatch in seen:
        first, second = minibatch[:16], minibatch[16:]
        assert minibatch.batch_size == torch.Size([32])
        assert torch.equal(second["observation"], maps["observation"](first["observation"]))
        assert torch.equal(second["action"], maps["action"](first["action"]))
        assert torch.equal(second["advantage"], first["advantage"])


def test_ppo_mirror_on_a_task_without_a_mirror_or_not_a_bool_is_refused_in_one_line(tmp_path):
    with pytest.raises(ConfigError, match="ppo.mirror=true: task 'point_reach' defines no left-right mirror"):
        train(make_cfg(*TINY, "ppo.mirror=true"), tmp_path / "run")
    with pytest.raises(ConfigError, match="ppo.mirror must be true or false, got 'yes'"):
        train(make_cfg(*TINY, "ppo.mirror=yes"), tmp_path / "run2")


@pytest.mark.parametrize("observation_norm", ["running", "none"])
def test_observation_norm_none_keeps_the_normaliser_the_identity_and_running_counts_every_frame(
    tmp_path, observation_norm
):
    """Oracles: ``running`` has merged every collected frame once (FRAMES x ITERATIONS); ``none`` was never
    updated, and the policy rebuilt from its checkpoint returns any observation unchanged, far outside running's
    clip."""
    run, checkpoint = run_once(tmp_path, observation_norm, f"model.observation_norm={observation_norm}")
    cfg = make_cfg(*TINY, f"model.observation_norm={observation_norm}")
    networks = build_networks(cfg, env_factory(cfg), with_critic=False)
    networks.actor.load_state_dict(checkpoint["actor"])
    norm_state = networks.actor_norm.state_dict()
    if observation_norm == "running":
        assert norm_state["count"].item() == FRAMES * ITERATIONS
        assert not torch.equal(norm_state["mean"], torch.zeros_like(norm_state["mean"]))
        return
    assert norm_state["count"].item() == 0
    torch.testing.assert_close(norm_state["mean"], torch.zeros_like(norm_state["mean"]))
    torch.testing.assert_close(norm_state["var"], torch.ones_like(norm_state["var"]))
    far = torch.linspace(-1e3, 1e3, networks.actor_norm.mean.shape[0]).unsqueeze(0)  # [1, obs_dim], |x| up to 1e3
    torch.testing.assert_close(networks.actor_norm(far), far)


def test_an_unknown_observation_norm_is_refused_in_one_line(tmp_path):
    with pytest.raises(ConfigError, match="model.observation_norm must be one of running, none, got 'fixed'"):
        train(make_cfg(*TINY, "model.observation_norm=fixed"), tmp_path / "refused")
    assert not (tmp_path / "refused" / "checkpoint.pt").exists()
