"""Auxiliary-reward generation behind ``python -m torchrl_ahrs.generate_aux task=<task> llm=openai [llm.model=<model>]``.

Asks the LLM with the "Add Auxiliary reward" prompt (task description, the task's reward code, each
component, the inputs measured on real transitions, the output requirements), extracts the code block,
checks it with the sandbox (static allow-list, then the limited child process calling it on real
transitions of the task: finite, shape [N]) and, when it is refused, sends the reasons back and asks
again, up to ``aux.generate.attempts`` answers. The accepted function is written with provenance
(model, date, prompt hash, attempts) to ``aux_reward.py``, which ``aux.path=<file>`` uses for training.

Output: ``+output=<dir>`` (default ``outputs/aux/<task>-<model>-<time>/``) receives ``aux_reward.py`` and
``llm_calls.jsonl``. Exit status 0 when a function was accepted, 1 otherwise.
"""

from __future__ import annotations

import datetime
import importlib
import inspect
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig

from torchrl_ahrs.app.auxiliary import collect_aux_inputs
from torchrl_ahrs.app.run_dir import RunDirectory, calls_log
from torchrl_ahrs.common.config_access import select
from torchrl_ahrs.llm.aux_prompt import aux_feedback_message, aux_reward_prompt
from torchrl_ahrs.llm.client import LLMClient, prompt_hash
from torchrl_ahrs.llm.generation import extract_code_blocks, generation_output_dir, llm_and_task
from torchrl_ahrs.rewards.auxiliary import AUX_FUNCTION, load_aux_function
from torchrl_ahrs.sandbox import check_source, validate_in_child

# The Python that computes each task's reward terms ("module:qualified name"); tasks whose terms come
# from EnvPool's C++ have none and the prompt says so.
REWARD_SOURCES: dict[str, list[str]] = {
    "point_reach": ["torchrl_ahrs.envs.tasks.point_reach:PointReachEnv.reward_terms"],
    "quadcopter": ["torchrl_ahrs.envs.tasks.quadcopter:quadcopter_reward_terms"],
    "ant": ["torchrl_ahrs.envs.tasks.ant:ant_reward_terms"],
    "cassie": [
        "torchrl_ahrs.envs.common.legged_rewards",
        "torchrl_ahrs.envs.tasks.cassie:CassieEnv.after_physics_step",
    ],
    "shadow_hand": ["torchrl_ahrs.envs.tasks.shadow_hand:shadow_hand_terms"],
    "dmc_walker_walk": ["torchrl_ahrs.envs.tasks.dmc_tasks:walker_walk_terms"],
    "dmc_quadruped_run": ["torchrl_ahrs.envs.tasks.dmc_tasks:quadruped_run_terms"],
    "dmc_cheetah_run": ["torchrl_ahrs.envs.tasks.dmc_tasks:cheetah_run_terms"],
}
OBSERVATION_SOURCES: dict[str, str] = {
    "point_reach": "torchrl_ahrs.envs.tasks.point_reach:PointReachEnv.observation",
    "quadcopter": "torchrl_ahrs.envs.tasks.quadcopter:QuadcopterEnv.observation",
    "ant": "torchrl_ahrs.envs.tasks.ant:AntEnv.observation",
    "cassie": "torchrl_ahrs.envs.tasks.cassie:CassieEnv.observation",
}


def source_of(reference: str) -> str | None:
    """``inspect.getsource`` of ``"module"`` or ``"module:qualified.name"``; None when it does not exist."""
    module_name, _, qualname = reference.partition(":")
    try:
        target: Any = importlib.import_module(module_name)
        for part in filter(None, qualname.split(".")):
            target = getattr(target, part)
        return inspect.getsource(target)
    except (ImportError, AttributeError, OSError, TypeError):
        return None


def reward_code(task_name: str) -> str | None:
    """The Python source of the task's reward terms, or None (computed inside the simulator)."""
    parts = [part for reference in REWARD_SOURCES.get(task_name, []) if (part := source_of(reference))]
    return "\n\n".join(parts) if parts else None


def extract_aux_source(text: str) -> str:
    """The code block of an answer that defines ``compute_aux_reward``; raises ``ValueError`` if none does.

    Example:
        >>> extract_aux_source("Here:\\n```python\\ndef compute_aux_reward(obs):\\n    return obs['a']\\n```\\n")
        "def compute_aux_reward(obs):\\n    return obs['a']\\n"
    """
    blocks = [block for block in extract_code_blocks(text) if f"def {AUX_FUNCTION}(" in block]
    if not blocks:
        raise ValueError(f"the answer has no code block defining {AUX_FUNCTION}(obs)")
    return blocks[-1]


def check_candidate(source: str, inputs_path: Path) -> list[str]:
    """Every reason to refuse ``source`` (empty when accepted): static gate, then the limited child run
    on the saved real transitions (shape [N], finite, within CPU and memory limits)."""
    verdict = check_source(source, "<answer>")
    if not verdict.ok:
        return verdict.reasons
    if AUX_FUNCTION not in verdict.functions:
        return [f"no function named {AUX_FUNCTION}(obs); found {verdict.functions}"]
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as handle:
        handle.write(source)
    try:
        verdict = validate_in_child(handle.name, "aux", inputs_path=inputs_path)
    finally:
        Path(handle.name).unlink(missing_ok=True)
    return [] if verdict.ok else verdict.reasons


@dataclass
class AuxGenerationResult:
    """The accepted file (None when every attempt was refused) and the reasons of each refused attempt."""

    path: Path | None = None
    refusals: list[list[str]] = field(default_factory=list)
    attempts: int = 0


def generate(cfg: Any, output_dir: Path) -> AuxGenerationResult:
    """Runs the whole generation for a composed config (``cfg.task``, ``cfg.llm``, ``cfg.aux.generate``)."""
    llm_cfg, task = llm_and_task(cfg, "generate_aux")
    components = list(task["components"])
    attempts = int(select(cfg, "aux.generate.attempts", 3))
    inputs = collect_aux_inputs(
        task,
        int(select(cfg, "aux.generate.num_envs", 16)),
        int(select(cfg, "aux.generate.steps", 32)),
        int(select(cfg, "seed", 0)),
    )
    observation_ref = OBSERVATION_SOURCES.get(task["name"])
    messages = aux_reward_prompt(
        task,
        components,
        reward_code(task["name"]),
        {name: tuple(value.shape) for name, value in inputs.items()},
        source_of(observation_ref) if observation_ref else None,
    )
    first_prompt_hash = prompt_hash(messages)
    if llm_cfg.replay_from:
        llm_cfg.replay_from = calls_log(llm_cfg.replay_from)
    client = LLMClient(llm_cfg, calls_path=RunDirectory(output_dir).llm_calls)
    result = AuxGenerationResult()
    with tempfile.TemporaryDirectory() as scratch:
        inputs_path = Path(scratch) / "inputs.pt"
        torch.save(inputs, inputs_path)
        for attempt in range(1, attempts + 1):
            result.attempts = attempt
            reply = client.complete(messages, purpose="generate_aux")
            if reply.text is None:
                result.refusals.append([f"the LLM call failed: {reply.error}"])
                break  # the client already retried the transport; another prompt would not help
            try:
                source = extract_aux_source(reply.text)
                reasons = check_candidate(source, inputs_path)
            except ValueError as error:
                reasons = [str(error)]
            if not reasons:
                result.path = _write(output_dir, source, task["name"], llm_cfg.model, first_prompt_hash, attempt)
                load_aux_function(result.path)  # the file as written must load
                return result
            result.refusals.append(reasons)
            messages = [*messages, {"role": "assistant", "content": reply.text}, aux_feedback_message(reasons)]
    return result


def _write(output_dir: Path, source: str, task_name: str, model: str | None, digest: str, attempt: int) -> Path:
    stamp = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    header = (
        f'"""Auxiliary reward generated by {model} for task {task_name}.\n\n'
        f"provenance: model={model}, date={stamp}, prompt_hash={digest}, accepted at attempt {attempt}\n"
        f"use: python -m torchrl_ahrs.train task={task_name} method=ahrs aux.path=<this file>\n"
        '"""\n\n'
    )
    path = output_dir / "aux_reward.py"
    path.write_text(header + source.strip() + "\n")
    return path


def _report(result: AuxGenerationResult) -> None:
    for attempt, reasons in enumerate(result.refusals, start=1):
        print(f"attempt {attempt} refused:")
        for reason in reasons:
            print(f"  - {reason}")
    if result.path is not None:
        print(f"accepted at attempt {result.attempts}: {result.path} (use aux.path={result.path})")
    else:
        print(f"no auxiliary reward accepted after {result.attempts} attempt(s)")


def run(cfg: DictConfig) -> int:
    """The command: generate into the output directory, print the outcome; exit status 1 if nothing was accepted."""
    llm_and_task(cfg, "generate_aux")  # refuse a missing LLM before creating the output directory
    result = generate(cfg, generation_output_dir(cfg, "aux"))
    _report(result)
    return 0 if result.path is not None else 1
