"""The auxiliary-reward prompt (our wording of the paper's appendix A, "Add Auxiliary reward").

Structure, as in the paper: the role; the task description and the task's reward code; an explanation
of each reward component; the requirements (add on top of the reward, do not change it) and the output
format. We add what the function receives (the ``obs`` dict with the shapes measured on real
transitions) and the sandbox's rules, so an answer can be accepted without guessing. A refused answer is
followed by :func:`aux_feedback_message` with the reasons, and the model revises its function.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from torchrl_ahrs.llm.prompts import SEPARATOR
from torchrl_ahrs.llm.task_text import component_meanings

AUX_FORMAT = """import torch


def compute_aux_reward(obs):
    # Thoughts: what the agent struggles with and how this reward helps (several lines).
    # obs["..."]: which entries are used and what they mean.
    ...
    return aux  # a float tensor of shape [N]"""


def components_section(task: Mapping[str, Any], components: Sequence[str]) -> str:
    """One line per reward component, with ``task.component_descriptions`` when the task gives them."""
    lines = [f"Explanation of each reward component ({len(components)} in total, summed into the reward):"]
    for index, (name, meaning) in enumerate(component_meanings(task, components).items(), start=1):
        lines.append(f"{index}. {name}" + (f": {meaning}" if meaning else " (see the reward code above)"))
    return "\n".join(lines)


def inputs_section(input_shapes: Mapping[str, Sequence[int]], observation_code: str | None) -> str:
    """What ``compute_aux_reward(obs)`` receives: each key with its per-row shape."""
    lines = [
        "Input: the function is called once per environment step for N environments at once with one argument, "
        "`obs`, a dict of float32 torch tensors whose first dimension is N:"
    ]
    for name, shape in input_shapes.items():
        per_row = tuple(shape[1:])
        lines.append(f'- obs["{name}"]: shape [N' + "".join(f", {size}" for size in per_row) + "]")
    lines.append(
        'obs["observation"] is the state after the step, obs["action"] the action that led to it, obs["reward.<c>"] '
        'the value of reward component c at this step (obs["reward.total"] their sum), obs["info.<k>"] extra '
        "entries the simulator reports."
    )
    if observation_code:
        lines.append(
            "The observation vector is assembled by this code:\n```python\n" + observation_code.strip() + "\n```"
        )
    return "\n".join(lines)


def aux_reward_prompt(
    task: Mapping[str, Any],
    components: Sequence[str],
    reward_code: str | None,
    input_shapes: Mapping[str, Sequence[int]],
    observation_code: str | None = None,
) -> list[dict[str, str]]:
    """The "Add Auxiliary reward" prompt; the answer is one ```python block defining ``compute_aux_reward(obs)``.

    Example:
        >>> messages = aux_reward_prompt({"name": "toy", "description": "Walk forward."}, ["forward"],
        ...                              "def reward(v):\\n    return v", {"observation": (8, 3)})
        >>> "compute_aux_reward(obs)" in messages[0]["content"], "[N, 3]" in messages[0]["content"]
        (True, True)
    """
    robot = str(task.get("name", "robot"))
    description = str(task.get("description", "")).strip() or f"the {robot} task"
    code = (
        "```python\n" + reward_code.strip() + "\n```"
        if reward_code
        else "The reward is computed inside the simulator; each component's value is given to you at every step "
        '(obs["reward.<c>"]).'
    )
    content = "\n".join(
        [
            f"You are an expert in reinforcement learning. Help me write an auxiliary reward function that makes an "
            f"agent learn the {robot} task faster with reinforcement learning.",
            SEPARATOR,
            f"Task description: {description}",
            "The task's reward function (the auxiliary reward comes on top of it):",
            code,
            SEPARATOR,
            components_section(task, components),
            SEPARATOR,
            "Requirements: write one auxiliary reward function based on the reward above that helps the agent do its "
            "task better. It must not change or replace the existing components: it is added as one more component, "
            "learnt by its own value head, and its weight is scheduled during training like the others. Keep its "
            "magnitude comparable to the existing components.",
            inputs_section(input_shapes, observation_code),
            "Output requirements:\n"
            "1. Python 3 with torch, vectorised over the N environments (no Python loop over environments); return a "
            "finite float tensor of shape [N] for every possible input (guard divisions and logarithms).\n"
            "2. Only `import torch` and `import math` are allowed. No other imports, no file, network or system "
            "access, no names or attributes starting with an underscore, no while loops, lambdas, classes, nested "
            "functions or try blocks. Helper functions, if any, go at the top level of the code block.\n"
            "3. Explain your thoughts, the objective and the implementation in comments inside the code.\n"
            "4. Output one ```python code block and nothing outside it, in this format:\n```python\n"
            + AUX_FORMAT
            + "\n```",
            SEPARATOR,
            "I will check the function in a sandbox and run it on real transitions of the task, then use the reward "
            "function to train an RL agent and test it in the environment. I will tell you why it failed, or how "
            "training went (each component's episode returns), and you should modify the reward function "
            "accordingly.",
        ]
    )
    return [{"role": "user", "content": content}]


def training_feedback_message(round_text: str) -> dict[str, str]:
    """After a short training round with the candidate: each component's statistics, then a request for a
    better function (the paper's "I will use the reward function to train an RL agent and test it").

    Example:
        >>> training_feedback_message("return/total: 12.5")["content"].splitlines()[0]
        'I trained an agent with your auxiliary reward added as one more component. Results:'
    """
    return {
        "role": "user",
        "content": "I trained an agent with your auxiliary reward added as one more component. Results:\n"
        + round_text.strip()
        + "\nThe goal is a higher return/total (the task's own reward, without the auxiliary term) reached "
        "sooner. Analyse which components lag and why, then reply with an improved complete function "
        "`compute_aux_reward(obs)` in one ```python code block and nothing else.",
    }


def aux_feedback_message(reasons: Sequence[str]) -> dict[str, str]:
    """The follow-up after a refused answer: every reason, and a request for the whole corrected function."""
    listed = "\n".join(f"- {reason}" for reason in reasons)
    return {
        "role": "user",
        "content": "Your auxiliary reward function could not be used:\n"
        + listed
        + "\nCorrect it and reply with the complete function `compute_aux_reward(obs)` in one ```python code block "
        "and nothing else.",
    }
