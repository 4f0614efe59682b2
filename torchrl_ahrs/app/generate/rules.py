"""Rule generation behind ``python -m torchrl_ahrs.generate_rules task=<task> llm=openai [llm.model=<model>]``.

Asks the LLM with the "Build rule repository" prompt (task description, reward components, the HD-PPO
rule as the example), extracts the Python code blocks of the answer, checks every rule function
with the sandbox (static allow-list, then the limited child process), and writes a repository file
with provenance (model, date, prompt hash) that ``scheduler.rules=<file>`` loads. Refused rules are
reported with their reasons (and listed in the file's docstring).

Output: ``+output=<dir>`` (default ``outputs/rules/<task>-<model>-<time>/``) receives ``rules.py``
and ``llm_calls.jsonl``. Exit status 0 when at least one rule was accepted.
"""

from __future__ import annotations

import ast
import datetime
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from omegaconf import DictConfig

from torchrl_ahrs.app.shared.run_dir import RunDirectory, calls_log
from torchrl_ahrs.app.shared.settings import generation_output_dir, llm_and_task
from torchrl_ahrs.llm.client import LLMClient, prompt_hash
from torchrl_ahrs.llm.generation import GenerationError, extract_code_blocks
from torchrl_ahrs.llm.prompts import rule_generation_prompt
from torchrl_ahrs.sandbox import check_source, validate_in_child
from torchrl_ahrs.scheduling.rules import HDPG_REPOSITORY, RULE_ARITY, load_repository

HEADER_IMPORTS = "import math\n\nimport torch\n"


@dataclass
class GenerationResult:
    """Accepted rule sources (name → source) and refusals (name → reasons)."""

    accepted: dict[str, str] = field(default_factory=dict)
    refused: dict[str, list[str]] = field(default_factory=dict)
    path: Path | None = None


def split_rules(block: str) -> tuple[list[str], dict[str, str], dict[str, list[str]]]:
    """A code block → (module-level constant lines, {rule name: function source}, {name: parse problems})."""
    try:
        tree = ast.parse(block)
    except SyntaxError as error:
        return [], {}, {f"<block at line {error.lineno}>": [f"syntax error: {error.msg}"]}
    constants = [
        ast.get_source_segment(block, node) for node in tree.body if isinstance(node, (ast.Assign, ast.AnnAssign))
    ]
    rules: dict[str, str] = {}
    problems: dict[str, list[str]] = {}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef):
            source = cast(str, ast.get_source_segment(block, node))  # None only for nodes made without a position
            if node.decorator_list:
                source = "\n".join(f"@{ast.get_source_segment(block, d)}" for d in node.decorator_list) + "\n" + source
            if len(node.args.args) != RULE_ARITY:
                problems[node.name] = [f"takes {len(node.args.args)} arguments, a rule takes {RULE_ARITY}"]
            else:
                rules[node.name] = source
    return [c for c in constants if c], rules, problems


def validate_rules(constants: list[str], rules: dict[str, str]) -> GenerationResult:
    """Static check of each rule on its own, then one child-process validation of all survivors."""
    result = GenerationResult()
    preamble = HEADER_IMPORTS + "\n".join(constants) + "\n\n"
    for name, source in rules.items():
        verdict = check_source(preamble + source + "\n", name)
        if verdict.ok:
            result.accepted[name] = source
        else:
            result.refused[name] = verdict.reasons
    while result.accepted:
        with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as handle:
            handle.write(preamble + "\n\n".join(result.accepted.values()) + "\n")
        verdict = validate_in_child(handle.name, "rule")
        Path(handle.name).unlink(missing_ok=True)
        if verdict.ok:
            break
        blamed = {name for name in result.accepted for reason in verdict.reasons if reason.startswith(f"{name}:")}
        if not blamed:  # the whole child failed without naming a rule: refuse all rather than guess
            blamed = set(result.accepted)
        for name in blamed:
            result.refused[name] = [
                reason for reason in verdict.reasons if reason.startswith(f"{name}:")
            ] or verdict.reasons
            del result.accepted[name]
    return result


def hdpg_example() -> str:
    """The HD-PPO rule's source from its shipped one-rule repository (the prompt's example)."""
    source = HDPG_REPOSITORY.read_text()
    node = next(n for n in ast.parse(source).body if isinstance(n, ast.FunctionDef) and n.name == "hdpg")
    return cast(str, ast.get_source_segment(source, node))  # a parsed node has its position


def generate(cfg: Any, output_dir: Path) -> GenerationResult:
    """Runs the whole generation for a composed config (``cfg.task``, ``cfg.llm``); writes ``rules.py``."""
    llm_cfg, task = llm_and_task(cfg, "generate_rules")
    components = list(task["components"])
    messages = rule_generation_prompt(task, components, hdpg_example())
    if llm_cfg.replay_from:
        llm_cfg.replay_from = calls_log(llm_cfg.replay_from)
    client = LLMClient(llm_cfg, calls_path=RunDirectory(output_dir).llm_calls)
    reply = client.complete(messages, purpose="generate_rules")
    if reply.text is None:
        raise GenerationError(f"the LLM call failed: {reply.error}")
    constants: list[str] = []
    rules: dict[str, str] = {}
    problems: dict[str, list[str]] = {}
    for block in extract_code_blocks(reply.text):
        block_constants, block_rules, block_problems = split_rules(block)
        constants += block_constants
        problems.update(block_problems)
        for name, source in block_rules.items():
            if name in rules:
                problems[name] = ["defined twice; the first definition is kept"]
            else:
                rules[name] = source
    result = validate_rules(constants, rules)
    result.refused.update(problems)
    if not result.accepted:
        excerpt = " ".join(reply.text.split())[:200]
        result.refused.setdefault("<answer>", []).append(f"no rule was accepted; the answer began: {excerpt!r}")
    if result.accepted:
        result.path = output_dir / "rules.py"
        refused_lines = "".join(f"\n  - {name}: {'; '.join(reasons)}" for name, reasons in result.refused.items())
        header = (
            f'"""Rule repository generated by {llm_cfg.model} for task {task.get("name")}.\n\n'
            f"provenance: model={llm_cfg.model}, date={datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds')}, "
            f"prompt_hash={prompt_hash(messages)}, components={components}\n"
            f"refused rules: {len(result.refused)}{refused_lines}\n"
            '"""\n\n'
        )
        header = header.replace("\\", "/")  # reasons are quoted text; keep the docstring free of escapes
        result.path.write_text(
            header + HEADER_IMPORTS + "\n".join(constants) + "\n\n\n" + "\n\n\n".join(result.accepted.values()) + "\n"
        )
        load_repository(result.path, isolated=False)  # the file as written must load (its check ran in the child)
    return result


def _report(result: GenerationResult) -> None:
    print(f"accepted {len(result.accepted)} rule(s): {', '.join(result.accepted) or '-'}")
    for name, reasons in result.refused.items():
        print(f"refused {name}:")
        for reason in reasons:
            print(f"  - {reason}")
    if result.path is not None:
        print(f"repository written to {result.path} (use scheduler.rules={result.path})")


def run(cfg: DictConfig) -> int:
    """The command: generate into the output directory, print the outcome; exit status 1 if nothing was accepted."""
    llm_and_task(cfg, "generate_rules")  # refuse a missing LLM before creating the output directory
    result = generate(cfg, generation_output_dir(cfg, "rules"))
    _report(result)
    return 0 if result.accepted else 1
