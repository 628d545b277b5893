"""Ground-truth rendering of a procedural scene: RGB, z-depth, camera-frame normals and instance masks.

All four come from the same ray hit per pixel (one ray through each pixel centre), so they are consistent by
construction: the mask says which node the ray hit, depth is the hit's z in the camera frame, the normal is the
hit triangle's normal, and the colour is that node's procedural texture at the hit point, Lambert-shaded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from holousd.io import LazyArray, Observations
from holousd.synth._layout import SceneSpec
from holousd.synth._raycast import RayCaster
from holousd.synth._sensor import SensorModel
from holousd.synth._texture import albedo, shade
from holousd.usd import MeshData

__all__ = ["RenderedFrame", "SceneRenderer", "SynthCapture"]

_BATCH = 8
"""Frames ray-cast per kernel launch."""


@dataclass(kw_only=True)
class RenderedFrame:
    """One rendered frame."""

    rgb: np.ndarray
    """[H, W, 3] uint8 colour."""
    depth: np.ndarray
    """[H, W] float32 z-depth along the optical axis, metres (0 = no hit)."""
    normal: np.ndarray
    """[H, W, 3] float32 unit normals in the OpenCV camera frame ((0, 0, 0) = no hit)."""
    mask: np.ndarray
    """[H, W] int32 instance ids (0 = room)."""


def _face_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = points[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


class SceneRenderer:
    """Ray-casts a :class:`SceneSpec` (room + objects, each with its watertight mesh in object coordinates).

    Args:
        spec: The scene.
        meshes: Object name -> watertight mesh in object coordinates.
        room_mesh: The room shell in world coordinates.
    """

    def __init__(self, spec: SceneSpec, meshes: dict[str, MeshData], room_mesh: MeshData) -> None:
        self.spec = spec
        points, faces, owner = [room_mesh.points], [room_mesh.faces], [np.zeros(len(room_mesh.faces), np.int32)]
        offset = len(room_mesh.points)
        poses = [np.eye(4)]
        for obj in spec.objects:
            mesh = meshes[obj.name]
            points.append(obj.pose.apply(mesh.points))
            faces.append(mesh.faces + offset)
            owner.append(np.full(len(mesh.faces), obj.instance_id, np.int32))
            offset += len(mesh.points)
            poses.append(obj.pose.matrix())
        self._points = np.concatenate(points)  # [V, 3] world
        self._faces = np.concatenate(faces)  # [F, 3]
        self._owner = np.concatenate(owner)  # [F] instance id per face
        self._normals = _face_normals(self._points, self._faces)  # [F, 3] world
        self._poses = np.stack(poses)  # [N + 1, 4, 4] object-to-world per instance id
        self._textures = {obj.instance_id: obj.template.texture for obj in spec.objects}
        self._caster = RayCaster(self._points, self._faces)

    def render(self, intrinsics: np.ndarray, poses: np.ndarray, width: int, height: int) -> list[RenderedFrame]:
        """Render F frames ([F, 3, 3] intrinsics, [F, 4, 4] OpenCV camera-to-world poses)."""
        hits = self._caster.cast(intrinsics, poses, width, height)
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        frames = []
        for f in range(len(poses)):
            k, c2w = intrinsics[f], poses[f]
            face = hits.face[f].ravel()  # [P]
            hit = face >= 0
            depth = np.where(hit, hits.depth[f].ravel(), 0.0)  # [P]
            ray_cam = np.stack(
                [(u.ravel() - k[0, 2]) / k[0, 0], (v.ravel() - k[1, 2]) / k[1, 1], np.ones(u.size)], axis=1
            )  # [P, 3]
            world = (ray_cam * depth[:, None]) @ c2w[:3, :3].T + c2w[:3, 3]  # [P, 3]
            safe_face = np.where(hit, face, 0)
            normal_w = np.where(hit[:, None], self._normals[safe_face], 0.0)  # [P, 3]
            ids = np.where(hit, self._owner[safe_face], 0)  # [P]
            colour = np.zeros((u.size, 3))
            for node in np.unique(ids[hit]):
                sel = hit & (ids == node)
                pose = self._poses[node]
                local = (world[sel] - pose[:3, 3]) @ pose[:3, :3]  # object coordinates
                local_n = normal_w[sel] @ pose[:3, :3]
                if node == 0:
                    colour[sel] = self._room_albedo(local, local_n)
                else:
                    colour[sel] = albedo(local, local_n, self._textures[int(node)])
            colour = shade(colour, normal_w)
            rgb = np.where(hit[:, None], np.rint(colour * 255.0), 0).astype(np.uint8)
            normal_c = normal_w @ c2w[:3, :3]  # world -> camera frame
            frames.append(
                RenderedFrame(
                    rgb=rgb.reshape(height, width, 3),
                    depth=depth.astype(np.float32).reshape(height, width),
                    normal=normal_c.astype(np.float32).reshape(height, width, 3),
                    mask=ids.astype(np.int32).reshape(height, width),
                )
            )
        return frames

    def _room_albedo(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        room = self.spec.room
        out = np.zeros((len(points), 3))
        floor, ceiling = normals[:, 2] > 0.5, normals[:, 2] < -0.5
        walls = ~(floor | ceiling)
        for sel, tex in ((floor, room.floor_texture), (ceiling, room.ceiling_texture), (walls, room.wall_texture)):
            if np.any(sel):
                out[sel] = albedo(points[sel], normals[sel], tex)
        return out


class SynthCapture:
    """A rendered capture of a scene, rendered lazily in batches as frames are read.

    It also accumulates, once per frame, how many pixels of each object every frame shows and which sampled
    surface points of each object some frame observes (visible, unoccluded, facing the camera).

    Args:
        renderer: The scene renderer.
        intrinsics: [F, 3, 3] intrinsics.
        poses: [F, 4, 4] OpenCV camera-to-world poses.
        width: Image width, pixels.
        height: Image height, pixels.
        surface_samples: Object name -> ([S, 3] world points, [S, 3] world normals) to test for visibility.
    """

    def __init__(
        self,
        renderer: SceneRenderer,
        intrinsics: np.ndarray,
        poses: np.ndarray,
        width: int,
        height: int,
        surface_samples: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> None:
        self.renderer = renderer
        self.intrinsics = intrinsics
        self.poses = poses
        self.width, self.height = width, height
        self._cache: dict[int, RenderedFrame] = {}
        self._done: set[int] = set()
        n = len(renderer.spec.objects)
        self.pixels = np.zeros(n + 1, dtype=np.int64)
        """[N + 1] pixels showing each instance id over all frames rendered so far."""
        self.frames_seen = np.zeros(n + 1, dtype=np.int64)
        """[N + 1] number of frames in which each instance id appears."""
        self._samples = surface_samples or {}
        self.seen = {name: np.zeros(len(p), dtype=bool) for name, (p, _) in self._samples.items()}
        """Object name -> [S] which surface samples some frame observed."""
        self._ids = {o.name: o.instance_id for o in renderer.spec.objects}

    def __len__(self) -> int:
        return len(self.poses)

    def frame(self, i: int) -> RenderedFrame:
        """Frame ``i`` (rendering its batch if needed)."""
        if i not in self._cache:
            self._cache.clear()
            start = (i // _BATCH) * _BATCH
            stop = min(start + _BATCH, len(self.poses))
            rendered = self.renderer.render(
                self.intrinsics[start:stop], self.poses[start:stop], self.width, self.height
            )
            for j, fr in zip(range(start, stop), rendered, strict=True):
                self._cache[j] = fr
                if j not in self._done:
                    self._done.add(j)
                    self._account(j, fr)
        return self._cache[i]

    def render_all(self) -> None:
        """Render every frame once (for the statistics)."""
        for i in range(0, len(self), _BATCH):
            self.frame(i)

    def _account(self, i: int, fr: RenderedFrame) -> None:
        counts = np.bincount(fr.mask.ravel(), minlength=len(self.pixels))
        self.pixels += counts
        self.frames_seen += counts > 0
        k, c2w = self.intrinsics[i], self.poses[i]
        for name, (points, normals) in self._samples.items():
            cam = (points - c2w[:3, 3]) @ c2w[:3, :3]  # [S, 3] camera frame
            z = cam[:, 2]
            front = z > 1e-3
            u = np.rint(k[0, 0] * cam[:, 0] / np.where(front, z, 1) + k[0, 2]).astype(np.int64)
            v = np.rint(k[1, 1] * cam[:, 1] / np.where(front, z, 1) + k[1, 2]).astype(np.int64)
            inside = front & (u >= 0) & (u < self.width) & (v >= 0) & (v < self.height)
            facing = np.einsum("ij,ij->i", normals, c2w[:3, 3] - points) > 0
            ok = inside & facing
            if not np.any(ok):
                continue
            uu, vv = u[ok], v[ok]
            tol = 0.01 + 2.0 * z[ok] / k[0, 0]
            hit = (fr.mask[vv, uu] == self._ids[name]) & (np.abs(fr.depth[vv, uu] - z[ok]) < tol)
            idx = np.flatnonzero(ok)[hit]
            self.seen[name][idx] = True

    def flow(self, i: int) -> np.ndarray:
        """[H, W, 2] image motion (du, dv) of every pixel of frame ``i`` to the next frame (the previous one's,
        reversed, for the last), from the true depth and poses; 0 where nothing was hit."""
        j, sign = (i + 1, 1.0) if i + 1 < len(self) else (i - 1, -1.0)
        if j < 0:
            return np.zeros((self.height, self.width, 2))
        fr = self.frame(i)
        k, c2w, c2w_j = self.intrinsics[i], self.poses[i], self.poses[j]
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        z = fr.depth.astype(np.float64)
        cam = np.stack([(u - k[0, 2]) / k[0, 0] * z, (v - k[1, 2]) / k[1, 1] * z, z], axis=-1)  # [H, W, 3]
        world = cam @ c2w[:3, :3].T + c2w[:3, 3]
        other = (world - c2w_j[:3, 3]) @ c2w_j[:3, :3]
        kj = self.intrinsics[j]
        front = other[..., 2] > 1e-3
        zj = np.where(front, other[..., 2], 1.0)
        du = kj[0, 0] * other[..., 0] / zj + kj[0, 2] - u
        dv = kj[1, 1] * other[..., 1] / zj + kj[1, 2] - v
        ok = (z > 0) & front
        return sign * np.where(ok[..., None], np.stack([du, dv], axis=-1), 0.0)

    def observations(
        self, instance_names: dict[int, str], sensor: SensorModel | None = None, seed: int = 0
    ) -> Observations:
        """Lazy :class:`Observations` whose frames render on first access.

        Args:
            instance_names: Instance id -> object name.
            sensor: What a device makes of the rendered frames and the camera path (None: the exact frames).
            seed: Seed of the sensor's random choices.
        """
        n = len(self)

        def lazy(channel: str) -> list[LazyArray]:
            return [LazyArray(lambda i=i: getattr(self.frame(i), channel), f"<synth frame {i}>") for i in range(n)]

        def noisy(read) -> list[LazyArray]:
            return [LazyArray(lambda i=i: read(i), f"<synth frame {i}>") for i in range(n)]

        if sensor is None or sensor.clean:
            rgb, masks, depth, normals, poses = lazy("rgb"), lazy("mask"), lazy("depth"), lazy("normal"), self.poses
        else:
            gains = sensor.exposures(n, seed)
            rgb = noisy(lambda i: sensor.rgb(self.frame(i).rgb, self.flow(i), gains[i], seed, i))
            masks = noisy(lambda i: sensor.mask(self.frame(i).mask, seed, i))
            depth = noisy(lambda i: sensor.depth(self.frame(i).depth, seed, i)) if sensor.has_depth else None
            normals = lazy("normal") if sensor.normals else None
            poses = sensor.poses(self.poses, seed)
        return Observations(
            rgb=rgb,
            masks=masks,
            depth=depth,
            normals=normals,
            intrinsics=self.intrinsics,
            poses=poses,
            width=self.width,
            height=self.height,
            depth_kind="metric" if depth is not None else None,
            instance_names=instance_names,
        )
