"""Mesh ray casting (numpy): first hits of camera rays on triangle meshes, for reference images and depth."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from holousd.render._camera import Camera
from holousd.usd import MeshData

__all__ = ["RayHits", "raycast", "render_textured"]


@dataclass(kw_only=True)
class RayHits:
    """First hits of a camera's rays ([R] arrays; R = H x W x supersample^2, row-major sub-pixel blocks)."""

    mesh: np.ndarray
    """[R] index of the mesh hit, -1 for a miss."""
    face: np.ndarray
    """[R] face hit (undefined for misses)."""
    distance: np.ndarray
    """[R] ray parameter t (distance along the unit ray), metres; inf for misses."""
    points: np.ndarray
    """[R, 3] world hit points."""
    normals: np.ndarray
    """[R, 3] world unit face normals at the hits."""


def _rays(camera: Camera, supersample: int) -> tuple[np.ndarray, np.ndarray]:
    s = supersample
    offs = (np.arange(s) + 0.5) / s
    rows = (np.arange(camera.height)[:, None] + offs[None, :]).reshape(-1)  # [H * s]
    cols = (np.arange(camera.width)[:, None] + offs[None, :]).reshape(-1)  # [W * s]
    v, u = np.meshgrid(rows, cols, indexing="ij")
    d_cam = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=-1)
    d = d_cam.reshape(-1, 3) @ camera.cam_to_world[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(camera.center, d.shape), d


def raycast(meshes: list[MeshData], camera: Camera, *, supersample: int = 1, chunk: int = 4_000_000) -> RayHits:
    """Cast one ray per (sub)pixel into world-space meshes and keep the nearest hit (Moller-Trumbore)."""
    origin, direction = _rays(camera, supersample)
    n_rays = len(direction)
    best_t = np.full(n_rays, np.inf)
    best_mesh = np.full(n_rays, -1, dtype=np.int64)
    best_face = np.zeros(n_rays, dtype=np.int64)
    normals = np.zeros((n_rays, 3))
    o = camera.center
    for mi, mesh in enumerate(meshes):
        if len(mesh.faces) == 0:
            continue
        lo, hi = mesh.bounds
        with np.errstate(divide="ignore", invalid="ignore"):  # slab test of the bounding box
            inv = 1.0 / direction
            t0, t1 = (lo - o) * inv, (hi - o) * inv
        t_near = np.nanmax(np.minimum(t0, t1), axis=1)
        t_far = np.nanmin(np.maximum(t0, t1), axis=1)
        cand = np.nonzero((t_far >= np.maximum(t_near, 0)) & (t_near < best_t))[0]
        tri = mesh.points[mesh.faces]  # [F, 3, 3]
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        fn = np.cross(e1, e2)
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-30)
        step = max(chunk // max(len(tri), 1), 1)
        for s in range(0, len(cand), step):
            idx = cand[s : s + step]
            d = direction[idx][:, None, :]  # [r, 1, 3]
            p = np.cross(d, e2[None])  # [r, F, 3]
            det = np.einsum("rfj,fj->rf", p, e1)
            with np.errstate(divide="ignore", invalid="ignore"):
                inv_det = 1.0 / det
                tvec = o - tri[:, 0]  # [F, 3]
                u = np.einsum("rfj,fj->rf", p, tvec) * inv_det
                q = np.cross(tvec, e1)  # [F, 3]
                v = np.einsum("rj,fj->rf", d[:, 0], q) * inv_det
                t = np.einsum("fj,fj->f", e2, q)[None, :] * inv_det
            ok = (np.abs(det) > 1e-14) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6)
            t = np.where(ok, t, np.inf)
            face = np.argmin(t, axis=1)
            tmin = t[np.arange(len(idx)), face]
            better = tmin < best_t[idx]
            sel = idx[better]
            best_t[sel], best_mesh[sel], best_face[sel] = tmin[better], mi, face[better]
            normals[sel] = fn[face[better]]
    points = o + direction * np.where(np.isfinite(best_t), best_t, 0.0)[:, None]
    return RayHits(mesh=best_mesh, face=best_face, distance=best_t, points=points, normals=normals)


def render_textured(
    meshes: list[MeshData],
    camera: Camera,
    shade: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
    *,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    supersample: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast reference image of textured meshes, box-filtered over supersample^2 rays per pixel.

    Args:
        meshes: World-space meshes.
        camera: The camera.
        shade: ``shade(mesh_index [R], points [R, 3], normals [R, 3]) -> [R, 3]`` colour of the hits.
        background: Colour of rays that hit nothing.
        supersample: Rays per pixel along each axis.

    Returns:
        ([H, W, 3] float32 image, [H, W] int32 index of the mesh covering most of each pixel, -1 for none).
    """
    hits = raycast(meshes, camera, supersample=supersample)
    color = np.tile(np.asarray(background, dtype=np.float64), (len(hits.mesh), 1))
    hit = hits.mesh >= 0
    if hit.any():
        color[hit] = shade(hits.mesh[hit], hits.points[hit], hits.normals[hit])
    s, h, w = supersample, camera.height, camera.width
    image = color.reshape(h, s, w, s, 3).mean(axis=(1, 3))
    ids = hits.mesh.reshape(h, s, w, s).transpose(0, 2, 1, 3).reshape(h, w, s * s)
    votes = np.stack([(ids == k).sum(-1) for k in range(-1, len(meshes))], axis=-1)
    label = np.argmax(votes, axis=-1) - 1
    return image.astype(np.float32), label.astype(np.int32)
