"""``python -m torchrl_ahrs.generate_aux task=<task> llm=openai [llm.model=<model>]``: an LLM-written auxiliary reward.

The generation is :mod:`torchrl_ahrs.app.generate.aux`; this entry point composes the Hydra config and
turns a missing or failing LLM into one line on stderr. Exit status 0 when a function was accepted.
"""

from __future__ import annotations

from torchrl_ahrs.app.generate.aux import generate, run
from torchrl_ahrs.app.shared.cli import hydra_command
from torchrl_ahrs.llm.generation import GenerationError

__all__ = ["generate", "main"]

main = hydra_command("generate_aux", "config", run, {GenerationError: (1, "{}")})

if __name__ == "__main__":
    main()
