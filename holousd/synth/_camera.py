"""Hand-held video camera paths: smooth, inside the room, looking at the furniture, at standing eye height."""

from __future__ import annotations

import numpy as np

from holousd.synth._layout import SceneSpec
from holousd.usd import BACKGROUND

__all__ = ["camera_path", "intrinsics_for", "look_at"]

_MIN_HEIGHT, _MAX_HEIGHT = 1.05, 1.85
_WALL_MARGIN = 0.45
_OBJECT_MARGIN = 0.25
HORIZONTAL_FOV_DEG = 70.0
"""Horizontal field of view of the synthetic camera, degrees."""


def intrinsics_for(width: int, height: int) -> np.ndarray:
    """[3, 3] pinhole intrinsics: square pixels, ``HORIZONTAL_FOV_DEG``, principal point at the image centre."""
    f = width / (2 * np.tan(np.radians(HORIZONTAL_FOV_DEG) / 2))
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """[4, 4] OpenCV camera-to-world pose at ``eye`` looking at ``target`` with world Z up (image y down)."""
    forward = target - eye
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-6:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, down, forward], axis=1)
    pose[:3, 3] = eye
    return pose


def _catmull_rom(points: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Centripetal-free (uniform) Catmull-Rom through [K, D] ``points`` at parameters ``s`` in [0, K - 1]."""
    padded = np.concatenate([2 * points[:1] - points[1:2], points, 2 * points[-1:] - points[-2:-1]])
    i = np.clip(np.floor(s).astype(int), 0, len(points) - 2)
    t = (s - i)[:, None]
    p0, p1, p2, p3 = padded[i], padded[i + 1], padded[i + 2], padded[i + 3]
    return 0.5 * (2 * p1 + (p2 - p0) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t**2 + (3 * p1 - p0 - 3 * p2 + p3) * t**3)


def _targets(spec: SceneSpec, extra: list[str]) -> list[tuple[np.ndarray, float]]:
    """(look-at point, object size) of the furniture groups and of the ``extra`` objects."""
    names = list(dict.fromkeys(spec.focus + [o.name for o in spec.objects if o.parent == BACKGROUND] + extra))
    out = []
    for name in names:
        obj = spec.by_name(name)
        family = [obj] + [o for o in spec.objects if _descends(spec, o.name, name)]
        pts = np.concatenate([np.concatenate(o.world_parts()) for o in family])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        centre = (lo + hi) / 2
        if name not in extra:
            centre[2] = min(hi[2] - 0.1, max(lo[2] + 0.3, centre[2] + 0.15))
        out.append((centre, float(np.linalg.norm(hi - lo))))
    return out


def _descends(spec: SceneSpec, name: str, ancestor: str) -> bool:
    node = spec.by_name(name).parent
    while node != BACKGROUND:
        if node == ancestor:
            return True
        node = spec.by_name(node).parent
    return False


def _keep_clear(spec: SceneSpec, eye: np.ndarray) -> np.ndarray:
    """Move ``eye`` inside the room margins and out of the (expanded) bounding box of every object."""
    x, y, h = spec.room.size
    eye = eye.copy()
    eye[0] = np.clip(eye[0], -x / 2 + _WALL_MARGIN, x / 2 - _WALL_MARGIN)
    eye[1] = np.clip(eye[1], -y / 2 + _WALL_MARGIN, y / 2 - _WALL_MARGIN)
    eye[2] = np.clip(eye[2], _MIN_HEIGHT, min(_MAX_HEIGHT, h - 0.3))
    for obj in spec.objects:
        pts = np.concatenate(obj.world_parts())
        lo, hi = pts.min(axis=0) - _OBJECT_MARGIN, pts.max(axis=0) + _OBJECT_MARGIN
        if np.all(eye > lo) and np.all(eye < hi):
            if hi[2] + 0.05 < min(_MAX_HEIGHT, h - 0.3):
                eye[2] = hi[2] + 0.05  # rise over it
            else:  # slide out sideways through the nearest vertical face
                dists = [eye[0] - lo[0], hi[0] - eye[0], eye[1] - lo[1], hi[1] - eye[1]]
                k = int(np.argmin(dists))
                eye[k // 2] = lo[k // 2] if k % 2 == 0 else hi[k // 2]
    return eye


def camera_path(
    spec: SceneSpec,
    frames: int,
    rng: np.random.Generator,
    *,
    extra: list[str] | None = None,
    close: list[str] | None = None,
) -> np.ndarray:
    """[frames, 4, 4] camera-to-world poses of a hand-held sweep through the room.

    One viewpoint per furniture group (plus ``extra`` objects), 1.1-1.9 m away from it on the side facing the
    room, ordered by azimuth around the room centre; position and look-at point follow Catmull-Rom splines
    through them at constant speed, with smooth hand-held wobble. ``close`` objects get a nearer, higher view.
    """
    extra = extra or []
    close = list(spec.close) + (close or [])
    targets = _targets(spec, extra)
    x, y, _ = spec.room.size
    views = []
    for idx, (target, size) in enumerate(targets):
        name = (list(dict.fromkeys(spec.focus + [o.name for o in spec.objects if o.parent == BACKGROUND] + extra)))[idx]
        inward = -target[:2].copy()
        if np.linalg.norm(inward) < 0.3:
            angle = rng.uniform(0, 2 * np.pi)
            inward = np.array([np.cos(angle), np.sin(angle)])
        inward /= np.linalg.norm(inward)
        turn = rng.uniform(-0.6, 0.6)
        direction = np.array(
            [np.cos(turn) * inward[0] - np.sin(turn) * inward[1], np.sin(turn) * inward[0] + np.cos(turn) * inward[1]]
        )
        near = name in close
        dist = (rng.uniform(0.7, 0.95) if near else rng.uniform(1.1, 1.6)) + (0.0 if near else 0.25 * min(size, 2.0))
        height = max(target[2] + rng.uniform(0.7, 0.9), 1.6) if near else target[2] + rng.uniform(0.35, 0.75)
        eye = np.array([target[0] + dist * direction[0], target[1] + dist * direction[1], height])
        views.append((_keep_clear(spec, eye), target))
    azimuth = [np.arctan2(e[1], e[0]) for e, _ in views]
    order = np.argsort(azimuth, kind="stable")
    start = int(rng.integers(len(order)))
    order = np.roll(order, -start)
    if rng.random() < 0.5:
        order = order[::-1]
    eyes = np.array([views[i][0] for i in order])  # [K, 3]
    looks = np.array([views[i][1] for i in order])  # [K, 3]
    if len(eyes) == 1:  # orbit a little around a single target
        offset = np.array([0.4, 0.0, 0.0])
        eyes, looks = np.stack([eyes[0] - offset, eyes[0] + offset]), np.stack([looks[0], looks[0]])
    # constant speed: arc-length parameterisation over a dense sampling of the spline
    dense_s = np.linspace(0, len(eyes) - 1, 50 * len(eyes))
    dense = _catmull_rom(eyes, dense_s)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
    arc = arc / max(arc[-1], 1e-9)
    s = np.interp(np.linspace(0, 1, frames), arc, dense_s)
    eye = _catmull_rom(eyes, s)  # [frames, 3]
    look = _catmull_rom(looks, s)  # [frames, 3]
    t = np.linspace(0, 1, frames)[:, None]
    phase = rng.uniform(0, 2 * np.pi, (2, 3))
    wobble = 0.015 * np.sin(2 * np.pi * 3.0 * t + phase[0]) + 0.01 * np.sin(2 * np.pi * 7.0 * t + phase[1])
    poses = np.zeros((frames, 4, 4))
    for i in range(frames):
        e = _keep_clear(spec, eye[i] + wobble[i])
        target = look[i] + 2.0 * wobble[i]
        if np.linalg.norm(target - e) < 0.2:
            target = e + np.array([0.0, 0.3, -0.2])
        poses[i] = look_at(e, target)
    return poses
