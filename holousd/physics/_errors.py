"""Errors raised by the physics domain."""

from __future__ import annotations

from holousd._errors import SceneError

__all__ = ["PhysicsInputError"]


class PhysicsInputError(SceneError, ValueError):
    """A scene or argument the physics domain cannot use.

    The message is one line that names the file or prim at fault and says how to fix it, so the CLI can print
    it as is.
    """
