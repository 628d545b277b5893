"""Gather one object's evidence from a reconstructed scene and its capture (:class:`ObjectEvidence`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from holousd._errors import SceneError
from holousd.geometry._meshing import meshed_only
from holousd.io._observations import Observations
from holousd.priors._api import FrameEvidence, ObjectEvidence
from holousd.usd._scene import BACKGROUND, SceneGraph
from holousd.usd._types import MeshData

__all__ = ["object_evidence", "object_neighbours"]


def _world(scene: SceneGraph, name: str) -> MeshData | None:
    try:
        mesh = scene.get_mesh(name)
    except SceneError:
        return None
    return MeshData(points=scene.get_pose(name).apply(mesh.points), faces=mesh.faces)


_FROM_SCENE = object()


def object_neighbours(scene: SceneGraph, name: str, *, support: str | None, placed: dict[str, MeshData] | None = None,
                      margin: float = 0.05) -> dict[str, MeshData]:  # fmt: skip
    """World meshes of ``name``'s support and of every object whose box comes within ``margin`` metres of its
    fitted mesh's box; a shape in ``placed`` (one a search has chosen) replaces the scene's."""
    world = scene.get_pose(name).apply(scene.get_mesh(name).points)
    lo, hi = world.min(0) - margin, world.max(0) + margin
    neighbours: dict[str, MeshData] = {}
    for other in [BACKGROUND, *scene.objects()]:
        if other == name:
            continue
        found = (placed or {}).get(other) or _world(scene, other)
        if found is None or len(found.points) == 0:
            continue
        near = np.all(found.points.max(0) >= lo) and np.all(found.points.min(0) <= hi)
        if other == support or (other != BACKGROUND and near):
            neighbours[other] = found
    return neighbours


def object_evidence(scene: SceneGraph, obs: Observations, name: str, *, max_frames: int | None = 24,
                    stride: int = 2, margin: float = 0.05, support: object = _FROM_SCENE,
                    placed: dict[str, MeshData] | None = None,
                    floor: float | None = None) -> ObjectEvidence:  # fmt: skip
    """The evidence of object ``name``: the frames whose mask shows it (at most ``max_frames``, evenly spaced),
    its masked depth back-projected every ``stride`` pixels, its stage-1 mesh and SDF, its support (from the
    scene's relations when it has them, or ``support``) and the height of the support's surface under it, and
    the meshes of the support and of every object within ``margin`` metres of it (world meshes in ``placed``
    replace the scene's: the shapes a search has already chosen). The support's surface: rays cast straight
    down from ``margin`` above the object's bottom each take the upward-facing face nearest that bottom (the top
    the fit sank the object into; not a wall's face a ray grazes, a rim beside it or the floor under a table),
    and the third highest of those wins (an object overhanging its table's edge is on the table; a speck in
    the room's mesh that one ray meets is no support). Under an object on the room where the room's mesh has no
    such face (floor no camera saw, behind furniture), it is ``floor``, the room's floor height, when given."""
    info = scene.node_info(name)
    mesh = scene.get_mesh(name)
    try:
        sdf = scene.get_sdf(name)
    except SceneError:
        sdf = None
    if sdf is not None:  # the SDF's matter is the mesh's: a floater the meshing dropped is no evidence
        sdf = replace(sdf, grid=meshed_only(sdf.grid, sdf.origin, sdf.voxel_size, mesh, sdf.iso_level))
    pose = scene.get_pose(name)
    showing = [i for i in range(len(obs)) if obs.has_masks and (obs.mask(i) == info.instance_id).any()]
    if max_frames is not None and len(showing) > max_frames:
        showing = [showing[int(j)] for j in np.linspace(0, len(showing) - 1, max_frames).round()]
    frames, points = [], []
    for i in showing:
        labels = np.asarray(obs.mask(i), np.int32)
        depth = obs.depth(i) if obs.has_depth and obs.depth_kind == "metric" else None
        frame = FrameEvidence(index=i, intrinsics=np.asarray(obs.intrinsics[i], float),
                              camera_to_world=np.asarray(obs.poses[i], float), labels=labels,
                              depth=None if depth is None else np.asarray(depth, np.float32))  # fmt: skip
        frames.append(frame)
        if frame.depth is not None:
            sel = (labels == info.instance_id) & (frame.depth > 0)
            rows, cols = np.nonzero(sel[::stride, ::stride])
            rows, cols = rows * stride, cols * stride
            z = frame.depth[rows, cols].astype(np.float64)
            k = frame.intrinsics
            cam = np.stack([(cols - k[0, 2]) / k[0, 0] * z, (rows - k[1, 2]) / k[1, 1] * z, z], axis=1)
            points.append(cam @ frame.camera_to_world[:3, :3].T + frame.camera_to_world[:3, 3])
    world = pose.apply(mesh.points)
    lo, hi = world.min(0) - margin, world.max(0) + margin
    seen = np.concatenate(points) if points else np.zeros((0, 3))
    # what lies farther than ``margin`` outside the fitted shape's box is not the object's: a segmenter's fragment
    # or a return from behind its silhouette (on the demo's phone capture, a box's candidates spanned 1.8 m)
    seen = seen[np.all((seen >= lo) & (seen <= hi), axis=1)]
    support = scene.get_support(name) if support is _FROM_SCENE else support
    neighbours = object_neighbours(scene, name, support=support, placed=placed, margin=margin)
    height = None
    below = neighbours.get(support) if support is not None else None
    if below is not None and len(below.faces):  # the support's surface under the object: rays cast straight down
        from trimesh.ray.ray_triangle import RayMeshIntersector

        from holousd.geometry._contact import queryable

        bottom = float(world[:, 2].min())
        xs, ys = (np.linspace(world[:, a].min(), world[:, a].max(), 7) for a in (0, 1))
        origins = np.stack([*np.meshgrid(xs, ys, indexing="ij"), np.full((7, 7), bottom + margin)], -1).reshape(-1, 3)
        below_mesh = queryable((below.points, below.faces))
        hits, rays, faces = RayMeshIntersector(below_mesh).intersects_location(
            origins, np.tile([0.0, 0.0, -1.0], (len(origins), 1)), multiple_hits=True)  # fmt: skip
        hits, rays = np.asarray(hits, float).reshape(-1, 3), np.asarray(rays, int)
        up = below_mesh.face_normals[np.asarray(faces, int)][:, 2] > 0.5 if len(hits) else np.zeros(0, bool)
        nearest: dict[int, float] = {}  # per ray, the upward face nearest the object's bottom
        for ray, z in zip(rays[up], hits[up, 2], strict=True):
            if ray not in nearest or abs(z - bottom) < abs(nearest[ray] - bottom):
                nearest[int(ray)] = float(z)
        if len(nearest) >= 3:  # a surface at least three rays agree on: not a speck of the room's mesh
            height = sorted(nearest.values())[-3]
    if height is None and support == BACKGROUND and floor is not None and floor <= world[:, 2].min() + margin:
        height = float(floor)
    return ObjectEvidence(name=name, instance_id=info.instance_id, pose=pose, mesh=mesh, sdf=sdf, frames=frames,
                          points=seen, support=support,
                          support_height=height, neighbours=neighbours)  # fmt: skip
