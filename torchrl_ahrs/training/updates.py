"""What each optimiser step of :func:`~torchrl_ahrs.training.loop.learn` answers to: the refusal of a non-finite
update (:func:`check_finite_update`, one line naming the loss terms and reward components to blame) and the epoch's
mean of the loss outputs it logs (:func:`epoch_means`)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase


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
