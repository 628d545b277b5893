"""Geometry metrics (Chamfer, F-score, normal consistency) and SDF meshing helpers used by s1_fit."""

from __future__ import annotations

import numpy as np
import pytest

from holousd.eval._geometry import geometry_metrics, sample_surface, visible_mask
from holousd.geometry._grid import VoxelGrid, signed_distance_from_occupancy
from holousd.geometry._meshing import mesh_from_sdf
from holousd.usd import MeshData


def _cube(size: float = 0.2, offset: float = 0.0) -> MeshData:
    import trimesh

    box = trimesh.creation.box(extents=[size] * 3)
    return MeshData(points=np.asarray(box.vertices) + offset, faces=np.asarray(box.faces))


def test_identical_and_shifted_surfaces() -> None:
    rng = np.random.default_rng(0)
    gt = sample_surface(_cube(), 20_000, rng)
    same = geometry_metrics(sample_surface(_cube(), 20_000, rng), gt)
    assert same.chamfer_cm < 0.2 and same.fscore > 99.9 and same.normal_consistency > 97
    shifted = geometry_metrics(sample_surface(_cube(offset=0.1), 20_000, rng), gt)
    assert shifted.chamfer_cm > 3 and shifted.fscore < 70


def test_visible_restriction_only_touches_the_ground_truth_side() -> None:
    rng = np.random.default_rng(1)
    gt_pts, gt_nrm = sample_surface(_cube(), 10_000, rng)
    top = gt_pts[:, 2] > 0.099
    pred = (gt_pts[top], gt_nrm[top])  # only the top face predicted
    full = geometry_metrics(pred, (gt_pts, gt_nrm))
    visible = geometry_metrics(pred, (gt_pts, gt_nrm), gt_visible=top)
    assert visible.recall > 99 and full.recall < 60
    assert visible.precision == pytest.approx(full.precision)


def test_visible_mask_depth_test() -> None:
    pose = np.eye(4)  # camera at the origin looking along +z
    k = np.array([[10.0, 0, 4.5], [0, 10.0, 4.5], [0, 0, 1]])
    depth = np.full((10, 10), 2.0, np.float32)
    pts = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0], [0.0, 0.0, -2.0]])
    assert visible_mask(pts, k[None], pose[None], [depth]).tolist() == [True, False, False]


def test_meshing_closes_a_grid_cut_by_its_border_and_meets_the_budget() -> None:
    import trimesh

    grid = VoxelGrid.from_bounds(np.array([-0.2] * 3), np.array([0.2] * 3), 0.01, pad=0)
    pts = grid.points().reshape(*grid.shape, 3)
    occupied = np.linalg.norm(pts - np.array([0.0, 0.0, -0.25]), axis=-1) < 0.3  # crosses the grid's bottom face
    sdf = signed_distance_from_occupancy(occupied, grid.voxel_size)
    result = mesh_from_sdf(sdf, grid.origin, grid.voxel_size, max_faces=1500)
    assert result is not None and result.watertight and not result.fallback
    assert trimesh.Trimesh(result.mesh.points, result.mesh.faces, process=False).is_watertight
    assert len(result.mesh.faces) <= 1500
    assert mesh_from_sdf(np.ones((4, 4, 4), np.float32), np.zeros(3), 0.1) is None


def test_meshing_a_grid_whose_surface_is_not_closed_smooths_before_it_gives_a_hull(monkeypatch) -> None:
    import trimesh

    from holousd.geometry import _meshing

    grid = VoxelGrid.from_bounds(np.array([-0.2] * 3), np.array([0.2] * 3), 0.01, pad=2)
    pts = grid.points().reshape(*grid.shape, 3)
    ring = (np.abs(np.linalg.norm(pts[..., :2], axis=-1) - 0.12) < 0.04) & (np.abs(pts[..., 2]) < 0.05)  # a torus
    sdf = signed_distance_from_occupancy(ring, grid.voxel_size)
    real = _meshing._mesh_level_set
    calls = []

    def first_fails(g, *args):  # marching cubes on the raw grid gives an open surface (a noisy fit's case)
        calls.append(g)
        return None if len(calls) == 1 else real(g, *args)

    monkeypatch.setattr(_meshing, "_mesh_level_set", first_fails)
    result = mesh_from_sdf(sdf, grid.origin, grid.voxel_size)
    assert result is not None and result.fallback == "smoothed" and result.watertight
    mesh = trimesh.Trimesh(result.mesh.points, result.mesh.faces, process=False)
    assert mesh.is_watertight and mesh.euler_number == 0  # still a ring: the hole is kept, unlike a hull's
    monkeypatch.setattr(_meshing, "_mesh_level_set", lambda *a: None)
    hull = mesh_from_sdf(sdf, grid.origin, grid.voxel_size)
    assert hull is not None and hull.fallback == "hull"
    assert trimesh.Trimesh(hull.mesh.points, hull.mesh.faces).euler_number == 2
