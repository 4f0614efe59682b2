"""Actor, K-head critic and the observation normaliser they share."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
from torch import nn
from torchrl.data import TensorSpec
from torchrl.modules import IndependentNormal, ProbabilisticActor, TanhNormal

from torchrl_ahrs.value import MultiHeadCritic, make_mlp


class RunningNorm(nn.Module):
    """Observation standardisation with running statistics kept as buffers.

    The statistics travel with the networks' state (checkpoints, collector weight sync), so a
    multi-process collector normalises exactly like the learner. They change only through
    :meth:`update`, which the training loop calls after each PPO update with the batch just used.

    Example:
        >>> norm = RunningNorm(2)
        >>> norm.update(torch.tensor([[1.0, 10.0], [3.0, 30.0]]))
        >>> norm(torch.tensor([[2.0, 20.0]])).abs().max() < 1e-3
        tensor(True)
    """

    mean: torch.Tensor  # buffers, declared for the type checker (nn.Module.__getattr__ says Tensor | Module)
    var: torch.Tensor
    count: torch.Tensor

    def __init__(self, size: int, clip: float = 10.0, eps: float = 1e-8):
        super().__init__()
        self.clip = clip
        self.eps = eps
        self.register_buffer("mean", torch.zeros(size))
        self.register_buffer("var", torch.ones(size))
        self.register_buffer("count", torch.tensor(0.0))

    @torch.no_grad()
    def update(self, observations: torch.Tensor) -> None:
        """Merges the statistics of ``observations [*, size]`` (parallel Welford / Chan et al.)."""
        flat = observations.reshape(-1, self.mean.shape[0]).to(self.mean.dtype)
        batch_count = flat.shape[0]
        batch_mean, batch_var = flat.mean(0), flat.var(0, unbiased=False)
        total = self.count + batch_count
        delta = batch_mean - self.mean
        self.mean += delta * batch_count / total  # mu <- mu + delta * n_b / n
        m2 = self.var * self.count + batch_var * batch_count + delta**2 * self.count * batch_count / total
        self.var.copy_(m2 / total)  # sigma^2 <- (M2_a + M2_b + delta^2 n_a n_b / n) / n
        self.count.copy_(total)

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        normalized = (observation - self.mean) / torch.sqrt(self.var + self.eps)  # z = (x - mu) / sigma
        return normalized.clamp(-self.clip, self.clip)


DISTRIBUTIONS = ("tanh_normal", "normal")
OBSERVATION_NORMS = ("running", "none")
PRECISIONS = ("float32", "bfloat16", "auto")


def native_bfloat16(device: torch.device | str = "cpu") -> bool:
    """Whether ``device`` computes bfloat16 matrix products in hardware (a CPU with AVX512-BF16 or AMX, as oneDNN
    reports it; a CUDA device of compute capability 8.0 or above); elsewhere bfloat16 is emulated, slower than
    float32."""
    device = torch.device(device)
    if device.type == "cuda":
        return torch.cuda.is_bf16_supported(including_emulation=False)
    return (
        device.type == "cpu" and torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported()
    )


def compute_dtype(precision: str, device: torch.device | str = "cpu") -> torch.dtype | None:
    """The hidden layers' compute dtype that ``model.precision`` names, for networks on ``device`` (``None``:
    float32; see :class:`~torchrl_ahrs.value.critic.AutocastMLP`): ``float32``, ``bfloat16``, or ``auto``, which is
    bfloat16 where ``device`` computes it in hardware (:func:`native_bfloat16`) and float32 elsewhere.

    Example:
        >>> compute_dtype("float32") is None
        True
        >>> compute_dtype("auto") in (None, torch.bfloat16)
        True
        >>> compute_dtype("half")
        Traceback (most recent call last):
        ...
        ValueError: model.precision must be one of float32, bfloat16, auto, got 'half'
    """
    if precision not in PRECISIONS:
        raise ValueError(f"model.precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "auto":
        precision = "bfloat16" if native_bfloat16(device) else "float32"
    return torch.bfloat16 if precision == "bfloat16" else None


def make_observation_norm(size: int, kind: str = "running") -> RunningNorm:
    """The observation normaliser ``model.observation_norm`` names: ``running`` standardises with running
    statistics clipped to ±10; ``none`` passes the observation through as the task scales it (legged_gym's fixed
    ``obs_scales``) — a :class:`RunningNorm` without a clip that the loop never updates, so it stays the identity
    while checkpoints, export and deployment keep one layout.

    Example:
        >>> make_observation_norm(2, "none")(torch.tensor([[30.0, -40.0]]))
        tensor([[ 30., -40.]])
    """
    if kind not in OBSERVATION_NORMS:
        raise ValueError(f"observation_norm must be one of {', '.join(OBSERVATION_NORMS)}, got {kind!r}")
    return RunningNorm(size) if kind == "running" else RunningNorm(size, clip=math.inf)


def build_actor(
    obs_norm: RunningNorm,
    obs_dim: int,
    action_spec: TensorSpec,
    hidden_sizes: Sequence[int],
    activation: str = "tanh",
    init_log_std: float = -0.5,
    in_key: str = "observation",
    distribution: str = "tanh_normal",
) -> ProbabilisticActor:
    """Gaussian policy with a state-independent scale ``sigma = exp(log_std)`` ``[A]``.

    ``distribution``:

    - ``"tanh_normal"``: squashed into the action bounds (TorchRL's ``TanhNormal``): every sample is a
      valid action, and its log-probability includes the squash;
    - ``"normal"``: unsquashed (TorchRL's ``IndependentNormal``), as CleanRL's and rsl_rl's PPO: samples
      may leave the bounds, and the environment must clip them on the way in
      (:class:`~torchrl_ahrs.envs.common.clip_actions.ClipActionToSpec`) while the rollout keeps the sample.

    Example:
        >>> import torch
        >>> from torchrl.data import Bounded
        >>> spec = Bounded(-torch.ones(2), torch.ones(2), (2,))
        >>> actor = build_actor(RunningNorm(3), 3, spec, [8], init_log_std=-0.5, distribution="normal")
        >>> from tensordict import TensorDict
        >>> td = actor(TensorDict({"observation": torch.zeros(4, 3)}, [4]))
        >>> torch.allclose(td["scale"], torch.full((4, 2), -0.5).exp())  # sigma_0 = exp(init_log_std)
        True
    """
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution must be one of {', '.join(DISTRIBUTIONS)}, got {distribution!r}")
    action_dim = action_spec.shape[-1]
    loc_net = make_mlp(obs_dim, hidden_sizes, action_dim, activation)
    nn.init.orthogonal_(loc_net[-1].weight, 0.01)  # type: ignore[arg-type]  # small initial actions keep early rollouts near rest
    # the parameter is the log standard deviation: scale_mapping="exp" maps it to sigma = exp(init_log_std)
    scale = AddStateIndependentNormalScale(action_dim, scale_mapping="exp", init_value=float(init_log_std))
    module = TensorDictModule(nn.Sequential(obs_norm, loc_net, scale), in_keys=[in_key], out_keys=["loc", "scale"])
    if distribution == "normal":
        return ProbabilisticActor(
            module,
            in_keys=["loc", "scale"],
            spec=action_spec,
            distribution_class=IndependentNormal,
            return_log_prob=True,
        )
    low, high = action_spec.space.low, action_spec.space.high
    return ProbabilisticActor(
        module,
        in_keys=["loc", "scale"],
        spec=action_spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": low, "high": high, "tanh_loc": False},
        return_log_prob=True,
    )


def build_critic(
    obs_norm: RunningNorm,
    obs_dim: int,
    num_heads: int,
    hidden_sizes: Sequence[int],
    activation: str = "tanh",
    separate_heads: bool = False,
    in_key: str = "observation",
    anchor_head: bool = False,
) -> TensorDictModule:
    """A :class:`MultiHeadCritic` writing ``"state_value"`` ``[*B, K]`` (``[*B, K + 1]`` with ``anchor_head``)."""
    critic = MultiHeadCritic(obs_dim, num_heads, hidden_sizes, activation, separate_heads, anchor_head)
    return TensorDictModule(nn.Sequential(obs_norm, critic), in_keys=[in_key], out_keys=["state_value"])
