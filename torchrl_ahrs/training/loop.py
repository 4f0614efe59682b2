"""One iteration of hybrid-reward PPO, written as one function a reader scrolls through: :func:`learn`.

In the order it runs (the section comments in :func:`learn` carry these numbers)::

    1. collect       the Collector steps N envs x T steps with the current policy              -> batch [N, T]
                     (on LoopSettings.collection_threads torch threads; the update gets its own back)
                     (the env's RewardComponents wrote ("next", "reward", c), c = 1..K); FiniteGuard stops on NaN
    2. returns       reward/<c> (mean per step), return/<c> (episodes that ended), the scheduler's statistics
    3. PPO epochs    per epoch (advantage_pass="every_epoch"; "once_per_batch": before the first epoch only):
                     advantages (WeightedMultiGAE with the current critic), value targets standardised
                     -> minibatches -> HybridClipPPOLoss -> KL and learning rate -> Adam step, gradient clipped
    4. normalisers   the observation statistics absorb the batch just trained on; the learning rate anneals;
                     the collector gets the new policy
    5. schedule      RuleScheduler.step: every `interval` iterations statistics -> rule -> w_k in the estimator
    6. log           every scalar of the iteration once, at step = frames collected
    7. after         the app's after-iteration callables, in order: console line, video clip, and last the
                     checkpoint of the run's state registry (every `interval` iterations and after the last)

Below :func:`learn`, in the order it calls them, the helpers only it uses: :class:`FiniteGuard` (1),
:func:`total_explained_variance`, :func:`epoch_minibatches`, :func:`adaptive_kl_lr`, :func:`check_finite_update`
and :func:`epoch_means` (3).

The parts (:class:`~torchrl_ahrs.training.run.TrainingRun`) are built by :mod:`torchrl_ahrs.app.train.iteration`
from the Hydra config, or by hand; this module never reads configuration. The loop is TorchRL's pieces composed
as TorchRL's ``sota-implementations/ppo`` scripts compose them: a ``Collector``, a loss module, a value
estimator, ``torch.optim`` and a TorchRL ``Logger``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torch import nn

from torchrl_ahrs.rewards.auxiliary import AuxiliaryRewardError
from torchrl_ahrs.rewards.components import TOTAL, finished_episode_returns
from torchrl_ahrs.training.run import TrainingRun

# what the loss (and the KL between the collecting and the current policy) reads from a minibatch, besides
# the loss's own in_keys; the batch also holds "next", episode accumulators... that are never gathered
MINIBATCH_KEYS = ("advantage", "value_target", "state_value", "loc", "scale")


def minibatch_keys(loss_in_keys: Iterable[NestedKey]) -> list[NestedKey]:
    """What a PPO minibatch gathers: the loss's ``in_keys`` but those under ``"next"``, and :data:`MINIBATCH_KEYS`.
    (TorchRL's PPO losses list the next step's reward, done and observation for an advantage they would estimate
    themselves; the estimator wrote it before the epoch, so gathering them, 16 tensors on Cassie, is wasted.)

    Example:
        >>> minibatch_keys(["action", ("next", "reward"), "observation"])[:3]
        ['action', 'observation', 'advantage']
    """
    return [key for key in loss_in_keys if not (isinstance(key, tuple) and key[0] == "next")] + list(MINIBATCH_KEYS)


def learn(run: TrainingRun) -> dict[str, float]:
    """Trains until ``run.settings.total_frames`` frames are collected; returns the latest value of every
    scalar logged (``reward/<c>``, ``return/<c>``, ``weight/<c>``, ``share/<c>``, ``train/<loss term>``, ...)."""
    settings, progress, optimizer, estimator = run.settings, run.progress, run.optimizer, run.estimator
    components = list(estimator.components)
    tracked = components + ([TOTAL] if TOTAL not in components else [])
    keys = minibatch_keys(run.loss.in_keys)
    scale_key = getattr(run.loss.tensor_keys, "scale", "scale")  # where the collecting policy wrote its Gaussian's σ
    params = [param for group in optimizer.param_groups for param in group["params"]]
    max_norm = math.inf if settings.max_grad_norm is None else settings.max_grad_norm
    for group in optimizer.param_groups:  # lr_0 of the anneal, saved with the optimiser (torch's schedulers' key)
        group.setdefault("initial_lr", group["lr"])
    adapted = [group for group in optimizer.param_groups if group.get("kl_adaptive", True)]  # the KL rule's groups
    if settings.kl_target is not None and not getattr(run.loss, "kl", False):
        raise ValueError("LoopSettings.kl_target reads the loss's 'kl' output: build HybridClipPPOLoss(..., kl=True)")
    if settings.kl_target is not None and not adapted:
        raise ValueError(
            "LoopSettings.kl_target adapts the rate of the optimiser's groups not flagged kl_adaptive=False, and "
            "every group is flagged: leave the actor's group unflagged"
        )
    guard = FiniteGuard(components)
    # the loss's forward through inductor (actor, critic and the PPO terms, and so their backward); the module
    # itself stays the one the optimiser, the checkpoint and the collector know
    loss_forward = torch.compile(run.loss) if settings.compile else run.loss
    latest: dict[str, float] = {}
    # torch's threads: the update's as set by the caller; while the collector steps, collection_threads. A CPU
    # simulation steps on threads of its own, and every small exp or tanh of the rewards and the policy's sampling
    # wakes a sleeping second torch thread, which costs more than it computes (RESULTS, session 38)
    update_threads = torch.get_num_threads()
    collection_threads = settings.collection_threads or update_threads
    last_time = time.perf_counter()
    try:
        torch.set_num_threads(collection_threads)
        for batch in run.collector:
            # ---- 1. collect: batch [N, T], N envs x T steps of the current policy ---------------------------
            torch.set_num_threads(update_threads)  # collected: the update's threads until the next collection
            guard(batch)  # one NaN reward would poison every advantage through the GAE recursion
            progress.collected_frames += batch.numel()
            frames = progress.collected_frames

            # ---- 2. episode and component returns -----------------------------------------------------------
            metrics = {f"reward/{name}": batch.get(("next", "reward", name)).mean().item() for name in tracked}
            returns = finished_episode_returns(batch, tracked)  # [M, K+1]: the M episodes that ended in the batch
            if returns.shape[0]:
                metrics["episodes"] = float(returns.shape[0])
                metrics.update({f"return/{c}": r for c, r in zip(tracked, returns.mean(0).tolist(), strict=True)})
            metrics.update(run.scheduler.observe_batch(batch))  # into its statistics; weight/<c> in force
            if scale_key in batch.keys(include_nested=True):  # logged whatever the entropy coefficient (0: no entropy)
                metrics["train/noise_std"] = batch.get(scale_key).mean().item()  # mean σ before any squash, as rsl_rl

            # ---- 3. PPO epochs ------------------------------------------------------------------------------
            last_epoch_losses: list[TensorDictBase] = []  # train/<term> is the last epoch's mean over its minibatches
            for epoch in range(settings.num_epochs):
                if epoch == 0 or settings.advantage_pass == "every_epoch":  # once_per_batch: epoch 0's serve all
                    with torch.no_grad():
                        # advantages with the current critic: A_k, value_target [N, T, K], advantage = Σ_k w_k A_k
                        estimator(batch)
                        selected = batch.select(*keys, strict=False)  # shares the tensors; the sets stay out of batch
                        if epoch == 0:  # the collecting critic's Σ_k V_k (anchored: V_Σ) against the total
                            targets, values = batch.get("value_target"), batch.get("state_value")
                            if getattr(estimator, "anchored", False):  # the anchor's column is the total's
                                targets, values = targets[..., -1:], values[..., -1:]
                            metrics["train/explained_variance_total"] = total_explained_variance(targets, values)
                        if run.value_norm is not None:  # the loss regresses standardised targets; GAE read reward units
                            targets = selected.get("value_target")
                            if epoch == 0:  # the statistics absorb each batch once, before it is normalised with them
                                run.value_norm.update(targets)
                            selected.set("value_target", run.value_norm.normalize(targets))  # (x - mu_k) / sigma_k
                            selected.set("state_value", run.value_norm.normalize(selected.get("state_value")))
                logged = epoch == settings.num_epochs - 1
                # ppo.mirror: each minibatch followed by its mirror image (same advantages and targets)
                for minibatch in epoch_minibatches(selected, settings.num_minibatches, run.generator, run.augment):
                    progress.optim_steps += 1
                    losses = loss_forward(minibatch)
                    # KL and learning rate: with a KL target, this step's rate follows this minibatch's KL from the
                    # collecting to the current policy
                    # (rsl_rl's adaptive rule) in every parameter group not flagged kl_adaptive=False
                    if settings.kl_target is not None:
                        lr = adaptive_kl_lr(adapted[0]["lr"], losses.get("kl").item(), settings.kl_target)
                        for group in adapted:
                            group["lr"] = lr
                        if logged:
                            losses.set("lr", torch.tensor(lr))
                    # step: the sum of the loss_* terms, the gradient's global norm clipped to max_grad_norm; a
                    # non-finite loss or gradient stops the run before the step could write NaN into the networks.
                    # One test covers both (a sum of finite numbers is finite unless it overflows: then the
                    # function finds both finite and the step goes on); the loss is tested apart because a
                    # finite gradient does not make it finite (an inf squared error has a finite slope)
                    total = sum(value for key, value in losses.items() if key.startswith("loss_"))
                    total.backward()
                    grad_norm = nn.utils.clip_grad_norm_(params, max_norm)  # computed without grad
                    if not bool(torch.isfinite(total.detach() + grad_norm)):
                        check_finite_update(total, losses, minibatch, components, progress.optim_steps)
                        check_finite_update(grad_norm, losses, minibatch, components, progress.optim_steps, "gradient")
                    optimizer.step()
                    optimizer.zero_grad()
                    if logged:
                        losses.set("grad_norm", grad_norm)
                        last_epoch_losses.append(losses)
            # train/<term>: the last epoch's mean (as TorchRL's Trainer, which ran this loop before, averaged; so
            # earlier runs' numbers compare), computed once instead of a TensorDict running mean per minibatch
            metrics.update(epoch_means(last_epoch_losses))
            shares = estimator.shares.tolist()  # |c_j| std(A'_j) / Σ_i |c_i| std(A'_i) of the last epoch's advantages
            columns = getattr(estimator, "columns", components)  # the components, then the anchor when anchored
            metrics.update({f"share/{name}": share for name, share in zip(columns, shares, strict=True)})

            # ---- 4. after the update: observation statistics, learning rate, policy weights -----------------
            # only now, so the log-probabilities stored at collection stay those of the policy being optimised
            for norm, key in run.observation_norms:
                norm.update(batch.get(key))
            metrics["train/learning_rate"] = optimizer.param_groups[0]["lr"]  # the last step's (the anneal follows)
            if settings.anneal_lr and settings.kl_target is None:
                fraction = min(1.0, frames / settings.total_frames)
                for group in optimizer.param_groups:
                    group["lr"] = group["initial_lr"] * (1.0 - fraction)  # lr_i = lr_0 (1 - f_i / F)
            run.collector.update_policy_weights_()  # workers get the new policy (a sync collector shares it)

            # ---- 5. schedule: every `interval` iterations, statistics -> rule -> w_k ---------------------------
            run.scheduler.step()

            # ---- 6. log -----------------------------------------------------------------------------------------
            now = time.perf_counter()
            metrics["frames_per_second"] = batch.numel() / max(now - last_time, 1e-9)  # the whole iteration's rate
            last_time = now
            for name, value in metrics.items():
                run.logger.log_scalar(name, value, step=frames)
            latest.update(metrics)

            # ---- 7. after the iteration: console line, video clip, checkpoint (last: it holds the state the next
            # iteration starts from); the table's weights and shares are this iteration's, from one update ------
            for after in run.after_iteration:
                after(batch, metrics)
            if frames >= settings.total_frames:
                break
            torch.set_num_threads(collection_threads)  # the next collection
        run.scheduler.close()  # waits for (and applies) a decision still being made in the background
    except AuxiliaryRewardError:
        # the file's failure ends the run; what was learnt so far is kept: the state the failed iteration began
        # with (a resumed run, after the file is fixed, starts there)
        if run.after_failure is not None:
            run.after_failure()
        raise
    finally:
        torch.set_num_threads(update_threads)
        run.collector.shutdown()
    return latest


class FiniteGuard:
    """Stops training with a clear error when a batch carries NaN or inf in observations or rewards.

    A single non-finite reward poisons every advantage through the GAE recursion and the running
    observation statistics forever after, so the run is stopped at the first bad batch, naming the
    entry and how many values were bad, instead of training on garbage.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> guard = FiniteGuard(["a"])
        >>> batch = TensorDict({"observation": torch.zeros(2, 3),
        ...                     "next": {"reward": {"a": torch.tensor([[1.0], [float("nan")]])}}}, [2])
        >>> guard(batch)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        FloatingPointError: 1 non-finite value(s) in ('next', 'reward', 'a') of the collected batch; ...
    """

    def __init__(self, components: Iterable[str], observation_key: str = "observation"):
        self.keys = [observation_key, ("next", observation_key)] + [("next", "reward", name) for name in components]

    def __call__(self, batch: TensorDictBase) -> TensorDictBase:
        for key in self.keys:
            values = batch.get(key, None)
            if values is None:
                continue
            bad = (~torch.isfinite(values)).sum().item()
            if bad:
                raise FloatingPointError(
                    f"{bad} non-finite value(s) in {key} of the collected batch; the environment produced NaN/inf "
                    "(check the task's reward terms and physics stability); training stopped before using it"
                )
        return batch


def total_explained_variance(value_target: torch.Tensor, state_value: torch.Tensor) -> float:
    """How much of the total λ-return's variance the critic's summed heads explain: ``[*B, K], [*B, K] -> float``.

    The mixed advantage of equal weights reads ``V = Σ_k V_k``, so this is the number to compare with PPO's
    one head; TorchRL's ``explained_variance`` pools the K heads (in normalised units under ``ppo.value_norm``).

    Example:
        >>> targets = torch.tensor([[1.0, 0.0], [0.0, 1.0], [2.0, 2.0]])
        >>> total_explained_variance(targets, targets.flip(-1))  # each head wrong, the sums right
        1.0
    """
    total = value_target.sum(-1).flatten()  # R = Σ_k R_k
    error = total - state_value.sum(-1).flatten()  # R - Σ_k V_k
    return float(1.0 - error.var() / total.var().clamp_min(1e-12))  # 1 - Var(R - V) / Var(R)


def epoch_minibatches(
    batch: TensorDictBase,
    num_minibatches: int,
    generator: torch.Generator,
    augment: Callable[[TensorDictBase], TensorDictBase] | None = None,
) -> list[TensorDictBase]:
    """One PPO epoch's minibatches of ``batch [*B]``: every transition exactly once, in a fresh random order
    (sampling without replacement), as ``num_minibatches`` contiguous views of one gather (a gather per
    minibatch would cost a TensorDict index per key).

    ``augment`` (``ppo.mirror``'s :class:`~torchrl_ahrs.envs.common.mirror.MirrorAugmentation`, ``[n] -> [2n]``,
    the rows then their images) makes each minibatch ``[2b]``, its rows then their images: ``augment(minibatch)``
    bit for bit (the image is row-wise), from one mirror and one gather per epoch.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> batch = TensorDict({"x": torch.arange(16.0).reshape(2, 8)}, [2, 8])
        >>> minibatches = epoch_minibatches(batch, 4, torch.Generator().manual_seed(0))
        >>> [len(mb) for mb in minibatches], sorted(torch.cat([mb["x"] for mb in minibatches]).tolist()) == list(range(16))
        ([4, 4, 4, 4], True)
        >>> negated = lambda td: torch.cat([td, td.apply(torch.neg)], 0)  # a stand-in image: -x
        >>> doubled = epoch_minibatches(batch, 4, torch.Generator().manual_seed(0), negated)
        >>> [len(mb) for mb in doubled], bool((doubled[0]["x"][4:] == -minibatches[0]["x"]).all())
        ([8, 8, 8, 8], True)
    """
    flat = batch.reshape(-1)
    size = flat.shape[0]
    order = torch.randperm(size, generator=generator, device=generator.device)
    chunks = order.chunk(num_minibatches)
    sizes = [len(chunk) for chunk in chunks]
    if augment is not None:
        flat = augment(flat)  # [2n]: row i's image is row n + i
        order = torch.cat([torch.cat([chunk, chunk + size]) for chunk in chunks])  # each chunk, then its images
        sizes = [2 * chunk_size for chunk_size in sizes]
    # served last first: the order of the Trainer hook this loop replaced, so seeded runs keep their numbers
    return list(flat[order].split(sizes, 0))[::-1]


def adaptive_kl_lr(
    lr: float, kl: float, target: float, min_lr: float = 1e-5, max_lr: float = 1e-2, factor: float = 1.5
) -> float:
    """The learning rate after a minibatch whose KL from the collecting policy is ``kl`` (rsl_rl's and rl_games' rule)::

        KL = E_s[ KL( N(mu_old, sigma_old) || N(mu_new, sigma_new) ) ]      (summed over action dims)
        KL > 2 * target   ->  lr <- max(lr / 1.5, min_lr)
        KL < target / 2   ->  lr <- min(lr * 1.5, max_lr)

    The factors 2, 1/2 and 1.5 are those of rsl_rl's ``PPO.update`` (``schedule="adaptive"``,
    ``desired_kl=0.01``, lr bounded to [1e-5, 1e-2]) and rl_games' ``AdaptiveScheduler``
    (``kl_threshold``: 0.008 in its ``mujoco/ant_envpool.yaml``, bounds [1e-6, 1e-2]). The KL is the ``"kl"``
    output of :class:`~torchrl_ahrs.training.loss.HybridClipPPOLoss` built with ``kl=True``: the closed form
    between the Gaussians *before* the tanh squash, as rsl_rl reads it from its loss forward pass (KL is
    invariant under a bijection applied to both distributions, so it equals the KL of the squashed policies).

    Example:
        >>> adaptive_kl_lr(1e-3, kl=0.001, target=0.01)  # barely moved: x 1.5
        0.0015
        >>> adaptive_kl_lr(9e-3, kl=0.0, target=0.01)  # bounded by max_lr
        0.01
    """
    if target <= 0:
        raise ValueError(f"the KL target must be positive, got {target}")
    if kl > 2.0 * target:
        return max(lr / factor, min_lr)  # too far from the collecting policy: smaller steps
    if kl < 0.5 * target:
        return min(lr * factor, max_lr)  # barely moved: larger steps
    return lr


def check_finite_update(
    value: torch.Tensor,
    losses: TensorDictBase,
    minibatch: TensorDictBase,
    components: Sequence[str],
    optim_step: int,
    what: str = "loss",
) -> None:
    """Raises ``FloatingPointError`` (one line naming the loss terms and the reward components to blame) when
    ``value`` (the summed loss, or the gradient's global norm) is not finite.

    A finite but huge reward (an auxiliary reward of 1e30) passes every check of the batch and still turns the
    critic's loss into NaN; the line names each component whose value targets are non-finite or beyond 1e15.

    Example:
        >>> from tensordict import TensorDict
        >>> losses = TensorDict({"loss_critic": torch.tensor(float("nan")), "loss_objective": torch.tensor(0.1)})
        >>> minibatch = TensorDict({"value_target": torch.tensor([[1.0, 1e30]])}, [1])
        >>> check_finite_update(losses["loss_critic"], losses, minibatch, ["pos", "aux"], 7)
        Traceback (most recent call last):
        ...
        FloatingPointError: non-finite loss at optimiser step 7 in loss_critic (reward component 'aux': value targets up to 1e+30); update not applied, training stopped
    """
    if bool(torch.isfinite(value).all()):
        return
    terms = [key for key, term in losses.items() if key.startswith("loss_") and not bool(torch.isfinite(term).all())]
    blamed = []
    targets = minibatch.get("value_target", None)
    if targets is not None and targets.shape[-1] == len(components):
        magnitude = targets.detach().abs().reshape(-1, len(components)).nan_to_num(nan=float("inf")).amax(0)  # [K]
        blamed = [
            f"{name!r}: value targets up to {float(m):.0e}" for name, m in zip(components, magnitude, strict=True)
        ]
        blamed = [text for text, m in zip(blamed, magnitude, strict=True) if not m < 1e15]
    where = f" in {', '.join(terms)}" if terms else ""
    why = f" (reward component {'; '.join(blamed)})" if blamed else ""
    raise FloatingPointError(
        f"non-finite {what} at optimiser step {optim_step}{where}{why}; update not applied, training stopped"
    )


def epoch_means(losses: Sequence[TensorDictBase]) -> dict[str, float]:
    """``{"train/<term>": mean}`` over one epoch's minibatch outputs ``losses`` (each term averaged over the
    minibatches, then over its elements; empty terms left out), without autograd.

    The mean is the running mean the loop used to update after every minibatch, ``m_n = m_(n-1) (n - 1) / n +
    x_n / n``, computed here once per epoch over all terms at once: the same float operations in the same order,
    so the logged numbers stay those of earlier runs bit for bit.

    Example:
        >>> from tensordict import TensorDict
        >>> epoch_means([TensorDict({"loss_critic": torch.tensor(1.0)}), TensorDict({"loss_critic": torch.tensor(2.0)})])
        {'train/loss_critic': 1.5}
    """
    if not losses:
        return {}
    with torch.no_grad():
        stacked = {key: torch.stack([step.get(key) for step in losses]) for key in losses[0].keys()}  # [M, *shape]
        by_dtype: dict[torch.dtype, list[str]] = {}
        for key, values in stacked.items():
            by_dtype.setdefault(values.dtype, []).append(key)
        means: dict[str, torch.Tensor] = {}
        for keys in by_dtype.values():  # one [M, P] table per dtype: a cat would promote the others
            table = torch.cat([stacked[key].reshape(len(losses), -1) for key in keys], 1)
            mean = table[0]
            for n in range(2, len(losses) + 1):
                mean = mean * (n - 1) / n + table[n - 1] / n
            for key, part in zip(keys, mean.split([stacked[key][0].numel() for key in keys]), strict=True):
                means[key] = part.reshape(stacked[key].shape[1:])
        return {f"train/{key}": means[key].mean().item() for key in stacked if means[key].numel()}
