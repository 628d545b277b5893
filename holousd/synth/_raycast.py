"""Ground-truth ray casting of a static triangle scene on the CPU with Warp (``wp.Mesh`` + ``mesh_query_ray``).

One kernel (compiled once, cached on disk by Warp) casts one ray through the centre of every pixel of a batch of
frames. Pixel (u, v) looks along ``R @ [(u - cx) / fx, (v - cy) / fy, 1]`` (OpenCV convention, centres at
integer coordinates); because that direction has unit z in the camera frame, the hit parameter ``t`` is the
z-depth along the optical axis directly.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["RayCaster", "RayHits"]


@dataclass(kw_only=True)
class RayHits:
    """What the rays of a batch of frames hit."""

    depth: np.ndarray
    """[F, H, W] float32 z-depth along the optical axis, metres (0 = no hit)."""
    face: np.ndarray
    """[F, H, W] int32 index of the triangle hit (-1 = no hit)."""


@functools.cache
def _kernel():  # noqa: ANN202 - a Warp kernel
    import warp as wp

    @wp.kernel
    def cast_rays(
        mesh: wp.uint64,
        rotation: wp.array(dtype=wp.mat33),
        origin: wp.array(dtype=wp.vec3),
        pinhole: wp.array(dtype=wp.vec4),
        width: int,
        pixels: int,
        max_t: float,
        depth: wp.array(dtype=float),
        face: wp.array(dtype=int),
    ):
        f, p = wp.tid()
        k = pinhole[f]
        u = float(p % width)
        v = float(p / width)
        ray = rotation[f] * wp.vec3((u - k[2]) / k[0], (v - k[3]) / k[1], 1.0)
        out = f * pixels + p
        q = wp.mesh_query_ray(mesh, origin[f], ray, max_t)
        if q.result:
            depth[out] = q.t
            face[out] = q.face
        else:
            depth[out] = 0.0
            face[out] = -1

    return cast_rays


class RayCaster:
    """Casts camera rays against one static triangle mesh in world coordinates.

    Args:
        points: [V, 3] vertices, metres.
        faces: [F, 3] triangle vertex indices.
        max_depth: Rays stop after this z-depth, metres.
    """

    def __init__(self, points: np.ndarray, faces: np.ndarray, *, max_depth: float = 100.0) -> None:
        import warp as wp

        if getattr(wp.config, "log_level", 0) < getattr(wp, "LOG_WARNING", 0):
            wp.config.log_level = wp.LOG_WARNING  # keep Warp's start-up banner out of the command's stdout
        wp.init()
        self._wp = wp
        self._points = wp.array(np.ascontiguousarray(points, dtype=np.float32), dtype=wp.vec3, device="cpu")
        self._faces = wp.array(np.ascontiguousarray(faces, dtype=np.int32).ravel(), dtype=wp.int32, device="cpu")
        self._mesh = wp.Mesh(points=self._points, indices=self._faces)
        self.max_depth = float(max_depth)
        """Largest z-depth a ray reports, metres."""

    def cast(self, intrinsics: np.ndarray, camera_to_world: np.ndarray, width: int, height: int) -> RayHits:
        """Cast one ray per pixel for each of F cameras ([F, 3, 3] intrinsics, [F, 4, 4] OpenCV poses)."""
        wp = self._wp
        intrinsics = np.asarray(intrinsics, dtype=np.float64).reshape(-1, 3, 3)
        c2w = np.asarray(camera_to_world, dtype=np.float64).reshape(-1, 4, 4)
        frames, pixels = len(c2w), width * height
        pinhole = np.stack([intrinsics[:, 0, 0], intrinsics[:, 1, 1], intrinsics[:, 0, 2], intrinsics[:, 1, 2]], 1)
        depth = wp.zeros(frames * pixels, dtype=float, device="cpu")  # [F * H * W]
        face = wp.zeros(frames * pixels, dtype=int, device="cpu")  # [F * H * W]
        wp.launch(
            _kernel(),
            dim=(frames, pixels),
            inputs=[
                self._mesh.id,
                wp.array(c2w[:, :3, :3].astype(np.float32), dtype=wp.mat33, device="cpu"),
                wp.array(c2w[:, :3, 3].astype(np.float32), dtype=wp.vec3, device="cpu"),
                wp.array(pinhole.astype(np.float32), dtype=wp.vec4, device="cpu"),
                width,
                pixels,
                self.max_depth,
                depth,
                face,
            ],
            device="cpu",
        )
        return RayHits(
            depth=depth.numpy().reshape(frames, height, width),
            face=face.numpy().reshape(frames, height, width),
        )
