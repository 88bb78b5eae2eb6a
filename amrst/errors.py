"""Exceptions raised by the engine. The CLI and the app show their messages as they are."""

from __future__ import annotations

#: Exit codes of every ``amrst`` command: bad input (one line says what to change); a
#: result that is not *registered* (failed, or needs review: check it before use);
#: cancelled.
EXIT_INPUT, EXIT_NOT_REGISTERED, EXIT_CANCELLED = 2, 3, 130


class AmrstError(Exception):
    """Base class: a message a user can act on (what is wrong, what to do)."""


class InvalidInput(AmrstError):
    """A file or an array the engine cannot use (missing, empty, corrupt, too few points)."""


class RegistrationFailed(AmrstError):
    """The scans could not be registered (too few key points, no verified candidate)."""


class Cancelled(AmrstError):
    """The user asked the running stage to stop."""

    def __init__(self, message: str = "Cancelled by the user.") -> None:
        super().__init__(message)
