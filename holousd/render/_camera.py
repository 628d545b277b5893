"""Pinhole cameras in the OpenCV convention and camera paths (orbits) around a scene.

Camera frame: x right, y down, z forward (looking along +z). Pixel (column i, row j) covers [i, i+1) x [j, j+1)
and its centre is (i + 0.5, j + 0.5), as in COLMAP, nerfstudio and gsplat; a centred principal point is
``(width / 2, height / 2)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from holousd._errors import InvalidDataError

__all__ = ["Camera", "look_at", "orbit_cameras"]


@dataclass(kw_only=True)
class Camera:
    """A pinhole camera: intrinsics in pixels, image size, camera-to-world pose (OpenCV axes)."""

    fx: float
    """Focal length along x, pixels."""
    fy: float
    """Focal length along y, pixels."""
    cx: float
    """Principal point x, pixels (image centre = width / 2)."""
    cy: float
    """Principal point y, pixels (image centre = height / 2)."""
    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""
    cam_to_world: np.ndarray
    """[4, 4] camera-to-world transform (columns: x right, y down, z forward in world coordinates, centre)."""

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise InvalidDataError(f"Camera.{name} must be finite, got {value}")
            setattr(self, name, value)
        if self.fx <= 0 or self.fy <= 0:
            raise InvalidDataError(f"Camera focal lengths must be positive pixels, got fx={self.fx}, fy={self.fy}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise InvalidDataError(f"Camera image size must be positive, got {self.width}x{self.height}")
        self.width, self.height = int(self.width), int(self.height)
        m = np.asarray(self.cam_to_world, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise InvalidDataError(f"Camera.cam_to_world must be a finite [4, 4] matrix, got shape {list(m.shape)}")
        rot = m[:3, :3]
        if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-4) or np.linalg.det(rot) < 0:
            raise InvalidDataError("Camera.cam_to_world: the upper 3x3 block must be a rotation (orthonormal, det +1)")
        self.cam_to_world = m

    @classmethod
    def from_intrinsics(cls, K: np.ndarray, cam_to_world: np.ndarray, width: int, height: int) -> Camera:
        """Build a camera from a [3, 3] intrinsics matrix ``K`` (zero skew)."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise InvalidDataError(f"intrinsics K must be [3, 3], got {list(K.shape)}")
        return cls(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], width=width, height=height,
                   cam_to_world=cam_to_world)  # fmt: skip

    @property
    def K(self) -> np.ndarray:
        """[3, 3] intrinsics matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def world_to_cam(self) -> np.ndarray:
        """[4, 4] world-to-camera transform."""
        inv = np.eye(4)
        rot = self.cam_to_world[:3, :3]
        inv[:3, :3] = rot.T
        inv[:3, 3] = -rot.T @ self.cam_to_world[:3, 3]
        return inv

    @property
    def center(self) -> np.ndarray:
        """[3] camera centre in world coordinates, metres."""
        return self.cam_to_world[:3, 3].copy()

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project [N, 3] world points; return ([N, 2] pixel coordinates, [N] camera depth z)."""
        cam = np.asarray(points, dtype=np.float64) @ self.world_to_cam[:3, :3].T + self.world_to_cam[:3, 3]
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * cam[:, 0] / z + self.cx, self.fy * cam[:, 1] / z + self.cy], axis=1)
        return uv, z

    def scaled(self, width: int, height: int) -> Camera:
        """The same camera at another image resolution (intrinsics scaled accordingly)."""
        sx, sy = width / self.width, height / self.height
        return Camera(fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy, width=width,
                      height=height, cam_to_world=self.cam_to_world)  # fmt: skip


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """Return the [4, 4] OpenCV camera-to-world matrix of a camera at ``eye`` looking at ``target``.

    Args:
        eye: [3] camera centre, metres.
        target: [3] point the optical axis passes through, metres.
        up: [3] world direction that appears up in the image (image y points the other way); default +Z.
    """
    up = np.array([0.0, 0.0, 1.0]) if up is None else up
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    forward = target - eye
    if np.linalg.norm(forward) < 1e-9:
        raise InvalidDataError("look_at: eye and target coincide")
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:  # looking along up: pick any perpendicular
        right = np.cross(forward, np.array([1.0, 0.0, 0.0]) if abs(forward[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, down, forward, eye
    return m


def orbit_cameras(
    center: np.ndarray,
    radius: float,
    height: float,
    count: int,
    *,
    width: int = 256,
    image_height: int = 256,
    fov_deg: float = 60.0,
    start_deg: float = 0.0,
    arc_deg: float = 360.0,
) -> list[Camera]:
    """Cameras on a horizontal circle around ``center`` (z up), all looking at it.

    Args:
        center: [3] point looked at, metres.
        radius: Horizontal distance from ``center``, metres.
        height: Camera height above ``center``, metres.
        count: Number of cameras, evenly spaced over ``arc_deg`` (a full circle does not repeat the start).
        width: Image width, pixels.
        image_height: Image height, pixels.
        fov_deg: Horizontal field of view, degrees.
        start_deg: Azimuth of the first camera, degrees.
        arc_deg: Azimuth span, degrees.
    """
    if count < 1:
        raise InvalidDataError(f"orbit_cameras: count must be >= 1, got {count}")
    center = np.asarray(center, dtype=np.float64)
    focal = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
    step = arc_deg / count if abs(arc_deg - 360.0) < 1e-9 else arc_deg / max(count - 1, 1)
    cams = []
    for i in range(count):
        a = np.radians(start_deg + i * step)
        eye = center + np.array([radius * np.cos(a), radius * np.sin(a), height])
        cams.append(Camera(fx=focal, fy=focal, cx=width / 2, cy=image_height / 2, width=width, height=image_height,
                           cam_to_world=look_at(eye, center)))  # fmt: skip
    return cams
