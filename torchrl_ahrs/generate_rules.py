"""``python -m torchrl_ahrs.generate_rules task=<task> llm=openai [llm.model=<model>]``: an LLM-written rule repository.

The generation is :mod:`torchrl_ahrs.app.generate.rules`; this entry point composes the Hydra config and
turns a missing or failing LLM into one line on stderr. Exit status 0 when at least one rule was accepted.
"""

from __future__ import annotations

from torchrl_ahrs.app.generate.rules import generate, run
from torchrl_ahrs.app.shared.cli import hydra_command
from torchrl_ahrs.llm.generation import GenerationError

__all__ = ["generate", "main"]

main = hydra_command("generate_rules", "config", run, {GenerationError: (1, "{}")})

if __name__ == "__main__":
    main()
