"""What several commands share: config checks and settings, the run directory, redaction, the auxiliary
reward's wiring, the error type and ``hydra_command``."""
