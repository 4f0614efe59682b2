"""Everything that speaks to or hears from an LLM.

* :mod:`~torchrl_ahrs.llm.client` — one client over litellm (timeouts, retries, JSONL call log, cache, replay).
* :mod:`~torchrl_ahrs.llm.prompts` — the paper's prompts in our words (rule selection, direct weights, rule generation).
* :mod:`~torchrl_ahrs.llm.answers` — parsers of the answers (``~[N]~``, ``~[w1, ..., wK]~``).
"""
