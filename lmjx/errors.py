"""User-facing error types.

Every `LmjxError` is a mistake the user can fix (bad spec, bad path, bad file).  The CLI
prints its message on one line and exits with status 2; library callers can catch it.
The message says what is wrong and how to fix it.
"""


class LmjxError(Exception):
    """Base class of errors caused by user input."""


class FailureSpecError(LmjxError):
    """A failure spec names a joint that does not exist or an angle out of range."""


class ConfigError(LmjxError):
    """A configuration value (cell size, counts, ...) is out of range."""


class OutputPathError(LmjxError):
    """An output file cannot be written where asked."""


class MapFileError(LmjxError):
    """A map file is missing, truncated, of another schema or of another robot."""


class MixedRunsError(LmjxError):
    """Trials of runs whose conditions differ (commit, maps, planner, ...) would be pooled."""


class SceneError(LmjxError):
    """A scene file is missing, malformed, or describes a scene that cannot be set up (objects
    overlapping, off the table, through the arm's base; a goal the map does not reach)."""
