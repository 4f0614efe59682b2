"""Complete episodes of a policy on a batched env: per-component returns, lengths, task metrics, clips."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase, ExplorationType, set_exploration_type
from torchrl.envs.utils import step_mdp

from torchrl_ahrs.evaluation.render import base_env
from torchrl_ahrs.evaluation.task_metrics import StepProbe
from torchrl_ahrs.rewards.components import episode_return_keys


@dataclass
class EpisodeResults:
    """One entry per episode (M of them).

    Attributes:
        returns: ``{component: [M]}`` undiscounted episode return of each reward leaf (and ``"total"``).
        lengths: ``[M]`` control steps per episode.
        metrics: ``{metric: [M]}`` per-step task metrics averaged over each episode, plus
            ``<metric>_final`` at its last step.
    """

    returns: dict[str, torch.Tensor]
    lengths: torch.Tensor
    metrics: dict[str, torch.Tensor] = field(default_factory=dict)


def exploration_type(deterministic: bool) -> ExplorationType:
    """DETERMINISTIC: the Gaussian's mean (tanh(μ) scaled to the bounds for tanh_normal); RANDOM: a sample."""
    return ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM


@torch.no_grad()
def run_episodes(
    env: EnvBase,
    policy: Callable[[TensorDictBase], TensorDictBase],
    components: Sequence[str],
    deterministic: bool = True,
    probe: StepProbe | None = None,
    max_steps: int = 100_000,
) -> EpisodeResults:
    """Runs each of the env's N parallel environments until its first episode ends.

    Taking the first episode of every env (rather than the first M episodes to finish) keeps short
    episodes from being over-represented.

    Args:
        env: batched env (batch size ``[N]``) from :func:`~torchrl_ahrs.envs.registry.make_env`, tracking
            ``("episode_reward", c)`` for every c in ``components``.
        policy: reads ``"observation"``, writes ``"action"``.
        components: reward leaves to report (include ``"total"``).
        deterministic: mean action (True) or sampled actions.
        probe: per-step task metrics read from the base env (see ``task_metrics``).
        max_steps: safety bound on control steps.

    Returns:
        :class:`EpisodeResults` with M = N episodes.

    Example:
        >>> from torchrl_ahrs.envs.registry import make_env
        >>> from torchrl_ahrs.app.shared.settings import load_task_settings
        >>> env = make_env(load_task_settings("point_reach"), num_envs=2)
        >>> zero = lambda td: td.set("action", torch.zeros(2, 2))
        >>> run_episodes(env, zero, ["distance", "total"]).lengths.tolist()
        [100, 100]
    """
    num_envs = env.batch_size[0]
    inner = base_env(env)
    active = torch.ones(num_envs, dtype=torch.bool)
    lengths = torch.zeros(num_envs, dtype=torch.long)
    returns = {name: torch.zeros(num_envs) for name in components}
    sums: dict[str, torch.Tensor] = {}
    finals: dict[str, torch.Tensor] = {}
    td = env.reset()
    with set_exploration_type(exploration_type(deterministic)):
        for _ in range(max_steps):
            td = env.step(policy(td))
            lengths += active
            if probe is not None:
                for name, value in probe(inner).items():
                    value = value.detach().to("cpu", torch.float64).reshape(num_envs)
                    sums[name] = sums.get(name, torch.zeros(num_envs, dtype=torch.float64)) + value * active
                    finals[name] = torch.where(active, value, finals.get(name, value))
            done = td.get(("next", "done")).reshape(num_envs).cpu()
            finished = done & active
            for name, key in zip(components, episode_return_keys(components), strict=True):
                episode_return = td.get(("next", *key)).reshape(num_envs).cpu()
                returns[name] = torch.where(finished, episode_return, returns[name])
            active &= ~done
            if not active.any():
                break
            td = env.maybe_reset(step_mdp(td))
        else:
            raise RuntimeError(f"{int(active.sum())} episodes did not end within {max_steps} steps")
    metrics = {name: total / lengths for name, total in sums.items()}  # per-episode mean over its steps
    metrics |= {f"{name}_final": value for name, value in finals.items()}
    return EpisodeResults(returns, lengths, metrics)


@torch.no_grad()
def record_frames(
    env: EnvBase,
    policy: Callable[[TensorDictBase], TensorDictBase],
    frame_source: Callable[[], np.ndarray],
    num_frames: int,
    stride: int = 1,
    deterministic: bool = True,
) -> np.ndarray:
    """Frames ``[num_frames, H, W, 3]`` uint8 of the policy acting: the reset state, then every
    ``stride``-th control step. Episodes that end restart (the frame after shows the new episode)."""
    frames = [frame_source()]
    td = env.reset()
    steps = 0
    with set_exploration_type(exploration_type(deterministic)):
        while len(frames) < num_frames:
            _, td = env.step_and_maybe_reset(policy(td))
            steps += 1
            if steps % stride == 0:
                frames.append(frame_source())
    return np.stack(frames)


def summarize(results: EpisodeResults, extra_metrics: dict[str, float] | None = None) -> dict:
    """JSON-ready summary: mean ± std of every return, lengths and metrics, plus the raw episode values of each
    (``per_episode``: which episode fell, and under what, is read there)."""

    def stats(values: torch.Tensor) -> dict[str, float]:
        values = values.double()
        std = values.std(unbiased=False).item() if values.numel() > 1 else 0.0  # population std over episodes
        return {"mean": values.mean().item(), "std": std, "min": values.min().item(), "max": values.max().item()}

    return {
        "episodes": int(results.lengths.numel()),
        "return": {name: stats(values) for name, values in results.returns.items()},
        "episode_length": stats(results.lengths),
        "metrics": {name: stats(values) for name, values in results.metrics.items()} | (extra_metrics or {}),
        "per_episode": {
            "return": {name: values.tolist() for name, values in results.returns.items()},
            "length": results.lengths.tolist(),
            "metrics": {name: values.tolist() for name, values in results.metrics.items()},
        },
    }
