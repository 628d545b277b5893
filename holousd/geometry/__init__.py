"""Geometry domain: SDF grids, TSDF fusion and visual hulls, meshing, mesh queries."""

from holousd.geometry._decompose import Decomposition, convexify, plane_decomposition
from holousd.geometry._grid import (
    FusionResult,
    Views,
    VoxelGrid,
    box_sdf,
    carve_hull,
    fuse_tsdf,
    sample_grid,
    signed_distance_from_occupancy,
)
from holousd.geometry._meshing import MeshingResult, face_budget, mesh_from_sdf
from holousd.geometry._sdf import point_triangle_distance, sdf_from_convex_parts

__all__ = [
    "Decomposition",
    "FusionResult",
    "MeshingResult",
    "Views",
    "VoxelGrid",
    "box_sdf",
    "carve_hull",
    "convexify",
    "face_budget",
    "fuse_tsdf",
    "mesh_from_sdf",
    "plane_decomposition",
    "point_triangle_distance",
    "sample_grid",
    "sdf_from_convex_parts",
    "signed_distance_from_occupancy",
]
