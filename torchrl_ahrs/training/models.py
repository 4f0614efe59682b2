"""Actor, K-head critic and the observation normaliser they share."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
from torch import nn
from torchrl.data import TensorSpec
from torchrl.modules import IndependentNormal, ProbabilisticActor, TanhNormal

from torchrl_ahrs.value import HeadwiseLinear, MultiHeadCritic, make_mlp


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


class AutocastMLP(nn.Sequential):
    """An MLP's layers applied in order, the output layer last; ``compute_dtype`` sets the precision of all the
    others.

    With ``compute_dtype=None`` every layer computes in its parameters' dtype (float32). With ``torch.bfloat16``
    the layers before the output layer run under :func:`torch.autocast` (their matrix products in bfloat16 from
    float32 parameters, gradients into those float32 parameters), and the output layer runs in float32 on the
    float32 cast of the last hidden activations. On a CPU with AVX512-BF16 a training step of Cassie's
    [512, 256, 128] network costs about a third of float32's (benchmarks/RESULTS.md, session 35), while the outputs
    (an action mean, a value) keep float32's resolution. It holds the very layers of the MLP it replaces
    (:func:`set_compute_dtype`), so ``state_dict`` is the same in every precision: a checkpoint loads into either.

    Shapes: ``[*B, in] -> [*B, out]``, float32 out.

    Example:
        >>> mlp = AutocastMLP(nn.Linear(4, 8), nn.ELU(), nn.Linear(8, 2))
        >>> x = torch.randn(5, 4)
        >>> exact = mlp(x)
        >>> mlp.compute_dtype = torch.bfloat16
        >>> mlp(x).dtype, bool((mlp(x) - exact).abs().max() < 0.05)
        (torch.float32, True)
    """

    compute_dtype: torch.dtype | None = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.compute_dtype is None:
            return super().forward(x)
        *hidden, output = self
        with torch.autocast(x.device.type, dtype=self.compute_dtype):
            for layer in hidden:
                x = layer(x)
        return output(x.float())


def set_compute_dtype(network: nn.Module, dtype: torch.dtype | None) -> nn.Module:
    """Runs every MLP inside ``network`` (an actor, a critic) with its hidden layers in ``dtype`` (``None``:
    float32); returns ``network``.

    An MLP is an ``nn.Sequential`` whose last layer is linear (``nn.Linear``, or the critic's
    :class:`~torchrl_ahrs.value.critic.HeadwiseLinear`): :func:`~torchrl_ahrs.value.critic.make_mlp`'s and the
    separate heads of :class:`~torchrl_ahrs.value.critic.MultiHeadCritic`. Each becomes an :class:`AutocastMLP`
    holding the same layers, so parameters, and the optimiser that holds them, are untouched; the actor's
    ``Sequential(norm, mlp, scale)`` ends in its scale and is left as it is.

    Example:
        >>> critic = MultiHeadCritic(8, 3, [16], anchor_head=True)
        >>> _ = set_compute_dtype(critic, torch.bfloat16)
        >>> [(name, mlp.compute_dtype) for name, mlp in critic.named_modules() if isinstance(mlp, AutocastMLP)]
        [('anchor', torch.bfloat16), ('net', torch.bfloat16)]
    """
    for parent in list(network.modules()):
        for name, child in list(parent.named_children()):
            if isinstance(child, nn.Sequential) and len(child) and isinstance(child[-1], (nn.Linear, HeadwiseLinear)):
                if not isinstance(child, AutocastMLP):
                    child = AutocastMLP(*child)  # the same layer objects, under the same name
                    setattr(parent, name, child)
                child.compute_dtype = dtype
    return network


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
    float32; see :class:`AutocastMLP`): ``float32``, ``bfloat16``, or ``auto``, which is
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


def precision_name(dtype: torch.dtype | None) -> str:
    """The ``model.precision`` value that :func:`compute_dtype` resolved to ``dtype``, for logs and files.

    Example:
        >>> precision_name(None), precision_name(torch.bfloat16)
        ('float32', 'bfloat16')
    """
    return str(dtype or torch.float32).removeprefix("torch.")


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
    anchor_hidden_sizes: Sequence[int] | None = None,
) -> TensorDictModule:
    """A :class:`MultiHeadCritic` writing ``"state_value"`` ``[*B, K]`` (``[*B, K + 1]`` with ``anchor_head``);
    ``hidden_sizes`` are the K heads' widths, ``anchor_hidden_sizes`` the anchor's (``None``: the same)."""
    critic = MultiHeadCritic(
        obs_dim, num_heads, hidden_sizes, activation, separate_heads, anchor_head, anchor_hidden_sizes
    )
    return TensorDictModule(nn.Sequential(obs_norm, critic), in_keys=[in_key], out_keys=["state_value"])
