"""Prompt templates (our wording of the AHRS paper's appendix A, following its structure).

* :func:`rule_selection_prompt` — "Rules' selection": task description, each component's meaning,
  framework, environment code, each component's reward code, the rules, the current and historical
  statistics and weights; the answer is ``~[N]~``.
* :func:`direct_weights_prompt` — AHRS-D: the same material, but the answer is K weights ``~[w1, ..., wK]~``.
* :func:`rule_generation_prompt` — "Build rule repository": task, components with meanings and reward
  code, the HD-PPO rule as the example; the answer is Python code blocks in the repository format.

Task text (description, meanings, reward and environment code read from our implementation with
``inspect.getsource``) comes from :mod:`torchrl_ahrs.llm.task_text`.
* :func:`correction_message` — the one corrective retry after an unreadable answer.

Each ``*_prompt`` returns chat messages ``[{"role": ..., "content": ...}]``; the exact text is
deterministic for given inputs, so the cache and replay can match it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from torchrl_ahrs.llm.task_text import component_meanings, environment_code, reward_code_blocks

SEPARATOR = "=" * 36

INTRO = (
    "You are helping to train a robot with reinforcement learning. Treat this as an optimisation problem "
    "and reason about it carefully before you answer."
)

FRAMEWORK = (
    "Training uses Proximal Policy Optimization (PPO) with the reward split into {k} components. Each "
    "component has its own value head, so each has its own advantage estimate A_k. The policy is updated with "
    "the weighted advantage sum_k w_k * A_k. A weight rule turns the statistics of each component's episode "
    "returns into scores s_k, and the weights are {mapping}. Changing the weights changes which skills the "
    "policy improves first."
)


def _framework(k: int, base: float, mapping_text: str | None) -> str:
    mapping = mapping_text or f"w_k = {base} + n_k with n_k >= 0, sum_k n_k = 1 (n: the scores normalised)"
    return "Algorithm framework: " + FRAMEWORK.format(k=k, mapping=mapping)


def _fmt(values: Sequence[float]) -> str:
    return "[" + ", ".join(f"{float(value):.4g}" for value in values) + "]"


def task_section(task: Mapping[str, Any], components: Sequence[str]) -> str:
    """Task description and the components' meanings (``task.component_descriptions``; ``aux`` explained).

    Example:
        >>> print(task_section({"description": "Walk.", "component_descriptions": {"v": "speed"}}, ["v"])[:40])
        Task description: Walk.
        The reward has 1
    """
    lines = [f"Task description: {str(task.get('description', task.get('name', 'a robot task'))).strip()}"]
    lines.append(f"The reward has {len(components)} components, in this order. Their physical meanings:")
    for index, (name, meaning) in enumerate(component_meanings(task, components).items(), start=1):
        lines.append(f"{index}. {name}" + (f": {meaning}" if meaning else ""))
    lines.append(
        "How much each component matters changes over training, so adjusting their weights from stage to stage "
        "can make learning faster."
    )
    return "\n".join(lines)


def environment_section(task: Mapping[str, Any]) -> str:
    """Environment description: the source of ``task.environment_code`` (how the observation is built)."""
    text = environment_code(task)
    return f"Environment description (the observation the policy sees):\n```python\n{text.strip()}\n```" if text else ""


def reward_code_section(task: Mapping[str, Any], components: Sequence[str], aux_path: str | Path | None = None) -> str:
    """Reward code of each component, read from the implementation (``task.reward_code``) and the aux file."""
    blocks = reward_code_blocks(task, components, aux_path)
    if not blocks:
        return "Reward code: computed inside the simulator; the meanings above describe each component."
    parts = ["Reward code of each component (the code that computes it in this training run):"]
    for names, source in blocks:
        label = ", ".join(f"{components.index(name) + 1}. {name}" for name in names)
        parts.append(f"Components {label}:\n```python\n{source.strip()}\n```")
    return "\n".join(parts)


def statistics_section(components: Sequence[str], context: Any) -> str:
    """Current means, variances and weights, then the earlier summaries (oldest first)."""
    lines = [
        f"Current data (episode returns since the last decision, {context.summary.count} episodes):",
        f"Components: {list(components)}",
        f"Mean returns: {_fmt(context.summary.mean)}",
        f"Variance of returns: {_fmt(context.summary.var)}",
        f"Weights in force: {_fmt(context.previous_weights.tolist())}",
    ]
    earlier = [summary for summary in context.past if summary is not context.summary]
    if earlier:
        lines.append(SEPARATOR)
        lines.append("Earlier periods (oldest first):")
        for index, summary in enumerate(earlier, start=1):
            rule = f"rule {summary.rule_id}" if summary.rule_id is not None else "no rule"
            lines.append(
                f"{index}. mean {_fmt(summary.mean)}, variance {_fmt(summary.var)}, weights {_fmt(summary.weights)}, {rule}"
            )
    else:
        lines.append("There is no earlier period yet.")
    return "\n".join(lines)


def _join(*sections: str) -> str:
    return f"\n{SEPARATOR}\n".join(section for section in sections if section)


def rule_selection_prompt(
    task: Mapping[str, Any],
    components: Sequence[str],
    rules_text: str,
    num_rules: int,
    context: Any,
    base_weight: float,
    interval: int,
    mapping_text: str | None = None,
    aux_path: str | Path | None = None,
) -> list[dict[str, str]]:
    """The "Rules' selection" prompt; the answer is one serial number ``~[N]~``.

    ``mapping_text`` states how scores become weights (``WeightMapping.describe()``); ``aux_path`` is
    the auxiliary reward file whose code is shown for component ``aux``.
    """
    previous = (
        f"{interval} training iterations ago you chose rule {context.previous_rule_id}, and its weights were used "
        "since then. Take that into account."
        if context.previous_rule_id is not None
        else "This is the first choice of this run."
    )
    content = _join(
        INTRO,
        task_section(task, components),
        _framework(len(components), base_weight, mapping_text),
        environment_section(task),
        reward_code_section(task, components, aux_path),
        "Goal: look at the mean returns, variances and weights of every component, now and in earlier periods. "
        "Think step by step about which components need attention at this stage, weigh the strengths and "
        "weaknesses of each rule below, and choose the rule that will help the next period of training most.",
        "Proposed rules:\n" + rules_text + "\nChoose the best rule and give its serial number.",
        "Additional context: " + previous,
        f"Output format: put the serial number between tildes and brackets, e.g. ~[1]~. It must be one integer from "
        f"1 to {num_rules}.",
        statistics_section(components, context),
    )
    return [{"role": "user", "content": content}]


def direct_weights_prompt(
    task: Mapping[str, Any],
    components: Sequence[str],
    context: Any,
    base_weight: float,
    interval: int,
    aux_path: str | Path | None = None,
) -> list[dict[str, str]]:
    """AHRS-D: the LLM gives the K shares directly, ``~[w1, ..., wK]~`` (non-negative, normalised by us)."""
    k = len(components)
    content = _join(
        INTRO,
        task_section(task, components),
        _framework(k, base_weight, f"w_k = {base_weight} + n_k with n_k your answer divided by its sum"),
        environment_section(task),
        reward_code_section(task, components, aux_path),
        "Goal: look at the mean returns, variances and weights of every component, now and in earlier periods. "
        f"Think step by step and propose how much each component should count for the next {interval} training "
        "iterations.",
        f"Output format: {k} non-negative numbers, one per component in the order given, between tildes and "
        f"brackets, e.g. ~[{', '.join(['1.0'] * k)}]~. They are divided by their sum to give n_k.",
        statistics_section(components, context),
    )
    return [{"role": "user", "content": content}]


def correction_message(reason: str, expected: str) -> dict[str, str]:
    """The single corrective follow-up after an unreadable answer."""
    return {
        "role": "user",
        "content": f"Your answer could not be used: {reason}. Reply again with only {expected} and nothing else.",
    }


RULE_FORMAT = '''def rule_name(mean_returns, var_returns, history, previous_weights):
    """Short Rule Name

    One or two sentences on what the rule prioritises and why.

    math: s_k = <the formula in one line>
    """
    return <raw scores, a tensor of shape [K]>'''


def rule_generation_prompt(
    task: Mapping[str, Any], components: Sequence[str], example_source: str, count: int = 6
) -> list[dict[str, str]]:
    """The "Build rule repository" prompt; the answer is Python code blocks of rules in our repository format."""
    content = _join(
        INTRO,
        "Task: you are an expert in reinforcement learning. Work out how the weights of the reward components "
        "should be adjusted during training so that the robot learns its task better.\n"
        + task_section(task, components),
        _framework(len(components), 0.5, None),
        environment_section(task),
        reward_code_section(task, components),
        f"Goal: think step by step and write at least {count} useful weight rules. Each rule is a formula that "
        "turns statistics of the components' episode returns into raw scores, one per component; a higher score "
        "means more weight. Then write each rule as a Python function.",
        "Inputs of every rule (torch tensors, K components, L earlier periods):\n"
        "- mean_returns [K]: mean episode return of each component in the current period\n"
        "- var_returns [K]: variance of those returns\n"
        "- history [L, K]: earlier mean returns, oldest first (history[-1] is the previous period)\n"
        "- previous_weights [K]: the weights in force\n"
        "The scores are mapped to weights afterwards (normalised across components), so their scale should not "
        "matter, but they must be finite for any finite input.",
        "Here is an example rule (the one HD-PPO uses) to build on:\n```python\n" + example_source.strip() + "\n```",
        "Code requirements: one function per rule in the exact format below; only `import torch` and `import "
        "math` are allowed; no other imports, no file or network access, no loops over data-dependent ranges, "
        "no names starting with an underscore. Put all functions in one ```python code block.\n```python\n"
        + RULE_FORMAT
        + "\n```",
        "Tips: simple hyper-parameters or a different normalisation of the inputs can make a rule more useful.",
    )
    return [{"role": "user", "content": content}]
