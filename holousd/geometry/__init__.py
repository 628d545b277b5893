"""Geometry domain: SDF grids, meshing, collision approximation, mesh queries."""

from holousd.geometry._sdf import point_triangle_distance, sdf_from_convex_parts

__all__ = ["point_triangle_distance", "sdf_from_convex_parts"]
