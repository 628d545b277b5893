"""Keep Warp's informational output off the command line's stdout."""

from __future__ import annotations

__all__ = ["quiet_warp"]


def quiet_warp() -> None:
    """Send only Warp's warnings and errors to the console: its init banner and per-module load lines go to
    stdout and would break the CLI's JSON output. For the ``holousd`` command only (library users keep Warp's own
    settings); a no-op where Warp is not installed."""
    try:
        import warp as wp
    except ImportError:
        return
    wp.config.log_level = wp.LOG_WARNING
