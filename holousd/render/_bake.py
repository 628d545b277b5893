"""Colour baked onto a mesh from its Gaussian splats: what tools that do not read splats show.

Each mesh point takes the opacity- and distance-weighted mean of the view-independent colour (the degree-0 SH
term, ``0.5 + 0.28209 c_0``) of its nearest splats, converted from the captured (sRGB-encoded) values to the
linear RGB of ``primvars:displayColor``.
"""

from __future__ import annotations

import numpy as np

from holousd.render._binding import SH_C0, splats_in_world
from holousd.usd import GaussianSplats, MeshData, Pose

__all__ = ["linear_from_srgb", "vertex_colors"]


def linear_from_srgb(values: np.ndarray) -> np.ndarray:
    """The sRGB transfer function undone (IEC 61966-2-1), values in [0, 1]."""
    v = np.clip(np.asarray(values, np.float64), 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def vertex_colors(mesh: MeshData, splats: GaussianSplats, *, neighbours: int = 8) -> np.ndarray:
    """[P, 3] linear RGB per mesh point from the node's splats (object coordinates; bound splats are placed on
    ``mesh``). A mesh without splats comes out mid grey."""
    from scipy.spatial import cKDTree

    points = np.asarray(mesh.points, np.float64)
    if len(splats) == 0 or len(points) == 0:
        return np.full((len(points), 3), 0.5 ** 2.2)
    centres, _, scales = splats_in_world(splats, Pose(), mesh if splats.bound else None)
    srgb = np.clip(0.5 + SH_C0 * splats.sh_coeffs[:, 0, :].astype(np.float64), 0.0, 1.0)
    k = min(neighbours, len(centres))
    distance, index = cKDTree(centres).query(points, k=k)
    distance, index = distance.reshape(len(points), k), index.reshape(len(points), k)
    reach = np.maximum(scales.max(axis=1)[index], 1e-6)  # each splat's own size sets how far its colour carries
    weight = np.maximum(splats.opacities[index].astype(np.float64), 1e-3) * np.exp(-0.5 * (distance / reach) ** 2)
    weight[np.arange(len(points)), 0] += 1e-12  # the nearest splat decides where every weight vanishes
    colour = np.einsum("pk,pkc->pc", weight, srgb[index]) / weight.sum(axis=1, keepdims=True)
    return linear_from_srgb(colour)
