"""Convex hulls, convex parts cut by planes, convexity and CoACD convex decomposition (collision approximation).

Collision approximation is geometry (ARCHITECTURE.md puts it in this domain): the physics domain builds its
colliders from these, and the physics set-ups derive an object's collider from its mesh with them. Meshes are
``(points [N, 3], faces [F, 3])`` pairs; parts are lists of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "DecompositionConfig",
    "convex_decomposition",
    "convex_hull",
    "convexity",
    "cut_above",
    "cut_axis",
    "cut_plane",
    "cut_below",
    "limited_hull",
    "PHYSX_HULL_VERTEX_LIMIT",
]

PHYSX_HULL_VERTEX_LIMIT = 64
"""PhysX cooks a convex collider of at most this many vertices by default (Omni PhysX's ``hullVertexLimit``, also its
GPU collision's limit; 255 the most it cooks): a part whose hull has more is simplified by the simulator, not
simulated as authored. The set-up's default limit and ``holousd validate``'s note both use it."""

ColliderParts = list[tuple[np.ndarray, np.ndarray]]
"""Convex parts, each ``(points [N, 3], faces [F, 3])``."""


@dataclass(kw_only=True)
class DecompositionConfig:
    """CoACD settings for convex decomposition.

    CoACD (Wei et al., SIGGRAPH 2022) is chosen over V-HACD because it is maintained, deterministic for a given
    seed, and *collision-aware*: it cuts along concave features measured by a Hausdorff-based concavity, so
    parts do not bridge openings (a bowl's cavity stays open), which is what contact needs. V-HACD's
    voxel-based parts tend to fill cavities and is no longer developed.
    """

    threshold: float = 0.08
    """Concavity tolerance of each part, relative to the object size (smaller = more, tighter parts)."""
    max_parts: int = 16
    """Upper bound on the number of parts (-1 = no bound); parts are merged to meet it."""
    max_part_vertices: int = 64
    """Vertex cap per part hull."""
    preprocess_resolution: int = 40
    """Voxel resolution of CoACD's manifold pre-processing."""
    resolution: int = 2000
    """Surface samples of CoACD's concavity metric (CoACD's default; 500 is about 5x faster on fitted meshes)."""
    mcts_iterations: int = 150
    """Iterations of CoACD's Monte-Carlo tree search for each cut (CoACD's default)."""
    mcts_nodes: int = 20
    """Child nodes expanded per tree-search step (CoACD's default)."""
    mcts_max_depth: int = 3
    """Depth of the cut search (CoACD's default)."""
    seed: int = 0
    """Random seed of CoACD's tree search (local to the call; no global seeding)."""


def _as_arrays(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(points, dtype=np.float64).reshape(-1, 3), np.asarray(faces, dtype=np.int64).reshape(-1, 3)


def convex_hull(points: np.ndarray, faces: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Convex hull of a mesh (or point cloud): ``(points [N, 3], faces [F, 3])`` with outward winding."""
    import trimesh

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    hull = trimesh.convex.convex_hull(pts)
    return np.asarray(hull.vertices, dtype=np.float64), np.asarray(hull.faces, dtype=np.int64)


def limited_hull(
    points: np.ndarray, max_vertices: int = PHYSX_HULL_VERTEX_LIMIT
) -> tuple[np.ndarray, np.ndarray, float]:
    """The convex hull of ``points`` with at most ``max_vertices`` vertices, all of them vertices of the full hull:
    from the vertices of its lowest and highest level faces (at most a quarter of ``max_vertices`` each, evenly round
    the face) and the extreme points along the axes, the vertex farthest outside the hull of those chosen so far is
    added until that many are chosen or none lies outside (an inner approximation: it lies inside the full hull).
    Returns ``(points [N, 3], faces [F, 3])`` with outward winding, and how far the farthest of ``points`` lies
    outside it, metres (0 and the full hull when that has at most ``max_vertices`` vertices).

    PhysX cooks a convex collider of at most 64 vertices by default (Omni PhysX's ``hullVertexLimit``; 64 is also
    its GPU collision's limit, 255 the most it cooks), from the vertices it is given: a hull authored with more is
    replaced by one of PhysX's choosing. One authored within the limit is cooked as it is."""
    from scipy.spatial import ConvexHull, QhullError

    if max_vertices < 8:
        raise ValueError(f"limited_hull: max_vertices must be at least 8, got {max_vertices}")
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    full = ConvexHull(pts)
    vertices = pts[full.vertices]
    if len(vertices) <= max_vertices:
        hull = convex_hull(vertices)
        return hull[0], hull[1], 0.0
    chosen = sorted({int(i) for i in (*np.argmin(vertices, axis=0), *np.argmax(vertices, axis=0))})
    # the vertices of its lowest and highest level faces (a base it stands on, a top cut flat under what rests on
    # it) while they leave room for the rest: a greedy choice of the farthest kept a lumpy ball's bumps and cut the
    # corners of its flat base, and it rolled
    level = np.abs(full.equations[:, 2]) >= 1.0 - 1e-6
    for side in (-1.0, 1.0):
        if not (level & (np.sign(full.equations[:, 2]) == side)).any():
            continue
        height = vertices[:, 2].min() if side < 0 else vertices[:, 2].max()
        flat = np.flatnonzero(np.abs(vertices[:, 2] - height) <= 1e-7)
        if len(flat) < 3:
            continue
        centre = vertices[flat, :2].mean(axis=0)
        flat = flat[np.argsort(np.arctan2(*(vertices[flat, :2] - centre).T[::-1]), kind="stable")]  # around it
        room = max_vertices // 4  # at most a quarter of the vertices for each: evenly round the polygon
        if len(flat) > room:
            flat = flat[np.unique(np.floor(np.linspace(0, len(flat), room, endpoint=False)).astype(int))]
        chosen = sorted(set(chosen) | {int(i) for i in flat})
    while True:  # extreme points on one plane (a flat part): add the vertex farthest from them until they span space
        try:
            hull = ConvexHull(vertices[chosen])
            break
        except QhullError:
            far = np.linalg.norm(vertices - vertices[chosen].mean(axis=0), axis=1)
            far[chosen] = -1.0
            chosen.append(int(np.argmax(far)))
    while True:
        outside = (vertices @ hull.equations[:, :3].T + hull.equations[:, 3]).max(axis=1)  # > 0: outside a face
        farthest = int(np.argmax(outside))
        if len(hull.vertices) >= max_vertices or outside[farthest] <= 1e-12:
            kept = vertices[np.asarray(chosen)[hull.vertices]]
            out = convex_hull(kept)
            return out[0], out[1], max(0.0, float(outside[farthest]))
        chosen = [chosen[int(i)] for i in hull.vertices] + [farthest]
        hull = ConvexHull(vertices[chosen])


def _volume(points: np.ndarray, faces: np.ndarray) -> float:
    """Enclosed volume by the divergence theorem: sum over triangles of det(a, b, c) / 6, m^3."""
    tri = points[faces]  # [F, 3, 3]
    return float(abs(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6.0)


def cut_below(parts: ColliderParts, height: float, *, min_points: int = 4) -> ColliderParts:
    """Convex parts cut by the horizontal plane ``z = height``, keeping what lies above (world coordinates).

    Each part is taken as convex (its hull is used): the kept part is the hull of its vertices above the plane and
    of the points where its hull edges cross it, so the part gets a flat base on the plane. Parts entirely below
    the plane, or left degenerate, are dropped.

    Args:
        parts: Convex parts, ``(points [N, 3], faces [F, 3])`` each.
        height: Plane height, metres.
        min_points: Parts with fewer points left are dropped.
    """
    return cut_axis(parts, 2, height, 1.0, min_points=min_points)


def cut_above(parts: ColliderParts, height: float, *, min_points: int = 4) -> ColliderParts:
    """Like :func:`cut_below`, keeping what lies below the plane: each part gets a flat top on it."""
    return cut_axis(parts, 2, height, -1.0, min_points=min_points)


def cut_axis(parts: ColliderParts, axis: int, height: float, side: float, *, min_points: int = 4) -> ColliderParts:
    """Keep the side ``side * (x[axis] - height) >= 0`` of each convex part (see :func:`cut_below`)."""
    normal = np.zeros(3)
    normal[axis] = side
    return cut_plane(parts, normal, side * height, min_points=min_points)


def cut_plane(parts: ColliderParts, normal: np.ndarray, offset: float, *, min_points: int = 4) -> ColliderParts:
    """Keep the side ``normal . x >= offset`` of each convex part (``normal`` a unit vector; see
    :func:`cut_below`): a wall of any orientation, a tilted cut."""
    import trimesh

    n = np.asarray(normal, dtype=np.float64).reshape(3)
    n = n / np.linalg.norm(n)
    out: ColliderParts = []
    for points, faces in parts:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        signed = pts @ n - offset
        if signed.min() >= 0:
            out.append((pts, np.asarray(faces, dtype=np.int64).reshape(-1, 3)))
            continue
        if signed.max() <= 0:
            continue
        try:
            hull = trimesh.convex.convex_hull(pts)
        except Exception:  # noqa: BLE001 - qhull fails on flat input: such a part is dropped
            continue
        v = np.asarray(hull.vertices)
        d = v @ n - offset
        ia, ib = hull.edges_unique[:, 0], hull.edges_unique[:, 1]
        crossing = d[ia] * d[ib] < 0
        a, b = v[ia[crossing]], v[ib[crossing]]
        t = d[ia[crossing]] / (d[ia[crossing]] - d[ib[crossing]])
        section = a + t[:, None] * (b - a)
        section -= np.outer(section @ n - offset, n)  # exactly on the plane
        kept = np.concatenate([v[d >= 0], section])
        if len(kept) < min_points or np.ptp(kept @ n) < 1e-6:
            continue
        try:
            out.append(convex_hull(kept))
        except Exception:  # noqa: BLE001 - degenerate remainder
            continue
    return out


def convexity(points: np.ndarray, faces: np.ndarray) -> float:
    """Volume ratio ``V(mesh) / V(hull(mesh))`` in [0, 1]; 1 for a convex mesh. The mesh should be closed."""
    pts, tri = _as_arrays(points, faces)
    hp, hf = convex_hull(pts)
    hull_volume = _volume(hp, hf)
    if hull_volume <= 0.0:
        return 1.0
    return float(min(1.0, _volume(pts, tri) / hull_volume))


def convex_decomposition(
    points: np.ndarray, faces: np.ndarray, config: DecompositionConfig | None = None
) -> ColliderParts:
    """Approximate convex decomposition with CoACD (see :class:`DecompositionConfig` for why CoACD).

    Returns:
        Convex parts, each ``(points [N, 3], faces [F, 3])``, object coordinates.
    """
    import coacd

    cfg = config or DecompositionConfig()
    pts, tri = _as_arrays(points, faces)
    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(pts, tri),
        threshold=cfg.threshold,
        max_convex_hull=cfg.max_parts,
        max_ch_vertex=cfg.max_part_vertices,
        preprocess_resolution=cfg.preprocess_resolution,
        resolution=cfg.resolution,
        mcts_iterations=cfg.mcts_iterations,
        mcts_nodes=cfg.mcts_nodes,
        mcts_max_depth=cfg.mcts_max_depth,
        seed=cfg.seed,
    )
    return [(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)) for v, f in parts]
