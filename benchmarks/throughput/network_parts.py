"""The network arithmetic of one training iteration as timed closures, shared by bench_floor.py and bench_precision.py.

Both scripts time the same three parts of an iteration's network work on one collected batch; they differ in when
they time them (bench_floor.py: beside each batch of a training run; bench_precision.py: every precision split in
turn each round). The closures are built here once so that both time the work ``training/loop.py`` does, the same
way.

Example (one batch of 2 Ant environments x 8 steps, an [8] network)::

    from hydra import compose, initialize_config_module
    from torchrl_ahrs.app.train.build import build_collector, build_networks, env_factory

    with initialize_config_module("torchrl_ahrs.conf", version_base="1.3"):
        cfg = compose("config", ["task=ant_v5", "trainer.num_envs=2", "trainer.frames_per_batch=16",
                                 "trainer.mini_batch_size=8", "model.hidden_sizes=[8]"])
    make_envs = env_factory(cfg)
    networks = build_networks(cfg, make_envs)
    collector = build_collector(cfg, networks.actor, make_envs)
    batch = next(iter(collector)); collector.shutdown()
    parts = network_parts(cfg, make_envs, networks, batch)
    parts.loss_step()  # one minibatch step; parts.loss_steps_per_batch of them make one batch's epochs
    parts.per_batch()["loss steps"]()  # all of them
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_ahrs.app.shared.config import num_minibatches
from torchrl_ahrs.app.train.build import Networks, build_estimator_and_loss, build_mirror
from torchrl_ahrs.training.loop import minibatch_keys


@dataclass
class NetworkParts:
    """One iteration's network work, each closure one unit of it, and how many units make one collected batch."""

    loss_step: Callable[[], None]  # loss forward, backward, gradient clipping and a fused Adam step on one minibatch
    advantage_pass: Callable[[], None]  # WeightedMultiGAE over the whole batch [N, T], values included
    acting_step: Callable[[], None]  # the actor sampling actions for the batch's N observations
    loss_steps_per_batch: int  # epochs x minibatches
    advantage_passes_per_batch: int  # 1 with ppo.advantage_pass=once_per_batch, else one per epoch
    acting_steps_per_batch: int  # T
    mirrored: bool  # ppo.mirror: each minibatch is followed by its mirror image (twice the rows)

    def per_batch(self) -> dict[str, Callable[[], None]]:
        """Closures doing one collected batch's worth of each part: ``loss steps``, ``advantages``, ``acting``."""

        def repeated(unit: Callable[[], None], count: int) -> Callable[[], None]:
            def run() -> None:
                for _ in range(count):
                    unit()

            return run

        return {
            "loss steps": repeated(self.loss_step, self.loss_steps_per_batch),
            "advantages": repeated(self.advantage_pass, self.advantage_passes_per_batch),
            "acting": repeated(self.acting_step, self.acting_steps_per_batch),
        }


def network_parts(cfg: DictConfig, make_envs, networks: Networks, batch: TensorDictBase) -> NetworkParts:
    """The timed closures of the run ``cfg`` over a collected ``batch`` [N, T], with ``networks`` as built for it.

    The minibatch is the batch's first ``trainer.mini_batch_size`` frames with the keys ``training/loop.py``
    gathers, made once and untimed (mirrored with ``ppo.mirror=true``); the loss's forward goes through
    ``torch.compile`` with ``trainer.compile=true``, as the loop calls it.
    """
    trainer = cfg.trainer
    estimator, loss = build_estimator_and_loss(cfg, networks, make_envs.components)
    with torch.no_grad():
        estimator(batch)  # writes the advantage and value-target keys the loss reads
    keys = minibatch_keys(loss.in_keys)
    minibatch = batch.reshape(-1)[: trainer.mini_batch_size].select(*keys, strict=False)
    augment = build_mirror(cfg, make_envs.task, loss, networks.critic_key)
    if augment is not None:  # the loss trains on the minibatch and its image, as any symmetric PPO does
        minibatch = augment(minibatch)
    optimizer = torch.optim.Adam(loss.parameters(), lr=1e-5, eps=1e-5, fused=True)  # as train() builds it
    loss_forward = torch.compile(loss) if trainer.get("compile", False) else loss
    observations = batch[:, 0].select(*networks.actor.in_keys).clone()

    def loss_step() -> None:
        losses = loss_forward(minibatch)
        sum(value for key, value in losses.items() if key.startswith("loss_")).backward()
        torch.nn.utils.clip_grad_norm_(loss.parameters(), trainer.max_grad_norm)
        optimizer.step()
        optimizer.zero_grad()

    def advantage_pass() -> None:
        with torch.no_grad():
            estimator(batch)

    def acting_step() -> None:
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            networks.actor(observations.clone(False))

    once = cfg.ppo.get("advantage_pass", "every_epoch") == "once_per_batch"
    return NetworkParts(
        loss_step=loss_step,
        advantage_pass=advantage_pass,
        acting_step=acting_step,
        loss_steps_per_batch=trainer.num_epochs * num_minibatches(cfg),
        advantage_passes_per_batch=1 if once else trainer.num_epochs,
        acting_steps_per_batch=batch.shape[-1],
        mirrored=augment is not None,
    )
