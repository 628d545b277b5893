"""Exceptions raised by holousd.

Every error a user can cause (bad file, bad argument, inconsistent data) is a :class:`HolousdError` whose message
is one line that names the file or prim and says how to fix it. The CLI prints that line and exits non-zero.
"""

from __future__ import annotations

__all__ = ["HolousdError", "InvalidDataError", "SceneError", "SchemaVersionError"]


class HolousdError(Exception):
    """Base class of all user-facing holousd errors (one-line message naming the culprit and the fix)."""


class SceneError(HolousdError):
    """A scene file or prim is missing, unreadable or inconsistent."""


class SchemaVersionError(SceneError):
    """A scene was written with a holousd schema version this release cannot read."""


class InvalidDataError(HolousdError, ValueError):
    """Arrays handed to holousd have the wrong shape, dtype or non-finite values."""
