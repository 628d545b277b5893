"""Watertight meshes from SDF grids: marching cubes, largest component, closure and a face budget."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from holousd.usd._types import MeshData

__all__ = ["MeshingResult", "face_budget", "mesh_from_sdf", "meshed_only"]


@dataclass(kw_only=True)
class MeshingResult:
    """A mesh extracted from an SDF grid and how it was made."""

    mesh: MeshData
    """Watertight triangle mesh (same coordinates as the grid origin), outward-facing."""
    watertight: bool
    """True when every edge is shared by exactly two consistently oriented faces."""
    tolerance: float
    """Largest deviation allowed to the simplification that met the face budget, metres (0: none)."""
    components: int
    """Connected components found before keeping the largest."""
    fallback: str = ""
    """'' when marching cubes succeeded, 'smoothed' when it did on the grid smoothed by half a voxel, 'hull' when
    the convex hull of the negative samples replaced it."""


def face_budget(extent: float, faces_per_metre2: float, minimum: int = 200, maximum: int = 200_000) -> int:
    """Face budget that scales with an object's size: ``faces_per_metre2`` times the square of its largest
    extent (metres), clamped to [minimum, maximum]."""
    return int(np.clip(faces_per_metre2 * extent * extent, minimum, maximum))


def _marching_cubes(padded: np.ndarray, voxel_size: float, step: int) -> tuple[np.ndarray, np.ndarray]:
    from skimage.measure import marching_cubes

    verts, faces, _, _ = marching_cubes(
        padded, level=0.0, spacing=(voxel_size,) * 3, step_size=step, allow_degenerate=False
    )
    return verts, faces


def _simplify(mesh: object, voxel_size: float, max_faces: int) -> tuple[object, float]:
    """Simplify a watertight trimesh with manifold3d until it meets ``max_faces`` (at most one voxel of error)."""
    import manifold3d
    import trimesh

    solid = manifold3d.Manifold(
        manifold3d.Mesh(
            vert_properties=np.asarray(mesh.vertices, np.float32),  # type: ignore[attr-defined]
            tri_verts=np.asarray(mesh.faces, np.uint32),  # type: ignore[attr-defined]
        )
    )
    if solid.status() != manifold3d.Error.NoError:
        return mesh, 0.0
    best, used = mesh, 0.0
    for factor in (0.25, 0.5, 1.0):
        out = solid.simplify(factor * voxel_size).to_mesh()
        candidate = trimesh.Trimesh(vertices=np.asarray(out.vert_properties[:, :3], np.float64),
                                    faces=np.asarray(out.tri_verts, np.int64), process=False)  # fmt: skip
        if not candidate.is_watertight or len(candidate.faces) < 4:
            break
        best, used = candidate, factor * voxel_size
        if len(candidate.faces) <= max_faces:
            break
    return best, used


def mesh_from_sdf(
    grid: np.ndarray, origin: np.ndarray, voxel_size: float, *, max_faces: int | None = None
) -> MeshingResult | None:
    """Extract the zero level set of an SDF grid as one closed, outward-oriented triangle mesh.

    The grid is padded with one layer of positive values so every surface closes; the largest connected
    component (by enclosed volume) is kept; when the mesh has more faces than ``max_faces`` it is simplified
    with manifold3d (edge collapses that keep the mesh manifold) at a tolerance of 1/4, 1/2 and then 1 voxel,
    stopping at the first that meets the budget (the budget is soft beyond one voxel of deviation). If the
    result is not watertight (a noisy grid's surface touching itself at a voxel edge), the grid smoothed by a
    Gaussian of half a voxel is meshed instead (``fallback`` 'smoothed'); if that is not watertight either, the
    convex hull of the negative samples replaces it so that no object is lost.

    Args:
        grid: [X, Y, Z] signed distances, metres, negative inside.
        origin: [3] position of sample (0, 0, 0).
        voxel_size: Grid spacing, metres.
        max_faces: Face budget (None: no limit).

    Returns:
        The mesh, or None when the grid has no negative sample.
    """
    grid = np.asarray(grid, dtype=np.float32)
    if not (grid < 0).any():
        return None
    found = _mesh_level_set(grid, origin, voxel_size, max_faces)
    if found is not None:
        return found
    from scipy.ndimage import gaussian_filter

    smoothed = gaussian_filter(grid, 0.5, mode="nearest")
    if (smoothed < 0).any():
        found = _mesh_level_set(smoothed, origin, voxel_size, max_faces)
        if found is not None:
            found.fallback = "smoothed"
            return found
    idx = np.argwhere(grid < 0)
    pts = np.asarray(origin, dtype=np.float64) + voxel_size * idx
    jitter = np.array([[dx, dy, dz] for dx in (-0.5, 0.5) for dy in (-0.5, 0.5) for dz in (-0.5, 0.5)])
    cloud = (pts[:, None, :] + voxel_size * jitter[None]).reshape(-1, 3)
    import trimesh

    hull = trimesh.PointCloud(cloud).convex_hull
    return MeshingResult(
        mesh=MeshData(points=np.asarray(hull.vertices), faces=np.asarray(hull.faces)),
        watertight=bool(hull.is_watertight),
        tolerance=0.0,
        components=0,
        fallback="hull",
    )


def _mesh_level_set(grid: np.ndarray, origin: np.ndarray, voxel_size: float,
                    max_faces: int | None) -> MeshingResult | None:  # fmt: skip
    """The closed mesh of :func:`mesh_from_sdf` (largest component, simplified to the budget), or None when it is
    not watertight."""
    import trimesh

    pad_value = float(max(voxel_size, float(np.abs(grid).max())))
    padded = np.pad(grid, 1, mode="constant", constant_values=pad_value)
    origin = np.asarray(origin, dtype=np.float64) - voxel_size
    verts, faces = _marching_cubes(padded, voxel_size, 1)
    mesh = trimesh.Trimesh(vertices=verts + origin, faces=faces, process=True)
    parts = mesh.split(only_watertight=False)
    components = len(parts)
    if components > 1:
        with np.errstate(invalid="ignore", divide="ignore"):  # a flat sliver's centre of mass is 0 / 0
            volumes = [abs(p.volume) if p.is_watertight else p.area * voxel_size for p in parts]
        mesh = parts[int(np.argmax(volumes))]
    if mesh.is_watertight and mesh.volume < 0:
        mesh.invert()
    tolerance = 0.0
    if mesh.is_watertight and max_faces is not None and len(mesh.faces) > max_faces:
        mesh, tolerance = _simplify(mesh, voxel_size, max_faces)
    if mesh.is_watertight and mesh.is_winding_consistent and len(mesh.faces) >= 4:
        return MeshingResult(
            mesh=MeshData(points=np.asarray(mesh.vertices), faces=np.asarray(mesh.faces)),
            watertight=True,
            tolerance=tolerance,
            components=components,
        )
    return None


def meshed_only(grid: np.ndarray, origin: np.ndarray, voxel_size: float, mesh: MeshData,
                iso_level: float = 0.0) -> np.ndarray:  # fmt: skip
    """``grid`` with the inside of every piece that ``mesh`` does not hold turned outside: :func:`mesh_from_sdf`
    keeps the largest piece of a grid's level set, and the pieces it drops (a fit's floaters: stray voxels a few
    frames' noise left under a chair's seat) would otherwise stay inside the SDF stored beside the mesh, where a
    proposer reading the SDF (a mirror image, columns carried down to the floor) brings them back as matter.

    Pieces are the regions below ``iso_level`` joined through samples' faces (finer than marching cubes'
    pieces); a piece is held when its deepest sample lies inside ``mesh`` (same coordinates as ``origin``). A
    dropped piece's values are mirrored about the level (as far outside as they were inside), so the field
    stays continuous and every piece the mesh holds keeps its values. When no piece's deepest sample is inside
    the mesh (a mesh from elsewhere), ``grid`` is returned as it is."""
    from scipy import ndimage

    grid = np.asarray(grid, np.float32)
    below = grid < iso_level
    labels, count = ndimage.label(below)  # face neighbours: what only an edge or a corner joins, the mesh may split
    if count <= 1 or len(mesh.faces) == 0:
        return grid
    import trimesh

    from holousd.geometry._contact import inside

    index = np.arange(1, count + 1)
    deepest = np.array(ndimage.minimum_position(grid, labels, index), float)  # [count, 3] sample indices
    held = inside(trimesh.Trimesh(mesh.points, mesh.faces, process=False),
                  np.asarray(origin, float) + voxel_size * deepest)  # fmt: skip
    if not held.any():
        return grid
    dropped = np.isin(labels, index[~held])
    out = grid.copy()
    out[dropped] = 2.0 * iso_level - grid[dropped]
    return out
