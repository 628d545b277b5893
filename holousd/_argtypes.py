"""Argument types shared by the sub-commands (``type=`` callables for argparse)."""

from __future__ import annotations

import argparse

__all__ = ["positive_int", "resolution"]


def positive_int(text: str) -> int:
    """A whole number >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return value


def resolution(text: str) -> tuple[int, int]:
    """``WIDTHxHEIGHT`` in pixels, 16..4096 per side."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 320x240, got {text!r}") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise argparse.ArgumentTypeError(f"resolution {w}x{h} out of range; use 16..4096 pixels per side")
    return w, h
