"""Metric depth from the colour frames alone: multi-view plane-sweep stereo with the capture's camera poses.

A capture without a depth sensor still holds depth in its colour frames: a textured surface seen from two
posed cameras appears where its depth puts it. For each reference frame, :func:`stereo_depth` sweeps fronto-
parallel planes (uniform in inverse depth between ``near`` and ``far``) through the frames beside it, samples
each of them where a point of the reference at that depth would appear, and scores the hypothesis by the
normalised cross-correlation (NCC) of ``window`` x ``window`` grey patches. NCC does not care about a frame's
exposure or white balance (it is invariant to an affine change of brightness), so a phone's per-frame auto
exposure does not bias it. The score of a depth is the mean of the ``best_of`` best source frames' (a point
hidden from one source by something in front is still matched in the others); the depth with the best score
wins, refined between planes by a parabola through its neighbours' scores.

A depth is kept only where it can be trusted: the winning NCC at least ``min_ncc``, the reference patch
textured (grey standard deviation at least ``min_texture`` levels: a white wall matches every depth equally),
the winner clearly better than a depth a few planes away (``min_margin``: a repeating pattern matches several),
no instance-mask boundary within ``edge`` pixels (a patch across a silhouette mixes an object with what is
behind it) and, when the neighbouring frames were swept too (:func:`consistent`), at least ``min_agree`` of them
agreeing within ``agreement`` of the depth. What is not kept is 0 (no value), as a depth sensor's holes are.

Cost: ``planes`` x ``neighbours`` bilinear samples per pixel; planes are chosen so that the widest baseline
moves a pixel by about ``step_px`` per plane. Measured figures are in the README ("Captures without depth").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from holousd.geometry._grid import _near_label_edge

__all__ = ["StereoConfig", "StereoDepth", "consistent", "stereo_depth", "stereo_neighbours"]


@dataclass(frozen=True, kw_only=True)
class StereoConfig:
    """Settings of the plane sweep (see the module docstring)."""

    near: float = 0.25
    """Nearest depth swept, metres."""
    far: float = 8.0
    """Farthest depth swept, metres."""
    step_px: float = 0.75
    """Image motion per plane along the widest baseline, pixels (sets the number of planes)."""
    min_planes: int = 48
    """Fewest planes."""
    max_planes: int = 256
    """Most planes (bounds the cost per frame)."""
    window: int = 7
    """NCC window, pixels (odd)."""
    neighbours: int = 4
    """Frames swept against each reference frame."""
    best_of: int = 2
    """Best-scoring neighbours averaged per depth: 1 or 2."""
    min_angle_deg: float = 2.0
    """Smallest triangulation angle of a neighbour at the scene's centre, deg (narrower: depth too coarse)."""
    max_angle_deg: float = 25.0
    """Largest triangulation angle of a neighbour, deg (wider: patches no longer look alike)."""
    min_ncc: float = 0.6
    """Smallest winning NCC kept."""
    min_texture: float = 3.0
    """Smallest grey standard deviation of the reference patch kept, 8-bit levels."""
    min_margin: float = 0.03
    """How much better the winner must score than the best depth outside its peak (NCC units)."""
    edge: int = 2
    """Pixels within this distance of an instance-mask boundary get no depth."""
    agreement: float = 0.03
    """Relative depth difference under which two frames agree about a point."""
    min_agree: int = 1
    """Neighbouring frames that must agree about a pixel's depth for it to be kept (0: no check)."""
    max_side: int = 320
    """Frames with a longer side are swept at this size (intrinsics scaled; the depth brought back to full size,
    nearest): memory and time grow with pixels x planes (a 640x480 frame took 55 s and 5.6 GB at full size)."""
    chunk_pixels: int = 2_000_000
    """Pixels x planes swept at once (bounds the memory of a sweep to about 100 bytes each)."""


@dataclass(kw_only=True)
class StereoDepth:
    """One frame's swept depth before the cross-frame check."""

    depth: np.ndarray
    """[H, W] float32 metric z-depth, 0 where no depth is kept."""
    score: np.ndarray
    """[H, W] float32 winning NCC (-1 where no neighbour saw the pixel)."""
    neighbours: list[int]
    """Frames it was swept against."""


def _grey(rgb: np.ndarray) -> np.ndarray:
    return (np.asarray(rgb[..., :3], np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)).astype(np.float32)


def _scene_centre(poses: np.ndarray) -> np.ndarray:
    """The point closest to every camera's optical axis (least squares): where a sweep around a scene looks."""
    centres, axes = poses[:, :3, 3], poses[:, :3, 2]
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for c, d in zip(centres, axes, strict=True):
        proj = np.eye(3) - np.outer(d, d)
        a += proj
        b += proj @ c
    if np.linalg.cond(a) > 1e6:  # all axes parallel: a point 2 m ahead of the mean camera
        return centres.mean(0) + 2.0 * axes.mean(0)
    return np.linalg.solve(a, b)


def stereo_neighbours(poses: np.ndarray, config: StereoConfig | None = None,
                      candidates: Sequence[int] | None = None) -> list[list[int]]:  # fmt: skip
    """For each frame, the frames it is swept against: triangulation angle at the point it looks at between
    ``min_angle_deg`` and ``max_angle_deg``, looking the same way (optical axes within 45 deg), preferring an
    angle of about a third of the way into that range.

    Args:
        poses: [N, 4, 4] camera-to-world.
        config: Settings.
        candidates: Frames that may serve as neighbours (default: all).
    """
    config = config or StereoConfig()
    poses = np.asarray(poses, np.float64)
    centre = _scene_centre(poses)
    centres, axes = poses[:, :3, 3], poses[:, :3, 2]
    pool = np.arange(len(poses)) if candidates is None else np.asarray(candidates, int)
    ideal = config.min_angle_deg + (config.max_angle_deg - config.min_angle_deg) / 3.0
    out = []
    for i in range(len(poses)):
        ahead = max(float((centre - centres[i]) @ axes[i]), config.near * 2)
        target = centres[i] + ahead * axes[i]  # the point on the optical axis level with the scene's centre
        to_i = centres[i] - target
        rays = centres[pool] - target
        cos = rays @ to_i / np.maximum(np.linalg.norm(rays, axis=1) * np.linalg.norm(to_i), 1e-12)
        angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        facing = axes[pool] @ axes[i] > np.cos(np.radians(45.0))
        ok = (pool != i) & facing & (angle >= config.min_angle_deg) & (angle <= config.max_angle_deg)
        order = np.argsort(np.abs(angle - ideal) + 1e3 * ~ok)
        out.append([int(pool[j]) for j in order[: config.neighbours] if ok[j]])
    return out


def _box(x, window: int):  # noqa: ANN001, ANN202 - torch tensors [B, 1, H, W]
    import torch.nn.functional as F

    return F.avg_pool2d(x, window, stride=1, padding=window // 2, count_include_pad=False)


def stereo_depth(i: int, rgb: Sequence[np.ndarray], intrinsics: np.ndarray, poses: np.ndarray,
                 neighbours: Sequence[int], config: StereoConfig | None = None,
                 labels: np.ndarray | None = None) -> StereoDepth:  # fmt: skip
    """Plane-sweep depth of frame ``i`` against ``neighbours`` (see the module docstring).

    Args:
        i: Reference frame.
        rgb: Colour images by frame index (only ``i`` and ``neighbours`` are read): [H, W, 3] uint8.
        intrinsics: [N, 3, 3] pinhole intrinsics.
        poses: [N, 4, 4] camera-to-world (OpenCV camera), metres.
        neighbours: Frames to sweep against (:func:`stereo_neighbours`).
        config: Settings.
        labels: The reference frame's [H, W] instance mask (no depth kept at its boundaries), or None.
    """
    import torch
    import torch.nn.functional as F

    config = config or StereoConfig()
    ref = _grey(rgb[i])
    h, w = ref.shape
    if not neighbours:
        return StereoDepth(depth=np.zeros((h, w), np.float32), score=np.full((h, w), -1.0, np.float32), neighbours=[])
    k = np.asarray(intrinsics[i], np.float64)
    pose_i = np.asarray(poses[i], np.float64)
    widest = max(float(np.linalg.norm(poses[j][:3, 3] - pose_i[:3, 3])) for j in neighbours)
    span = 1.0 / config.near - 1.0 / config.far
    planes = int(np.clip(np.ceil(k[0, 0] * widest * span / config.step_px), config.min_planes, config.max_planes))
    inv = np.linspace(1.0 / config.near, 1.0 / config.far, planes)  # near to far
    depths = torch.tensor(1.0 / inv, dtype=torch.float32)

    win = config.window
    r = torch.from_numpy(ref)[None, None]
    mu_r = _box(r, win)
    var_r = (_box(r * r, win) - mu_r**2).clamp_min(0.0)
    cols, rows = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([(cols - k[0, 2]) / k[0, 0], (rows - k[1, 2]) / k[1, 1], np.ones_like(cols)], -1)  # [H, W, 3]

    best1 = torch.full((planes, h, w), -1.0)
    best2 = torch.full((planes, h, w), -1.0)
    chunk = max(1, int(config.chunk_pixels // max(1, h * w)))  # planes swept at once: bounded memory
    for j in neighbours:
        rel = np.linalg.inv(np.asarray(poses[j], np.float64)) @ pose_i  # reference camera -> source camera
        a = torch.tensor(rays @ rel[:3, :3].T, dtype=torch.float32)  # [H, W, 3]: direction in the source camera
        t = torch.tensor(rel[:3, 3], dtype=torch.float32)
        ks = np.asarray(intrinsics[j], np.float64)
        grey = torch.from_numpy(_grey(rgb[j]))[None, None]
        for s in range(0, planes, chunk):
            d = depths[s : s + chunk]
            p = d[:, None, None, None] * a[None] + t  # [D, H, W, 3]
            z = p[..., 2]
            zs = z.clamp_min(1e-6)
            u = ks[0, 0] * p[..., 0] / zs + ks[0, 2]
            v = ks[1, 1] * p[..., 1] / zs + ks[1, 2]
            inside = (z > 1e-3) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
            grid = torch.stack([u / (w - 1) * 2 - 1, v / (h - 1) * 2 - 1], -1)
            src = grey.expand(len(d), 1, h, w)
            warped = F.grid_sample(src, grid, mode="bilinear", padding_mode="border", align_corners=True)  # [D,1,H,W]
            mu_s = _box(warped, win)
            var_s = (_box(warped * warped, win) - mu_s**2).clamp_min(0.0)
            cov = _box(warped * r, win) - mu_s * mu_r
            ncc = (cov / torch.sqrt(var_s * var_r + 1e-3))[:, 0]
            full = _box(inside[:, None].float(), win)[:, 0] > 0.999  # the whole window lands inside the source
            ncc = torch.where(full, ncc, torch.tensor(-1.0))
            b1, b2 = best1[s : s + chunk], best2[s : s + chunk]
            b2.copy_(torch.maximum(b2, torch.minimum(b1, ncc)))
            b1.copy_(torch.maximum(b1, ncc))
            del p, u, v, grid, warped, mu_s, var_s, cov
    score = best1 if config.best_of <= 1 or len(neighbours) < 2 else (best1 + best2) / 2
    top, arg = score.max(0)  # [H, W]
    # the best score outside the winner's peak (more than two planes away)
    idx = torch.arange(planes)[:, None, None]
    away = (idx - arg[None]).abs() > 2
    runner = torch.where(away, score, torch.tensor(-2.0)).max(0).values
    lo = (arg - 1).clamp(0, planes - 1)
    hi = (arg + 1).clamp(0, planes - 1)
    s0 = score.gather(0, lo[None])[0]
    s2 = score.gather(0, hi[None])[0]
    curv = s0 - 2 * top + s2
    offset = torch.where((curv < -1e-6) & (arg > 0) & (arg < planes - 1), 0.5 * (s0 - s2) / curv, torch.tensor(0.0))
    inv_t = torch.tensor(inv, dtype=torch.float32)
    step = inv_t[1] - inv_t[0] if planes > 1 else torch.tensor(0.0)
    inv_best = inv_t[arg] + offset.clamp(-0.5, 0.5) * step
    depth = (1.0 / inv_best).numpy().astype(np.float32)
    top_n = top.numpy().astype(np.float32)
    std = torch.sqrt(var_r)[0, 0].numpy()
    keep = (top_n >= config.min_ncc) & (std >= config.min_texture)
    keep &= (top - runner).numpy() >= config.min_margin
    keep &= (arg.numpy() > 0) & (arg.numpy() < planes - 1)  # a winner at the sweep's end is out of range
    if labels is not None:
        if config.edge > 0:
            keep &= ~_near_label_edge(np.asarray(labels), 2 * config.edge + 1)
    return StereoDepth(depth=np.where(keep, depth, 0.0).astype(np.float32), score=top_n, neighbours=list(neighbours))


def consistent(i: int, depth: dict[int, np.ndarray], intrinsics: np.ndarray, poses: np.ndarray,
               neighbours: Sequence[int], config: StereoConfig | None = None) -> np.ndarray:  # fmt: skip
    """Frame ``i``'s depth with every pixel that fewer than ``min_agree`` neighbouring frames confirm set to 0.

    A neighbour confirms a pixel when the point's depth in that neighbour's camera is within ``agreement`` of the
    depth the neighbour found at the pixel it lands on (a wrong match lands on a surface at another depth).
    """
    config = config or StereoConfig()
    d = depth[i]
    if config.min_agree <= 0:
        return d
    rows, cols = np.nonzero(d > 0)
    if len(rows) == 0:
        return d
    k = intrinsics[i]
    z = d[rows, cols].astype(np.float64)
    cam = np.stack([(cols - k[0, 2]) / k[0, 0] * z, (rows - k[1, 2]) / k[1, 1] * z, z], 1)
    world = cam @ poses[i][:3, :3].T + poses[i][:3, 3]
    votes = np.zeros(len(rows), np.int32)
    h, w = d.shape
    for j in neighbours:
        if j not in depth:
            continue
        pose = poses[j]
        pj = (world - pose[:3, 3]) @ pose[:3, :3]
        kj = intrinsics[j]
        zj = pj[:, 2]
        ok = zj > 1e-3
        u = np.rint(kj[0, 0] * pj[:, 0] / np.where(ok, zj, 1.0) + kj[0, 2]).astype(np.int64)
        v = np.rint(kj[1, 1] * pj[:, 1] / np.where(ok, zj, 1.0) + kj[1, 2]).astype(np.int64)
        ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
        seen = np.where(ok, depth[j][np.where(ok, v, 0), np.where(ok, u, 0)], 0.0)
        votes += (seen > 0) & (np.abs(seen - zj) <= config.agreement * zj)
    out = np.zeros_like(d)
    kept = votes >= config.min_agree
    out[rows[kept], cols[kept]] = d[rows[kept], cols[kept]]
    return out
