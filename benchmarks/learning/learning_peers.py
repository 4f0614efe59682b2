"""The peers of ``learning.py``, one training run each, started by it as a subprocess::

    python benchmarks/learning/learning_peers.py <torchrl|sb3|rsl_rl> --task <task> --seed <s> --seconds <budget>
        [--frames <cap>] --run-dir <dir> --t0 <epoch seconds at launch> [--torch-threads 1]

A run trains until the wall-clock budget (counted from ``--t0``, the moment ``learning.py`` launched the
process, so start-up counts as it does for ours) or the frame cap, then evaluates its policy with
:func:`evaluate_policy` on our task's environment (for ``ant_v5``: EnvPool's Ant-v5, which steps like
gymnasium's Ant-v5, ``tests/envs/test_envpool.py``) exactly as ``python -m torchrl_ahrs.evaluate`` evaluates
ours: 10 environments seeded 12345, each one's first episode, the policy's mean action. It writes into
``--run-dir``:

* ``curve.csv``: ``wall_s, frames, return, episodes`` once per collected batch (``return``: the mean native
  return of the episodes that ended in that batch, blank when none did; sampled actions);
* ``evaluation.json``: the summary of :func:`torchrl_ahrs.evaluation.episodes.summarize`, as ``evaluate``
  writes it;
* ``worker.json``: frames the evaluated policy was trained on, wall time and reason of the stop, torch
  threads, package versions and the settings used.

The settings, with their sources:

Both ``ant_v5`` peers make gymnasium's ``Ant-v5`` with our preset's observation (no contact forces, 27 entries:
``reference_ppo.ours_gymnasium_kwargs``); a peer env that observes otherwise is refused before it trains.

* ``torchrl`` (gymnasium ``Ant-v5``): TorchRL's ``sota-implementations/ppo`` MuJoCo config, see
  ``reference_ppo.py``; its total-frames horizon (1M, the learning-rate annealing horizon) unless ``--frames``.
* ``sb3`` (gymnasium ``Ant-v5``): rl-baselines3-zoo ``hyperparams/ppo.yml``, entry ``Ant-v4`` (no ``Ant-v5``
  entry; DLR-RM/rl-baselines3-zoo at 208b6fdf): ``normalize: true``, ``n_timesteps: 1e6``, ``policy:
  'MlpPolicy'``, every other value SB3's PPO default (spelled out in :data:`SB3_ZOO_ANT`); the zoo's
  ``n_envs`` default 1 (``rl_zoo3/exp_manager.py``) and ``VecNormalize`` with its default arguments
  (observations and rewards normalised, clipped at 10).
* ``rsl_rl`` (our ``cassie``): rsl-rl-lib's ``OnPolicyRunner`` and PPO with legged_gym's Cassie numbers
  (leggedrobotics/legged_gym at 05481214, ``legged_robot_config.py`` ``LeggedRobotCfgPPO`` and
  ``cassie_config.py`` ``CassieRoughCfgPPO``, :data:`LEGGED_GYM_CASSIE_PPO`) at 64 environments, as our
  ``conf/preset/cassie.yaml`` had them before issue 26 (legged_gym: 4 096; the preset now runs 128 x 12 steps).
  Our ``CassieEnv`` is adapted to rsl_rl's ``VecEnv`` by :class:`rsl_rl_adapter.RslRlVecEnv`.
* ``rsl_rl_mirror`` (our ``cassie``; context, not legged_gym's settings): the same, plus rsl-rl-lib's own symmetry
  data augmentation (``algorithm.symmetry_cfg``, fed our task's mirror maps by :func:`rsl_rl_adapter.mirror_augmentation`)
  and its bfloat16 autocast (``algorithm.use_mixed_precision``): the mirrored minibatch and the precision of our
  Cassie preset, in rsl-rl-lib's loop. It measures how much of the frames-per-second gap to ``rsl_rl`` is that
  arithmetic rather than our pipeline (ours also trains a second critic and re-estimates advantages every epoch).
"""

from __future__ import annotations

import argparse
import csv
import functools
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict
from importlib import metadata
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase

EVAL_EPISODES = 10
EVAL_SEED = 12345  # python -m torchrl_ahrs.evaluate's default seed
DEFAULT_FRAMES = {"torchrl": 1_000_000, "sb3": 1_000_000}  # each peer's own horizon (rsl_rl has none: adaptive lr)

# rl-baselines3-zoo Ant-v4: normalize, 1e6 steps, MlpPolicy; all else SB3 PPO's defaults (stable-baselines3 2.x)
SB3_ZOO_ANT: dict[str, Any] = dict(
    n_steps=2048,
    batch_size=64,
    n_epochs=10,
    learning_rate=3e-4,
    gamma=0.99,
    gae_lambda=0.95,
    clip_range=0.2,
    ent_coef=0.0,
    vf_coef=0.5,
    max_grad_norm=0.5,
)

# legged_gym LeggedRobotCfgPPO (algorithm, policy, runner) with CassieRoughCfgPPO's entropy_coef, in rsl-rl-lib 5.x form
LEGGED_GYM_CASSIE_PPO: dict[str, Any] = {
    "num_envs": 64,  # legged_gym: 4 096; 64 on a 2-core CPU, as our Cassie preset before issue 26
    "num_steps_per_env": 24,
    "save_interval": 50,
    "obs_groups": {"actor": ["policy"], "critic": ["policy"]},
    "algorithm": {
        "class_name": "PPO",
        "value_loss_coef": 1.0,
        "use_clipped_value_loss": True,
        "clip_param": 0.2,
        "entropy_coef": 0.01,
        "num_learning_epochs": 5,
        "num_mini_batches": 4,
        "learning_rate": 1e-3,
        "schedule": "adaptive",
        "gamma": 0.99,
        "lam": 0.95,
        "desired_kl": 0.01,
        "max_grad_norm": 1.0,
    },
    "actor": {
        "class_name": "MLPModel",
        "hidden_dims": [512, 256, 128],
        "activation": "elu",
        "obs_normalization": False,  # legged_gym scales observations in the env, as our CassieEnv does
        "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": 1.0},  # init_noise_std
    },
    "critic": {
        "class_name": "MLPModel",
        "hidden_dims": [512, 256, 128],
        "activation": "elu",
        "obs_normalization": False,
    },
}

Policy = Callable[[TensorDictBase], TensorDictBase]


class Budget:
    """The wall-clock budget of one run, counted from ``t0`` (epoch seconds at process launch), and a frame cap.

    Example:
        >>> budget = Budget(t0=time.time(), seconds=60.0, frames=1000)
        >>> budget.out_of_time(), budget.frames_left(400), budget.frames_left(1000)
        (False, True, False)
    """

    def __init__(self, t0: float, seconds: float, frames: int | None):
        self.t0, self.seconds, self.frames = t0, seconds, frames

    def elapsed(self) -> float:
        return time.time() - self.t0

    def out_of_time(self) -> bool:
        return self.elapsed() >= self.seconds

    def frames_left(self, frames: int) -> bool:
        return self.frames is None or frames < self.frames


class CurveWriter:
    """Appends ``wall_s, frames, return, episodes`` rows to ``path`` (flushed per row: a killed run keeps its curve).

    Example:
        >>> import tempfile
        >>> curve = CurveWriter(Path(tempfile.mkdtemp()) / "curve.csv")
        >>> curve.add(1.5, 2048, [10.0, 20.0]); curve.add(3.0, 4096, [])
        >>> curve.path.read_text().splitlines()
        ['wall_s,frames,return,episodes', '1.500,2048,15.0,2', '3.000,4096,,0']
    """

    def __init__(self, path: Path):
        self.path = path
        self._file = path.open("w", newline="")
        self._writer = csv.writer(self._file)
        self._writer.writerow(["wall_s", "frames", "return", "episodes"])

    def add(self, wall_s: float, frames: int, returns: Sequence[float]) -> None:
        mean = sum(returns) / len(returns) if returns else ""  # mean native return of the episodes that ended
        self._writer.writerow([f"{wall_s:.3f}", int(frames), mean, len(returns)])
        self._file.flush()


def require_our_observation(task: str, size: int) -> None:
    """Refuse, before any training, a peer env whose observation has another size than our ``task`` env's.

    The peer is evaluated on our env (:func:`evaluate_policy`); a mismatch found there would throw the whole
    training budget away.
    """
    from torchrl_ahrs.app.shared.settings import load_task_settings
    from torchrl_ahrs.envs.registry import make_env

    env = make_env(load_task_settings(task), 1, 0)
    ours = env.observation_spec["observation"].shape[-1]
    env.close()
    if size != ours:
        raise SystemExit(
            f"the peer's env observes {size} entries, our {task} env {ours}: they train different problems"
        )


def evaluate_policy(task: str, policy: Policy, episodes: int = EVAL_EPISODES, seed: int = EVAL_SEED) -> dict[str, Any]:
    """``policy`` on our ``task`` env as ``python -m torchrl_ahrs.evaluate`` runs ours: ``episodes`` envs seeded
    ``seed``, each one's first episode, under ``ExplorationType.DETERMINISTIC``; every task component and
    ``total`` reported, with the task's step metrics (Cassie's velocity errors). Returns the JSON summary."""
    from torchrl_ahrs.app.shared.settings import load_task_settings
    from torchrl_ahrs.envs.registry import make_env
    from torchrl_ahrs.evaluation.episodes import run_episodes, summarize
    from torchrl_ahrs.evaluation.task_metrics import episode_metrics, step_probe
    from torchrl_ahrs.rewards.components import TOTAL

    task_cfg = load_task_settings(task)
    components = [c for c in task_cfg.components if c != TOTAL] + [TOTAL]
    env = make_env(task_cfg, episodes, seed, components=components)
    try:
        results = run_episodes(env, policy, components, True, step_probe(task))
    finally:
        env.close()
    summary = {"task": task, "deterministic": True, "seed": seed, "components": components}
    return summary | summarize(results, episode_metrics(results.returns, results.metrics))


# --- TorchRL reference --------------------------------------------------------------------------------


def train_torchrl(task: str, seed: int, budget: Budget, curve: CurveWriter) -> tuple[Policy, dict[str, Any]]:
    """TorchRL's sota MuJoCo PPO on gymnasium Ant-v5; stops before the update of the batch that ends the budget."""
    from reference_ppo import ReferenceConfig, ReferencePPO, ours_gymnasium_kwargs

    if task != "ant_v5":
        raise ValueError(f"the torchrl peer trains gymnasium Ant-v5 (task ant_v5), not {task!r}")
    config = ReferenceConfig(
        total_frames=budget.frames or DEFAULT_FRAMES["torchrl"], env_kwargs=ours_gymnasium_kwargs()
    )
    ppo = ReferencePPO(config, seed)
    require_our_observation(task, ppo.env.observation_spec["observation"].shape[-1])
    trained, reason = 0, "frames"
    for data in ppo.batches():
        done = data.get(("next", "done"))
        curve.add(budget.elapsed(), ppo.collected_frames, data.get(("next", "episode_reward"))[done].tolist())
        if budget.out_of_time():
            reason = "budget"
            break
        trained = ppo.collected_frames  # the loop's next step updates on this batch
    return ppo.evaluation_policy(), {"trained_frames": trained, "stop": reason, "settings": asdict(config)}


# --- stable-baselines3 ---------------------------------------------------------------------------------


def train_sb3(task: str, seed: int, budget: Budget, curve: CurveWriter) -> tuple[Policy, dict[str, Any]]:
    """SB3 PPO with the zoo's Ant settings on gymnasium Ant-v5 (one env, ``VecNormalize``)."""
    import numpy as np
    from reference_ppo import ours_gymnasium_kwargs
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    if task != "ant_v5":
        raise ValueError(f"the sb3 peer trains gymnasium Ant-v5 (task ant_v5), not {task!r}")
    vec_env = make_vec_env("Ant-v5", n_envs=1, seed=seed, env_kwargs=ours_gymnasium_kwargs())
    env = VecNormalize(vec_env)  # Monitor (inside) records raw episode returns
    require_our_observation(task, env.observation_space.shape[-1])
    model = PPO("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **SB3_ZOO_ANT)

    class Recorder(BaseCallback):
        """Curve rows at each rollout's end; stops (returns False) at the first step past the budget."""

        def __init__(self):
            super().__init__()
            self.returns: list[float] = []
            self.collected = self.trained = 0
            self.out_of_time = False

        def _on_rollout_start(self) -> None:
            self.trained = self.collected  # called after train() on the previous rollout

        def _on_step(self) -> bool:
            self.returns += [float(info["episode"]["r"]) for info in self.locals["infos"] if "episode" in info]
            self.out_of_time = budget.out_of_time()
            return not self.out_of_time

        def _on_rollout_end(self) -> None:
            self.collected = self.num_timesteps
            curve.add(budget.elapsed(), self.num_timesteps, self.returns)
            self.returns = []

    recorder = Recorder()
    model.learn(total_timesteps=budget.frames or DEFAULT_FRAMES["sb3"], callback=recorder)
    trained = recorder.trained if recorder.out_of_time else model.num_timesteps

    @torch.no_grad()
    def policy(td: TensorDictBase) -> TensorDictBase:
        obs = env.normalize_obs(td.get("observation").cpu().numpy().astype(np.float64))  # zoo: clip((o − μ)/σ, ±10)
        action, _ = model.predict(obs, deterministic=True)
        return td.set("action", torch.as_tensor(action, dtype=torch.float32))

    settings = {"zoo_entry": "Ant-v4", "n_envs": 1, "normalize": True, **SB3_ZOO_ANT}
    return policy, {
        "trained_frames": trained,
        "stop": "budget" if recorder.out_of_time else "frames",
        "settings": settings,
    }


# --- rsl-rl-lib on our Cassie ----------------------------------------------------------------------------


def train_rsl_rl(
    task: str, seed: int, budget: Budget, curve: CurveWriter, mirrored: bool = False
) -> tuple[Policy, dict[str, Any]]:
    """rsl_rl's OnPolicyRunner with legged_gym's Cassie PPO on our batched task env, one iteration per call;
    ``mirrored``: with rsl-rl-lib's symmetry data augmentation and bfloat16 autocast (the ``rsl_rl_mirror`` peer)."""
    from rsl_rl.runners import OnPolicyRunner
    from rsl_rl_adapter import RslRlVecEnv, StopTraining, mirror_augmentation
    from tensordict import TensorDict

    from torchrl_ahrs.app.shared.settings import load_task_settings
    from torchrl_ahrs.envs.registry import make_env, task_mirror

    torch.manual_seed(seed)
    settings = json.loads(json.dumps(LEGGED_GYM_CASSIE_PPO))  # a deep copy: the runner writes into it
    num_envs, steps = settings.pop("num_envs"), settings["num_steps_per_env"]
    task_settings = load_task_settings(task)
    env = make_env(task_settings, num_envs, seed, components=["total"])
    vec_env = RslRlVecEnv(env, steps, on_rollout=curve.add, clock=budget.elapsed, should_stop=budget.out_of_time)
    runner_settings = json.loads(json.dumps(settings))
    if mirrored:  # rsl-rl-lib's own options; the augmentation is a callable, so it stays out of the JSON copies
        runner_settings["algorithm"]["use_mixed_precision"] = True
        runner_settings["algorithm"]["symmetry_cfg"] = {
            "use_data_augmentation": True,
            "data_augmentation_func": mirror_augmentation(task_mirror(task_settings)),
        }
        settings["algorithm"] |= {"use_mixed_precision": True, "symmetry_cfg": "data augmentation, the task's mirror"}
    runner = OnPolicyRunner(vec_env, runner_settings, log_dir=None, device="cpu")
    iterations, reason = 0, "frames"
    try:
        while budget.frames_left(iterations * num_envs * steps):
            runner.learn(num_learning_iterations=1)  # the runner's own loop, one rollout + update per call
            iterations += 1
    except StopTraining:  # raised by the env step past the budget: the policy is the last update's
        reason = "budget"
    finally:
        env.close()
    actor = runner.get_inference_policy()

    @torch.no_grad()
    def policy(td: TensorDictBase) -> TensorDictBase:
        obs = TensorDict(policy=td.get("observation").to(torch.float32), batch_size=td.batch_size[:1])
        return td.set("action", actor(obs))  # the Gaussian's mean (rsl_rl's deterministic output)

    settings["num_envs"] = num_envs
    return policy, {"trained_frames": iterations * num_envs * steps, "stop": reason, "settings": settings}


PEERS = {
    "torchrl": train_torchrl,
    "sb3": train_sb3,
    "rsl_rl": train_rsl_rl,
    "rsl_rl_mirror": functools.partial(train_rsl_rl, mirrored=True),
}
PACKAGES = {
    "torchrl": ["gymnasium", "mujoco"],
    "sb3": ["stable-baselines3", "gymnasium"],
    "rsl_rl": ["rsl-rl-lib"],
    "rsl_rl_mirror": ["rsl-rl-lib"],
}


def versions(peer: str) -> dict[str, str]:
    """Installed versions of torch, torchrl and the peer's packages."""
    names = ["torch", "torchrl", *PACKAGES[peer]]
    return {name: metadata.version(name) for name in names}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("peer", choices=sorted(PEERS))
    parser.add_argument("--task", required=True)
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--seconds", type=float, required=True, help="wall-clock budget from --t0")
    parser.add_argument("--frames", type=int, default=None, help="frame cap (default: the peer's own horizon)")
    parser.add_argument("--run-dir", type=Path, required=True)
    parser.add_argument("--t0", type=float, default=None, help="epoch seconds at launch (default: now)")
    parser.add_argument("--torch-threads", type=int, default=1, help="torch intra-op threads (ours' default: 1)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.torch_threads)
    budget = Budget(args.t0 if args.t0 is not None else time.time(), args.seconds, args.frames)
    args.run_dir.mkdir(parents=True, exist_ok=True)
    curve = CurveWriter(args.run_dir / "curve.csv")
    policy, info = PEERS[args.peer](args.task, args.seed, budget, curve)
    info |= {"peer": args.peer, "seed": args.seed, "wall_s": budget.elapsed(), "torch_threads": torch.get_num_threads()}
    info["versions"] = versions(args.peer)
    (args.run_dir / "worker.json").write_text(json.dumps(info, indent=2) + "\n")
    evaluation = evaluate_policy(args.task, policy)
    (args.run_dir / "evaluation.json").write_text(json.dumps(evaluation, indent=2) + "\n")
    total = evaluation["return"]["total"]
    print(f"{args.peer} seed {args.seed}: evaluated return {total['mean']:.1f} ± {total['std']:.1f}")
    if not math.isfinite(total["mean"]):
        raise SystemExit(1)


if __name__ == "__main__":
    main()
