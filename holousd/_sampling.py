"""Evenly spread subsets of indices (frames, contact points, vertices)."""

from __future__ import annotations

import numpy as np

__all__ = ["evenly_spaced"]


def evenly_spaced(n: int, count: int) -> np.ndarray:
    """At most ``count`` indices spread evenly over ``range(n)``, first and last included; all of them when
    ``n <= count``. [K] int, ascending."""
    if n <= count:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, count).round().astype(int))
