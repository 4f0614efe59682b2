"""Export behind ``python -m torchrl_ahrs.export run=<run dir>``: the trained policy as files that leave the package.

Writes into ``<run>/export/``::

    policy.pt     TorchScript (torch.jit.trace): torch.jit.load(path)(observation) -> action
    policy.onnx   ONNX (torch.onnx.export, dynamic batch): input "observation", output "action"
    policy.json   what the files expect and give: task, obs_dim, act_dim, action bounds, squash, and the
                  largest difference from the in-process policy measured at export

The files compute in float32. A run trained with ``model.precision=bfloat16`` (or ``auto`` on a CPU with bfloat16)
is exported as the float32 reading of its weights; ``policy.json`` records how far those actions lie from the
bfloat16 arithmetic the run trained and evaluated with.

Both files map a raw observation batch ``[B, obs_dim]`` float32 (as the environment emits it) to the
deterministic action ``[B, act_dim]`` (:class:`~torchrl_ahrs.training.deploy.DeterministicPolicy`:
normalisation and squashing inside); neither needs TorchRL or this package to load, TorchScript needs
torch, ONNX needs an ONNX runtime. The export is checked before it is reported: the in-process actor acts on
real observations of the task (``check_envs`` environments for ``check_steps`` steps), and each written file,
loaded back, must give the same actions within ``tolerance``.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import json
import logging
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_ahrs.app.evaluate.policy import EvaluationError, load_policy
from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.training.deploy import DeterministicPolicy
from torchrl_ahrs.training.models import AutocastMLP, precision_name, set_compute_dtype

FORMATS = ("torchscript", "onnx")
ONNX_PACKAGES = ("onnx", "onnxscript")  # torch.onnx.export (the dynamo exporter) needs both
EXPORT_DIR = "export"


class ExportError(RuntimeError):
    """The policy cannot be exported as asked; the message is one line saying why and what to do."""


@dataclass
class ExportResult:
    """The files written and the largest |action difference| of each from the in-process actor."""

    directory: Path
    files: dict[str, Path] = field(default_factory=dict)
    max_difference: dict[str, float] = field(default_factory=dict)
    trained_precision: str = "float32"  # the hidden layers' dtype the run trained with (model.precision resolved)
    precision_difference: float = 0.0  # largest |float32 action - action in trained_precision|


def reference_observations(policy, num_envs: int = 16, steps: int = 20, seed: int = 12345) -> torch.Tensor:
    """Real observations ``[num_envs * (steps + 1), obs_dim]`` of the run's task: the resets and the states the
    trained actor (mean action) drives ``num_envs`` environments through."""
    env = policy.make_envs(num_envs, seed)
    observations = []
    try:
        td = env.reset()
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            for _ in range(steps):
                observations.append(td["observation"].clone())
                _, td = env.step_and_maybe_reset(policy.actor(td))
        observations.append(td["observation"].clone())
    finally:
        env.close()
    return torch.cat(observations).float().cpu()


def actor_actions(actor, observations: torch.Tensor) -> torch.Tensor:
    """The in-process actor's deterministic action ``[B, act_dim]``, clipped into its bounds as the environment
    receives it (a ``normal`` policy's mean may leave them; a ``tanh_normal`` one never does)."""
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        action = actor(TensorDict({"observation": observations}, [observations.shape[0]]))["action"]
    space = actor.spec["action"].space
    return torch.maximum(torch.minimum(action, space.high), space.low)


def export(
    run_dir: str | Path,
    formats: tuple[str, ...] | list[str] = FORMATS,
    output: str | Path | None = None,
    check_envs: int = 16,
    check_steps: int = 20,
    tolerance: float = 1e-5,
    seed: int = 12345,
) -> ExportResult:
    """Exports the run's policy (see the module docstring); returns the files and the measured differences.

    Raises:
        EvaluationError: the run directory has no loadable policy.
        ExportError: an unknown format, a missing ONNX package (TorchScript is written first), or a file whose
            actions differ from the actor's by more than ``tolerance``.

    Example:
        >>> export("/nonexistent")
        Traceback (most recent call last):
        ...
        torchrl_ahrs.app.evaluate.policy.EvaluationError: no run directory at /nonexistent
    """
    unknown = [name for name in formats if name not in FORMATS]
    if unknown or not formats:
        raise ExportError(f"formats must be a non-empty list of {', '.join(FORMATS)}, got {list(formats)}")
    policy = load_policy(run_dir)
    observations = reference_observations(policy, check_envs, check_steps, seed)
    trained_actions = actor_actions(policy.actor, observations)  # in the run's model.precision
    trained_dtype = next((mlp.compute_dtype for mlp in policy.actor.modules() if isinstance(mlp, AutocastMLP)), None)
    # the files compute in float32, which every runtime has; a run trained with bfloat16 hidden layers is exported
    # as the float32 reading of its weights, checked against the actor in float32, and policy.json says how far the
    # exported actions lie from the trained arithmetic's
    set_compute_dtype(policy.actor, None)
    module = DeterministicPolicy.from_actor(policy.actor.cpu())
    expected = actor_actions(policy.actor, observations)
    result = ExportResult(Path(output) if output else RunDirectory(run_dir).path / EXPORT_DIR)
    result.trained_precision = precision_name(trained_dtype)
    result.directory.mkdir(parents=True, exist_ok=True)
    result.max_difference["module"] = _max_difference(module(observations), expected)
    result.precision_difference = _max_difference(expected, trained_actions)

    if "torchscript" in formats:
        path = result.directory / "policy.pt"
        traced = torch.jit.trace(module, observations[:1], check_inputs=[(observations,)])
        traced.save(str(path))
        result.files["torchscript"] = path
        result.max_difference["torchscript"] = _max_difference(torch.jit.load(str(path))(observations), expected)
    _write_metadata(result, policy, module, observations.shape[-1], tolerance)  # now: a failure below keeps the .pt
    if "onnx" in formats:
        path = result.directory / "policy.onnx"
        _export_onnx(module, observations, path)
        result.files["onnx"] = path
        difference = _onnx_difference(path, observations, expected)
        if difference is not None:
            result.max_difference["onnx"] = difference
    _write_metadata(result, policy, module, observations.shape[-1], tolerance)
    failed = {name: value for name, value in result.max_difference.items() if not value <= tolerance}
    if failed:
        raise ExportError(f"exported actions differ from the trained policy's by {failed} (tolerance {tolerance})")
    return result


def _max_difference(actions: torch.Tensor, expected: torch.Tensor) -> float:
    return float((torch.as_tensor(actions) - expected).abs().max())


def _export_onnx(module: DeterministicPolicy, observations: torch.Tensor, path: Path) -> None:
    missing = [name for name in ONNX_PACKAGES if importlib.util.find_spec(name) is None]
    if missing:
        raise ExportError(
            f"ONNX export needs the package(s) {', '.join(missing)}: pip install 'torchrl-ahrs[onnx]' "
            "(policy.pt is written), or formats=[torchscript]"
        )
    # torch.onnx logs every registry it skips (torchvision's ops), onnxscript each optimiser pass: not the user's business
    for name in ("torch.onnx", "onnxscript", "onnx_ir"):
        logging.getLogger(name).setLevel(logging.ERROR)
    # the exporter prints each stage, and torch's own pytree code warns of its own deprecation: neither is ours
    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        torch.onnx.export(
            module,
            (observations[:2],),
            str(path),
            input_names=["observation"],
            output_names=["action"],
            dynamic_shapes={"observation": {0: torch.export.Dim("batch")}},
            dynamo=True,
            external_data=False,  # one file: the weights inside the graph
            verbose=False,
        )


def _onnx_difference(path: Path, observations: torch.Tensor, expected: torch.Tensor) -> float | None:
    """The largest difference of the ONNX file's actions under onnxruntime, None without onnxruntime."""
    if importlib.util.find_spec("onnxruntime") is None:
        return None
    import onnxruntime

    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (actions,) = session.run(["action"], {"observation": observations.numpy()})
    return _max_difference(torch.from_numpy(actions), expected)


def _write_metadata(result: ExportResult, policy, module: DeterministicPolicy, obs_dim: int, tolerance: float) -> None:
    metadata: dict[str, Any] = {
        "task": policy.task.name,
        "method": policy.cfg.method.name,
        "obs_dim": obs_dim,
        "act_dim": int(module.low.numel()),
        "input": "observation [B, obs_dim] float32, raw (normalised inside)",
        "output": "action [B, act_dim] float32, deterministic, inside [action_low, action_high]",
        "action_low": module.low.tolist(),
        "action_high": module.high.tolist(),
        "squash": "tanh" if module.tanh else "clip",
        "files": {name: path.name for name, path in result.files.items()},
        "max_abs_difference_from_trained_policy": result.max_difference,
        "trained_precision": result.trained_precision,  # the hidden layers' (training/models.py AutocastMLP)
        "exported_precision": "float32",
        "max_abs_difference_from_trained_precision": result.precision_difference,  # 0 for a float32 run
        "tolerance": tolerance,
    }
    (result.directory / "policy.json").write_text(json.dumps(metadata, indent=2) + "\n")


def run(cfg: DictConfig) -> int:
    """The command (``conf/export.yaml``): export, then print each file and its measured difference."""
    if OmegaConf.is_missing(cfg, "run"):
        raise EvaluationError("give the training run directory: python -m torchrl_ahrs.export run=<run dir>")
    result = export(
        cfg.run, list(cfg.formats), cfg.output, cfg.check_envs, cfg.check_steps, float(cfg.tolerance), cfg.seed
    )
    for name, path in result.files.items():
        difference = result.max_difference.get(name)
        measured = f"max |action difference| {difference:.2e}" if difference is not None else "not run here"
        print(f"wrote {path} ({name}; {measured} on {cfg.check_envs * (cfg.check_steps + 1)} real observations)")
    if result.precision_difference > 0:
        print(
            f"the files compute in float32; the run trained its hidden layers in {result.trained_precision}: their actions"
            f" differ from the trained arithmetic's by up to {result.precision_difference:.2e}"
        )
    print(f"wrote {result.directory / 'policy.json'}")
    return 0
