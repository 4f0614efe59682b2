"""Auxiliary-reward generation behind ``python -m torchrl_ahrs.generate_aux task=<task> llm=openai [llm.model=<model>]``.

Asks the LLM with the "Add Auxiliary reward" prompt (task description, the task's reward code, each
component, the inputs measured on real transitions, the output requirements), extracts the code block,
checks it with the sandbox (static allow-list, then the limited child process calling it on real
transitions of the task: finite, shape [N]) and, when it is refused, sends the reasons back and asks
again, up to ``aux.generate.attempts`` answers. Every accepted function is written with provenance
(model, date, prompt hash, attempt) to ``candidates/attempt_<i>/aux_reward.py``.

With ``aux.generate.train_rounds=R > 0`` (the paper's "I will use the reward function to train an RL
agent and test it"), each accepted candidate is trained for ``aux.generate.train_frames`` frames with
the composed method (default ``ahrs``; any method with an auxiliary branch), each component's episode
returns, weights and effective shares are sent back to the LLM, and it writes the next candidate, until
R candidates have been trained or the attempts run out. The candidate with the highest final
``return/total`` is chosen (see :mod:`torchrl_ahrs.app.generate.aux_rounds`). With R = 0 the first accepted
candidate is chosen.

Output: ``+output=<dir>`` (default ``outputs/aux/<task>-<model>-<time>/``) receives the chosen
``aux_reward.py`` (use ``aux.path=<file>``), ``candidates/`` (every answer, its code, its training
round), ``candidates.json`` (reasons or scores of every attempt and the chosen one) and
``llm_calls.jsonl``. Exit status 0 when a function was chosen, 1 otherwise.
"""

from __future__ import annotations

import datetime
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig

from torchrl_ahrs.app.generate.aux_rounds import Candidate, choose, scores_text, train_round, write_index
from torchrl_ahrs.app.shared.auxiliary import collect_aux_inputs
from torchrl_ahrs.app.shared.run_dir import RunDirectory, calls_log
from torchrl_ahrs.app.shared.settings import generation_output_dir, llm_and_task, select
from torchrl_ahrs.common.text import ANSWER_CHARS, cap_text
from torchrl_ahrs.llm.aux_prompt import aux_feedback_message, aux_reward_prompt, training_feedback_message
from torchrl_ahrs.llm.client import LLMClient, prompt_hash
from torchrl_ahrs.llm.generation import extract_code_blocks
from torchrl_ahrs.llm.task_text import environment_code, reward_code_blocks
from torchrl_ahrs.rewards.auxiliary import AUX_FUNCTION, load_aux_function
from torchrl_ahrs.sandbox import check_source, validate_in_child


def reward_code(task: dict[str, Any]) -> str | None:
    """The Python source of the task's reward terms (``task.reward_code``, read with ``inspect.getsource``),
    or None when they are computed inside the simulator."""
    blocks = reward_code_blocks(task, list(task["components"]))
    return "\n\n".join(source for _, source in blocks) if blocks else None


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
    chosen_attempt: int | None = None


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
    messages = aux_reward_prompt(
        task,
        components,
        reward_code(task),
        {name: tuple(value.shape) for name, value in inputs.items()},
        environment_code(task),
    )
    rounds = int(select(cfg, "aux.generate.train_rounds", 0))
    frames = int(select(cfg, "aux.generate.train_frames", 40_960))
    first_prompt_hash = prompt_hash(messages)
    if llm_cfg.replay_from:
        llm_cfg.replay_from = calls_log(llm_cfg.replay_from)
    client = LLMClient(llm_cfg, calls_path=RunDirectory(output_dir).llm_calls)
    result = AuxGenerationResult()
    candidates: list[Candidate] = []
    with tempfile.TemporaryDirectory() as scratch:
        inputs_path = Path(scratch) / "inputs.pt"
        torch.save(inputs, inputs_path)
        for attempt in range(1, attempts + 1):
            result.attempts = attempt
            reply = client.complete(messages, purpose="generate_aux")
            if reply.text is None:
                result.refusals.append([f"the LLM call failed: {reply.error}"])
                break  # the client already retried the transport; another prompt would not help
            candidate_dir = output_dir / "candidates" / f"attempt_{attempt}"
            candidate_dir.mkdir(parents=True, exist_ok=True)
            (candidate_dir / "answer.md").write_text(reply.text)
            try:
                source = extract_aux_source(reply.text)
                reasons = check_candidate(source, inputs_path)
            except ValueError as error:
                reasons = [str(error)]
            candidate = Candidate(attempt, reasons=reasons)
            candidates.append(candidate)
            if reasons:
                result.refusals.append(reasons)
                messages = [
                    *messages,
                    {"role": "assistant", "content": cap_text(reply.text, ANSWER_CHARS)},
                    aux_feedback_message(reasons),
                ]
                continue
            path = _write(candidate_dir, source, task["name"], llm_cfg.model, first_prompt_hash, attempt)
            load_aux_function(path, isolated=False)  # the file as written must load (its check ran in the child)
            candidate.path = str(path)
            if rounds == 0:
                break  # no training feedback: the first accepted candidate is the answer
            candidate.scores = train_round(cfg, path, candidate_dir / "run", frames)
            write_index(output_dir, candidates, choose(candidates), {"train_frames": frames})
            if sum(1 for c in candidates if c.scores) >= rounds:
                break
            feedback = training_feedback_message(scores_text(candidate.scores, _round_components(cfg), frames))
            messages = [*messages, {"role": "assistant", "content": cap_text(reply.text, ANSWER_CHARS)}, feedback]
    chosen = choose(candidates)
    write_index(output_dir, candidates, chosen, {"train_frames": frames if rounds else 0})
    if chosen is not None:
        result.path = output_dir / "aux_reward.py"
        shutil.copyfile(str(chosen.path), result.path)
        result.chosen_attempt = chosen.attempt
    return result


def _round_components(cfg: Any) -> list[str]:
    from torchrl_ahrs.app.shared.config import resolve_components

    return resolve_components(cfg)


def _write(output_dir: Path, source: str, task_name: str, model: str | None, digest: str, attempt: int) -> Path:
    stamp = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    header = (
        f'"""Auxiliary reward generated by {model} for task {task_name}.\n\n'
        f"provenance: model={model}, date={stamp}, prompt_hash={digest}, accepted at attempt {attempt}\n"
        f"use: python -m torchrl_ahrs.train task={task_name} method=ahrs aux.path=<this file>\n"
        '"""\n\n'
    )
    path = output_dir / "aux_reward.py"  # the candidate's own directory; the chosen one is copied up
    path.write_text(header + source.strip() + "\n")
    return path


def _report(result: AuxGenerationResult) -> None:
    for attempt, reasons in enumerate(result.refusals, start=1):
        print(f"attempt {attempt} refused:")
        for reason in reasons:
            print(f"  - {reason}")
    if result.path is not None:
        print(f"chose attempt {result.chosen_attempt} of {result.attempts}: {result.path} (use aux.path={result.path})")
    else:
        print(f"no auxiliary reward accepted after {result.attempts} attempt(s)")


def run(cfg: DictConfig) -> int:
    """The command: generate into the output directory, print the outcome; exit status 1 if nothing was accepted."""
    llm_and_task(cfg, "generate_aux")  # refuse a missing LLM before creating the output directory
    result = generate(cfg, generation_output_dir(cfg, "aux"))
    _report(result)
    return 0 if result.path is not None else 1
