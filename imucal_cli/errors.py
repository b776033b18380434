"""Exceptions that carry a one-line message for the user and the exit code the CLI returns.

Every layer raises these for problems a user can fix (bad file, bad config, a design that
cannot determine the model, a solve that cannot converge).  The CLI prints ``str(exc)`` on one
line and exits with ``exc.exit_code``; nothing else in the package prints or exits.
"""

from __future__ import annotations


class ImucalError(Exception):
    """Base class: a user-facing problem.  ``exit_code`` is what the CLI returns."""

    exit_code = 2


class InputError(ImucalError):
    """Bad input: unreadable or malformed file, bad option, or data that cannot determine
    the model.  Exit code 2."""

    exit_code = 2


class SessionError(InputError):
    """A session file that does not follow the session format (message names the file)."""


class WriteFailed(SessionError):
    """Samples could not be written to a session (disk full, I/O error).

    Attributes
    ----------
    pending : int
        Samples appended but not written (still in memory, or given up when closing).
    reason : str
        Why, in a few words (``No space left on device``).
    """

    def __init__(self, message: str, pending: int = 0, reason: str = "") -> None:
        super().__init__(message)
        self.pending = pending
        self.reason = reason or message


class CalibrationFileError(InputError):
    """A calibration JSON that does not follow the calibration format."""


class ConfigError(InputError):
    """A TOML config with an unknown key or a value of the wrong kind."""


class DesignError(InputError):
    """The recorded poses/rotations cannot determine the requested model.

    The message says what to capture more of.
    """


class SolverError(ImucalError):
    """The solver ran but did not produce a result worth saving (no convergence, or a result
    outside physical sense).  Exit code 1."""

    exit_code = 1


class ImucalWarning(UserWarning):
    """Something the user should know that does not stop the command (a file repaired, data
    dropped).  Library code issues it with :func:`warnings.warn`; the CLI prints it on one line
    as ``imucal: warning: ...``."""
