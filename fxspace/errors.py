"""Errors raised by fxspace.

Every error is a ``ValueError`` subclass, so ``except ValueError`` keeps working, and
each message names the offending argument (or file) and what to do about it.
"""

from __future__ import annotations

__all__ = [
    "FxspaceError",
    "CorruptFileError",
    "DisconnectedGraphError",
    "DataNotFoundError",
    "NotAFileError",
]


class FxspaceError(ValueError):
    """Base class of fxspace's errors (a ``ValueError``)."""


class CorruptFileError(FxspaceError):
    """A file is truncated, malformed or not of the format its extension claims."""


class DisconnectedGraphError(FxspaceError):
    """A neighbourhood graph has more than one connected component."""


class DataNotFoundError(FxspaceError, FileNotFoundError):
    """The real capture data (``FXSPACE_DATA``) or one of its files is absent."""


class NotAFileError(FxspaceError, IsADirectoryError):
    """A path given as a file to read is a directory (an ``IsADirectoryError`` too)."""
