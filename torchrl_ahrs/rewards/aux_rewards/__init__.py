"""Auxiliary rewards shipped with the project, one file per task (``<task>.py``).

Each file is sandbox data, not a module to import: it is loaded through the sandbox like a file an LLM
wrote (``torchrl_ahrs.rewards.auxiliary.load_aux_function``) and defines
``compute_aux_reward(obs: dict[str, Tensor [N, ...]]) -> Tensor [N]``. They are used when no LLM
generated one (``llm=offline``); ``aux.path=<file>`` replaces them.
"""
