"""The ``generate_rules`` and ``generate_aux`` commands: LLM-written rule repositories and auxiliary rewards."""
