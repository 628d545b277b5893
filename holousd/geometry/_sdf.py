"""Signed distance grids from triangle meshes (exact distances, sign from convex parts)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from holousd.usd._types import MeshData, SdfField

__all__ = ["point_triangle_distance", "sdf_from_convex_parts"]


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Exact Euclidean distance from each point to the nearest of the triangles.

    Uses the closest-point-on-triangle case analysis (vertex, edge and face regions) in vectorised numpy.

    Args:
        points: [P, 3] query points.
        triangles: [T, 3, 3] triangle vertices.
        chunk: Points processed per batch (bounds memory to chunk * T * 3 floats per temporary).

    Returns:
        [P] distances.
    """
    points = np.asarray(points, dtype=np.float64)
    a, b, c = (np.asarray(triangles, dtype=np.float64)[:, i][None] for i in range(3))  # [1, T, 3]
    ab, ac = b - a, c - a
    out = np.empty(len(points))
    for start in range(0, len(points), chunk):
        p = points[start : start + chunk, None, :]  # [B, 1, 3]
        ap, bp, cp = p - a, p - b, p - c
        d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
        d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
        d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
        va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
        with np.errstate(divide="ignore", invalid="ignore"):
            denom = 1.0 / (va + vb + vc)
            v_face, w_face = vb * denom, vc * denom
            t_ab = d1 / (d1 - d3)
            t_ac = d2 / (d2 - d6)
            t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        closest = a + ab * v_face[..., None] + ac * w_face[..., None]
        regions = [
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * t_bc[..., None]),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * t_ac[..., None]),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * t_ab[..., None]),
            ((d6 >= 0) & (d5 <= d6), np.broadcast_to(c, closest.shape)),
            ((d3 >= 0) & (d4 <= d3), np.broadcast_to(b, closest.shape)),
            ((d1 <= 0) & (d2 <= 0), np.broadcast_to(a, closest.shape)),
        ]
        for mask, value in regions:  # later entries (vertex regions) take precedence, as in the case analysis
            closest = np.where(mask[..., None], value, closest)
        out[start : start + chunk] = np.sqrt(((p - closest) ** 2).sum(-1)).min(axis=1)
    return out


def _inside_convex(points: np.ndarray, part: MeshData) -> np.ndarray:
    tri = part.points[part.faces]  # [F, 3, 3]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    offsets = (normals * tri[:, 0]).sum(-1)
    return np.all(points @ normals.T <= offsets + 1e-12, axis=1)


def sdf_from_convex_parts(
    mesh: MeshData, parts: Sequence[MeshData], *, voxel_size: float, padding: int = 2
) -> SdfField:
    """Sample the signed distance to ``mesh`` on a grid covering it, negative inside.

    Distances are exact (to ``mesh``'s triangles); the sign comes from ``parts``, closed convex meshes whose
    union is the solid (a single convex hull for convex objects).

    Args:
        mesh: Surface whose distance is sampled.
        parts: Convex, outward-oriented closed meshes whose union is the inside of ``mesh``.
        voxel_size: Grid spacing, metres.
        padding: Extra samples beyond the mesh bounds on every side.
    """
    lo, hi = mesh.bounds
    origin = lo - padding * voxel_size
    res = np.ceil((hi - lo) / voxel_size).astype(int) + 1 + 2 * padding
    axes = [origin[i] + voxel_size * np.arange(res[i]) for i in range(3)]
    grid_points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)  # [X*Y*Z, 3]
    dist = point_triangle_distance(grid_points, mesh.points[mesh.faces])
    inside = np.zeros(len(grid_points), dtype=bool)
    for part in parts:
        inside |= _inside_convex(grid_points, part)
    dist[inside] *= -1.0
    return SdfField(grid=dist.reshape(tuple(res)).astype(np.float32), origin=origin, voxel_size=voxel_size)
