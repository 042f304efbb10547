"""The exception family: one root, so callers can catch everything groundstation raises."""


class GroundstationError(Exception):
    """Root of every exception groundstation raises on purpose."""


class ConfigError(GroundstationError):
    """Invalid configuration; ``key`` names the offending setting."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"configuration error: {key}: {message}")
        self.key = key
        self.message = message


class InputError(GroundstationError):
    """An input file or stream that cannot be used (missing, unreadable, unknown format)."""


class DecodeError(GroundstationError):
    """A frame that passed its checksum but could not be decoded."""


class SourceError(GroundstationError):
    """A byte source failed in a way reconnecting will not fix."""
