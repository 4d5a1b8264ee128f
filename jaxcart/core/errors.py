"""The error a bad configuration raises, in a module that imports no JAX, so that the commands
can catch it before (or without) importing JAX."""

from __future__ import annotations


class ConfigError(ValueError):
    """A configuration value a user gave is invalid; the message says what to change.

    ``option`` names the setting when the message starts with it (``num_seeds must be ...``),
    so a command line can say ``--num-seeds must be ...`` instead.
    """

    def __init__(self, message: str, option: str | None = None) -> None:
        super().__init__(message)
        self.option = option
