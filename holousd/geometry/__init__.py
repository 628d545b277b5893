"""Geometry domain: SDF grids, TSDF fusion and visual hulls, meshing, mesh queries."""

from holousd.geometry._decompose import Decomposition, convexify, plane_decomposition
from holousd.geometry._grid import (
    Consensus,
    FusionResult,
    Views,
    VoxelGrid,
    box_sdf,
    carve_hull,
    confirmed_points,
    fuse_tsdf,
    label_consensus,
    object_points,
    sample_grid,
    signed_distance_from_occupancy,
)
from holousd.geometry._meshing import MeshingResult, face_budget, mesh_from_sdf
from holousd.geometry._poses import PoseConfig, PoseRefinement, refine_poses
from holousd.geometry._sdf import point_triangle_distance, sdf_from_convex_parts

__all__ = [
    "Consensus",
    "Decomposition",
    "FusionResult",
    "MeshingResult",
    "PoseConfig",
    "PoseRefinement",
    "Views",
    "VoxelGrid",
    "box_sdf",
    "carve_hull",
    "confirmed_points",
    "convexify",
    "face_budget",
    "fuse_tsdf",
    "label_consensus",
    "mesh_from_sdf",
    "object_points",
    "plane_decomposition",
    "point_triangle_distance",
    "refine_poses",
    "sample_grid",
    "sdf_from_convex_parts",
    "signed_distance_from_occupancy",
]
