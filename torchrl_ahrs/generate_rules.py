"""Rule generator: ``python -m torchrl_ahrs.generate_rules task=<task> llm=openai [llm.model=<model>]``.

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
import re
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from torchrl_ahrs.llm.client import LLMClient, LLMConfig, prompt_hash
from torchrl_ahrs.llm.generation import generation_output_dir
from torchrl_ahrs.llm.prompts import rule_generation_prompt
from torchrl_ahrs.sandbox import check_source, validate_in_child
from torchrl_ahrs.scheduling.rules import DEFAULT_REPOSITORY, RULE_ARITY, load_repository

_CODE_BLOCK = re.compile(r"```[ \t]*(?:python|py)?[ \t]*\n(.*?)```", re.DOTALL)
HEADER_IMPORTS = "import math\n\nimport torch\n"


@dataclass
class GenerationResult:
    """Accepted rule sources (name → source) and refusals (name → reasons)."""

    accepted: dict[str, str] = field(default_factory=dict)
    refused: dict[str, list[str]] = field(default_factory=dict)
    path: Path | None = None


def extract_code_blocks(text: str) -> list[str]:
    """Fenced code blocks of an answer (```python ... ```); the whole text if there is no fence."""
    blocks = _CODE_BLOCK.findall(text)
    return blocks if blocks else [text]


def split_rules(block: str) -> tuple[list[str], dict[str, str], dict[str, list[str]]]:
    """A code block → (module-level constant lines, {rule name: function source}, {name: parse problems})."""
    try:
        tree = ast.parse(block)
    except SyntaxError as error:
        return [], {}, {f"<block at line {error.lineno}>": [f"syntax error: {error.msg}"]}
    constants = [
        ast.get_source_segment(block, node) for node in tree.body if isinstance(node, (ast.Assign, ast.AnnAssign))
    ]
    rules, problems = {}, {}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef):
            source = ast.get_source_segment(block, node)
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
    """The HD-PPO rule's source from the shipped repository (the prompt's example)."""
    source = DEFAULT_REPOSITORY.read_text()
    node = next(n for n in ast.parse(source).body if isinstance(n, ast.FunctionDef) and n.name == "hdpg")
    return ast.get_source_segment(source, node)


def generate(cfg: Any, output_dir: Path) -> GenerationResult:
    """Runs the whole generation for a composed config (``cfg.task``, ``cfg.llm``); writes ``rules.py``."""
    llm_cfg = LLMConfig.from_cfg(OmegaConf.to_container(cfg.llm, resolve=True))
    if not llm_cfg.model and not llm_cfg.replay_from:
        raise SystemExit("generate_rules needs an LLM: pass llm=openai (or llm.model=... llm.api_base=...)")
    task = OmegaConf.to_container(cfg.task, resolve=True)
    components = list(task["components"])
    messages = rule_generation_prompt(task, components, hdpg_example())
    client = LLMClient(llm_cfg, run_dir=output_dir)
    reply = client.complete(messages, purpose="generate_rules")
    if reply.text is None:
        raise SystemExit(f"the LLM call failed: {reply.error}")
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
        load_repository(result.path)  # the file as written must load
    return result


def _report(result: GenerationResult) -> None:
    print(f"accepted {len(result.accepted)} rule(s): {', '.join(result.accepted) or '-'}")
    for name, reasons in result.refused.items():
        print(f"refused {name}:")
        for reason in reasons:
            print(f"  - {reason}")
    if result.path is not None:
        print(f"repository written to {result.path} (use scheduler.rules={result.path})")


def main() -> None:
    import hydra

    @hydra.main(config_path="pkg://torchrl_ahrs.conf", config_name="config", version_base="1.3")
    def _entry(cfg) -> None:
        output_dir = generation_output_dir(cfg, "rules")
        result = generate(cfg, output_dir)
        _report(result)
        if not result.accepted:
            sys.exit(1)

    _entry()


if __name__ == "__main__":
    main()
