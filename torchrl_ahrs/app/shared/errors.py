"""The one error type of the application layer."""


class ConfigError(ValueError):
    """A config value that cannot work; the message names the field and the accepted values."""
