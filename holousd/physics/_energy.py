"""Physics energies of the tree search (HoloScene E_physics terms): stability, contact and penetration.

All lengths in metres, angles in radians, volumes in cubic metres.
"""

from __future__ import annotations

import os

import numpy as np
from pxr import Usd

from . import _scene
from ._errors import PhysicsInputError
from ._simulate import Trajectories

__all__ = ["e_pene_mesh", "e_pene_sdf", "e_stable", "e_touch"]


def e_stable(traj: Trajectories, path: str | None = None) -> float | dict[str, float]:
    """Stability energy from a gravity-only simulation.

    ``E_stable = ||p(T) - p(0)|| + angle(q(0)^-1 q(T))``: translation of the object's origin (m) plus the angle
    of its rotation (rad) between the first and last sample.

    Args:
        traj: Trajectories from :func:`~holousd.physics.simulate` (gravity only, e.g. 2 s at 240 Hz).
        path: One object's prim path; None returns every object's energy.

    Returns:
        The energy of ``path``, or a dict of energies keyed by prim path.
    """

    def one(p: str) -> float:
        return float(traj.translation_m(p)[-1] + np.radians(traj.rotation_deg(p)[-1]))

    if path is not None:
        return one(path)
    return {p: one(p) for p in traj.positions}


def e_touch(source: str | os.PathLike[str] | Usd.Stage, path: str | None = None) -> float | dict[str, float]:
    """Contact energy: how far each supported object is from its support parent's surface.

    ``E_touch(i) = min_{x in S_i} d(x, S_parent(i))``: the smallest distance from the object's surface
    (vertices and area-weighted surface samples of its render mesh, world frame) to the parent's surface
    (closest point on the parent's render meshes). It is 0 when the two touch (or intersect) and grows
    with the gap. The parent is the first target of ``rel holo:supportedBy`` (HoloRelationsAPI).

    Args:
        source: Stage or file path.
        path: One object (prim path or name under /World/Objects); None evaluates every rigid body that has a
            ``holo:supportedBy`` target.

    Returns:
        The energy in metres, or a dict keyed by prim path.

    Raises:
        PhysicsInputError: ``path`` has no ``holo:supportedBy`` target.
    """
    import trimesh

    from holousd.geometry._contact import queryable

    stage = _scene.open_stage(source)
    if path is not None:
        paths = [_scene.resolve_object(stage, path)]
    else:
        paths = [p for p in _scene.rigid_bodies(stage) if _scene.supported_by(stage, p) is not None]
    out: dict[str, float] = {}
    for p in paths:
        parent = _scene.supported_by(stage, p)
        if parent is None:
            raise PhysicsInputError(
                f"{_scene.stage_label(stage)}: {p} has no holo:supportedBy target; author the support relation"
            )
        cp, cf = _scene.world_mesh(stage, p)
        pp, pf = _scene.world_mesh(stage, parent)
        child = trimesh.Trimesh(cp, cf, process=False)
        parent_mesh = queryable((pp, pf))
        n = min(2000, max(200, 20 * len(cf)))
        samples, _ = trimesh.sample.sample_surface_even(child, n, seed=0) if len(cf) else (np.empty((0, 3)), None)
        query = np.concatenate([cp, np.asarray(samples).reshape(-1, 3)])  # [Q, 3]
        _, dist, _ = trimesh.proximity.closest_point(parent_mesh, query)
        out[p] = float(np.min(dist))
    return out[paths[0]] if path is not None else out


def e_pene_mesh(mesh_a: tuple[np.ndarray, np.ndarray], mesh_b: tuple[np.ndarray, np.ndarray]) -> float:
    """Penetration energy of two closed meshes: the volume of their intersection.

    ``E_pene = Vol(A ∩ B)`` computed exactly with manifold3d's boolean intersection, m^3. Both meshes must be
    closed, consistently oriented 2-manifolds in a common frame.

    Args:
        mesh_a: ``(points [N, 3], faces [F, 3])``.
        mesh_b: ``(points [M, 3], faces [G, 3])``.

    Raises:
        PhysicsInputError: A mesh is not a closed manifold.
    """
    import manifold3d

    def manifold(mesh: tuple[np.ndarray, np.ndarray], which: str) -> manifold3d.Manifold:
        pts, faces = mesh
        m = manifold3d.Manifold(
            manifold3d.Mesh(
                vert_properties=np.asarray(pts, dtype=np.float32).reshape(-1, 3),
                tri_verts=np.asarray(faces, dtype=np.uint32).reshape(-1, 3),
            )
        )
        if m.status() != manifold3d.Error.NoError:
            raise PhysicsInputError(f"mesh {which} is not a closed manifold ({m.status()}); repair or remesh it")
        return m

    return float((manifold(mesh_a, "a") ^ manifold(mesh_b, "b")).volume())


def e_pene_sdf(
    sdf_a: np.ndarray,
    origin_a: np.ndarray,
    voxel_a: float,
    sdf_b: np.ndarray,
    origin_b: np.ndarray,
    voxel_b: float,
) -> float:
    """Penetration energy of two SDF grids: the volume inside both.

    ``E_pene = sum_{x in grid A} [s_A(x) < 0] [s_B(x) < 0] * voxel_a^3``, where ``s_B`` is trilinearly
    interpolated at A's sample points (points outside B's grid count as outside B). Sample (i, j, k) of a grid
    lies at ``origin + (i, j, k) * voxel``. Resolution: one voxel of A.

    Args:
        sdf_a: [X, Y, Z] signed distances of A, m (negative inside).
        origin_a: [3] position of A's sample (0, 0, 0), m.
        voxel_a: A's grid spacing, m.
        sdf_b: [X', Y', Z'] signed distances of B, m.
        origin_b: [3] position of B's sample (0, 0, 0), m.
        voxel_b: B's grid spacing, m.

    Returns:
        Overlap volume, m^3.
    """
    from scipy.ndimage import map_coordinates

    a = np.asarray(sdf_a, dtype=np.float64)
    b = np.asarray(sdf_b, dtype=np.float64)
    if a.ndim != 3 or b.ndim != 3 or voxel_a <= 0 or voxel_b <= 0:
        raise PhysicsInputError("SDF grids must be 3-D arrays with positive voxel sizes")
    inside = np.argwhere(a < 0.0)  # [K, 3] indices into A
    if len(inside) == 0:
        return 0.0
    world = np.asarray(origin_a, dtype=np.float64) + inside * voxel_a  # [K, 3]
    coords = ((world - np.asarray(origin_b, dtype=np.float64)) / voxel_b).T  # [3, K] in B's index space
    sb = map_coordinates(b, coords, order=1, mode="constant", cval=np.inf)  # [K]
    return float(np.count_nonzero(sb < 0.0) * voxel_a**3)
