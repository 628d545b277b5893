"""Dense voxel grids over an object's extent: projection into posed frames, TSDF fusion, visual-hull carving.

Everything here is numpy and works in world coordinates (metres, Z up) with OpenCV pinhole cameras
(camera-to-world poses, pixel (u, v) centred at image coordinates (u, v)). Depth is z-depth along the optical
axis. Label images hold instance ids (0 = background, the room shell).

The fusion keeps, per voxel, the evidence a stage needs to decide inside / outside of one instance:

- a truncated signed distance averaged over the frames where the voxel lies within the truncation band of the
  instance's observed surface (plus ``+trunc`` from frames where it lies in observed free space),
- votes ``inside`` (the voxel lies behind the instance's observed surface) and ``outside`` (it lies in free space
  in front of some observed surface, or behind the room shell, which no object can be).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "NEIGHBOURS",
    "Consensus",
    "label_consensus",
    "FusionResult",
    "Views",
    "VoxelGrid",
    "box_sdf",
    "carve_hull",
    "confirmed_points",
    "fuse_tsdf",
    "object_points",
    "observed_fraction",
    "sample_grid",
    "signed_distance_from_occupancy",
]


@dataclass(kw_only=True)
class VoxelGrid:
    """An axis-aligned regular grid in world coordinates: sample (i, j, k) at ``origin + voxel_size * (i, j, k)``."""

    origin: np.ndarray
    """[3] world position of sample (0, 0, 0), metres."""
    voxel_size: float
    """Grid spacing, metres."""
    shape: tuple[int, int, int]
    """Number of samples along x, y, z."""

    @classmethod
    def from_bounds(cls, lo: np.ndarray, hi: np.ndarray, voxel_size: float, pad: int = 2) -> VoxelGrid:
        """Grid covering the box [lo, hi] with ``pad`` extra samples on every side."""
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.maximum(np.asarray(hi, dtype=np.float64), lo)
        origin = lo - pad * voxel_size
        shape = np.ceil((hi - lo) / voxel_size).astype(int) + 1 + 2 * pad
        return cls(origin=origin, voxel_size=float(voxel_size), shape=(int(shape[0]), int(shape[1]), int(shape[2])))

    @property
    def size(self) -> int:
        """Number of samples."""
        return int(np.prod(self.shape))

    @property
    def upper(self) -> np.ndarray:
        """[3] world position of the last sample, metres."""
        return self.origin + self.voxel_size * (np.asarray(self.shape) - 1)

    def points(self) -> np.ndarray:
        """[X*Y*Z, 3] float32 world positions of the samples in C order (x slowest)."""
        axes = [self.origin[i] + self.voxel_size * np.arange(self.shape[i]) for i in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3).astype(np.float32)

    def refined(self, factor: int) -> VoxelGrid:
        """The grid over the same box with ``factor`` times finer spacing."""
        shape = tuple(int((n - 1) * factor + 1) for n in self.shape)
        return VoxelGrid(origin=self.origin.copy(), voxel_size=self.voxel_size / factor, shape=shape)  # type: ignore[arg-type]


@dataclass(kw_only=True)
class Views:
    """Posed frames held in memory: labels and (optionally) depth, as the fusion reads them."""

    intrinsics: np.ndarray
    """[N, 3, 3] pinhole intrinsics, pixels."""
    poses: np.ndarray
    """[N, 4, 4] camera-to-world matrices (OpenCV camera)."""
    labels: np.ndarray
    """[N, H, W] int32 instance ids (0 = background)."""
    depth: np.ndarray | None = None
    """[N, H, W] float32 metric z-depth (0 = no value), or None."""

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def height(self) -> int:
        """Image height, pixels."""
        return int(self.labels.shape[1])

    @property
    def width(self) -> int:
        """Image width, pixels."""
        return int(self.labels.shape[2])

    def project(self, i: int, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Project [P, 3] world points into frame ``i``.

        Returns:
            (row [P] int, col [P] int, z [P] float camera z-depth, valid [P] bool: in front of the camera and
            inside the image).
        """
        pose = self.poses[i]
        rot = pose[:3, :3].astype(np.float32)
        cam = (points - pose[:3, 3].astype(np.float32)) @ rot  # [P, 3] camera coordinates
        z = cam[:, 2]
        k = self.intrinsics[i]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_z = 1.0 / np.where(z > 1e-6, z, 1.0)
            u = np.rint(k[0, 0] * cam[:, 0] * inv_z + k[0, 2])
            v = np.rint(k[1, 1] * cam[:, 1] * inv_z + k[1, 2])
        valid = (z > 1e-3) & (u >= 0) & (u < self.width) & (v >= 0) & (v < self.height)
        col = np.where(valid, u, 0).astype(np.int64)
        row = np.where(valid, v, 0).astype(np.int64)
        return row, col, z, valid

    def backproject(self, i: int, select: np.ndarray, stride: int = 1) -> np.ndarray:
        """[P, 3] world points of the ``select``-ed pixels of frame ``i`` (row-major order, every ``stride``-th;
        needs metric depth)."""
        assert self.depth is not None
        rows, cols = np.nonzero(select)
        if stride > 1:
            rows, cols = rows[::stride], cols[::stride]
        d = self.depth[i][rows, cols]
        k = self.intrinsics[i]
        cam = np.stack([(cols - k[0, 2]) / k[0, 0] * d, (rows - k[1, 2]) / k[1, 1] * d, d], axis=1)
        pose = self.poses[i]
        return cam @ pose[:3, :3].T + pose[:3, 3]

    def footprint(self, i: int, depth: float) -> float:
        """Size of one pixel at ``depth`` metres in frame ``i``, metres."""
        k = self.intrinsics[i]
        return float(depth / (0.5 * (k[0, 0] + k[1, 1])))


@dataclass(kw_only=True)
class FusionResult:
    """Per-voxel evidence of one instance (flat arrays over the grid's samples, C order)."""

    tsdf: np.ndarray
    """[P] float32 averaged truncated signed distance, metres (``+trunc`` where nothing was observed)."""
    weight: np.ndarray
    """[P] float32 number of observations averaged into ``tsdf``."""
    inside: np.ndarray
    """[P] int32 frames in which the voxel lies behind the instance's observed surface."""
    outside: np.ndarray
    """[P] int32 frames in which the voxel lies in free space or behind the room shell."""
    free: np.ndarray | None = None
    """[P] int32 frames in which the voxel lies in observed free space (in front of an observed surface, any
    label); None where not counted."""
    behind: np.ndarray | None = None
    """[P] float32 the least distance, metres, the voxel lies behind the instance's observed surface over the
    frames in which it does (``inside``); inf where it never does; None where not measured."""

    def solid_sdf(self, trunc: float, shape: tuple[int, int, int] | None = None, keep: float = 2.0,
                  min_free: int = 2, min_opening: int = 4) -> np.ndarray:
        """[P] signed distance: the TSDF where observed, else ``-trunc`` inside (behind the surface and never
        seen free) and ``+trunc`` elsewhere.

        With ``shape`` (the samples are a whole grid, C order, z last), what was never observed is decided by
        what encloses it:

        - hidden voxels (behind the instance's observed surface) are outside where they open onto space seen
          free under the instance's own observed solid (two voxels in from its edges: a fitted top overhangs its
          true edge by about that), joined to it through hidden voxels. Behind an observed surface and never
          seen is no evidence of matter where cameras saw through under the object: the space
          under a table top between its legs, seen from above and at grazing angles only, is hidden behind the
          top from every camera, and filling it made a cone of matter from the legs' feet to the top's edges. A
          box's or a cabinet's inside stays solid, even with two of its sides unseen (space seen free beside it
          is not under it), and so does what lies within ``keep`` voxels of the observed solid (a board's unseen
          underside, a top's voxels under what stands on it) and what lies between observed solid above and
          below it in its vertical column (a leg's upper end, hidden behind the top's edge from every camera,
          that joins the leg seen below to the top) or that observed solid walls in along x and along y in its
          slice (a ball's inside above its unseen underside; the inside of a cabinet on legs seen from its front
          and one side: under a table only opposite legs line up). Nothing is opened when that would raise the
          instance's lowest point by more than ``keep`` voxels: it stood on what was opened (a ball's unseen underside
          above the floor it rests on; a table none of whose legs was seen);
        - voxels no frame observed at all (hidden behind other objects: a table top under the book lying on
          it) are inside where the instance's observed solid walls them in on three of their four horizontal
          sides, in their slice (the first thing seen along the line, not beyond space seen free: a sofa's arms
          and back around a box on its seat wall in nothing), and none of it lies above them (the back of a
          shelf's compartment behind a bowl stays open).

        An opening is space at least ``min_free`` frames saw free, in a piece of at least ``min_opening`` such
        voxels (faces shared): a noisy depth sensor's return centimetres too far (a flying pixel at an edge)
        now and then makes a voxel behind an observed surface look free in one frame. On the phone demo capture
        9 single voxels behind the cabinet's front and side (each seen free once and behind the surface 12
        times) opened its whole inside: the fitted cabinet was a stack of thin sheets (F1 63, half its volume).
        The space under a table top is thousands of voxels, most seen free by several frames."""
        hidden_inside = (self.weight == 0) & (self.inside > 0) & (self.outside == 0)
        sdf = np.where(self.weight > 0, self.tsdf, trunc).astype(np.float32)
        if shape is None or self.free is None:
            sdf[hidden_inside] = -trunc
            return sdf
        from scipy.ndimage import binary_erosion, distance_transform_edt

        observed = ((self.weight > 0) & (self.tsdf < 0)).reshape(shape)
        # never observed at all (behind other objects in every frame that looks there), walled in by the
        # observed solid on three of four horizontal sides in its slice, with none of it above (the top of a
        # table under a book lying on it; not the back of a shelf's compartment behind a bowl). A wall is the
        # first thing seen along the line: beyond space seen free it walls in nothing (a sofa's arms and back
        # around the box standing on its seat, whose inside it would fill); free is what ``min_free`` frames saw
        # a truncation distance or more in front of a surface, not the band just above one (a top's surface
        # voxels beside what stands on it)
        seen = np.where(observed, 1, np.where((self.free >= min_free).reshape(shape), 2, 0)).astype(np.int8)
        walls = sum((_first_seen(seen, axis, step) == 1).astype(np.int8) for axis in (0, 1) for step in (1, -1))
        unseen = ((self.weight == 0) & (self.outside == 0) & (self.inside == 0)).reshape(shape)
        unseen &= (walls >= 3) & ~_reaches(observed, 2, 1)
        solid = observed | unseen
        over = _reaches(solid, 2, 1)  # solid at or above, in the voxel's column
        held = (distance_transform_edt(~solid) <= keep) | (over & _reaches(solid, 2, -1))
        held |= solid.any(axis=0, keepdims=True) & solid.any(axis=1, keepdims=True)  # walled in along x and y
        deep = hidden_inside & ~held.reshape(-1)
        # openings: space seen free under the instance's own solid, two voxels in from its edges (between a
        # table's legs, in a shelf's compartment), and outside by the fused evidence (a voxel of the surface band
        # that one frame saw past, at a silhouette's edge, is no opening)
        under = binary_erosion(over, structure=_FLAT, iterations=2)
        opening = (self.free >= min_free) & (self.weight > 0) & (self.tsdf >= 0) & under.reshape(-1)
        opening = _large_pieces(opening, shape, min_opening)
        opened = _open_onto(deep, opening, shape)
        before = (sdf < 0) | hidden_inside | unseen.reshape(-1)
        if _lowest(before & ~opened, shape) <= _lowest(before, shape) + keep:  # it still stands where it did
            hidden_inside &= ~opened
        sdf[hidden_inside | unseen.reshape(-1)] = -trunc
        return sdf


_FLAT = np.zeros((3, 3, 3), bool)
"""Face neighbours within a horizontal slice (z last): morphology slice by slice."""
_FLAT[1, :, 1] = _FLAT[:, 1, 1] = True


def _lowest(solid: np.ndarray, shape: tuple[int, int, int]) -> float:
    """Index along z of the lowest ``solid`` voxel (inf when none)."""
    rows = np.nonzero(solid.reshape(shape).any(axis=(0, 1)))[0]
    return float(rows[0]) if len(rows) else np.inf


def _reaches(solid: np.ndarray, axis: int, step: int) -> np.ndarray:
    """[X, Y, Z] whether a straight line from each voxel along ``axis`` (forwards with ``step`` 1, backwards with
    -1) meets ``solid``, the voxel itself included."""
    if step > 0:
        return np.flip(np.maximum.accumulate(np.flip(solid, axis=axis), axis=axis), axis=axis)
    return np.maximum.accumulate(solid, axis=axis)


def _first_seen(code: np.ndarray, axis: int, step: int) -> np.ndarray:
    """[X, Y, Z] the first non-zero ``code`` met on a straight line from each voxel along ``axis`` (forwards with
    ``step`` 1, backwards with -1), the voxel itself included; 0 where the line meets none."""
    n = code.shape[axis]
    shape = [1] * code.ndim
    shape[axis] = n
    index = np.arange(n).reshape(shape)
    if step > 0:
        at = np.flip(np.minimum.accumulate(np.flip(np.where(code > 0, index, n), axis=axis), axis=axis), axis=axis)
    else:
        at = np.maximum.accumulate(np.where(code > 0, index, -1), axis=axis)
    met = np.take_along_axis(code, np.clip(at, 0, n - 1), axis=axis)
    return np.where((at >= 0) & (at < n), met, 0)


def _large_pieces(select: np.ndarray, shape: tuple[int, int, int], size: int) -> np.ndarray:
    """[P] the ``select``-ed voxels lying in pieces (faces shared) of at least ``size`` voxels."""
    from scipy.ndimage import label

    if size <= 1 or not select.any():
        return select
    labels, _ = label(select.reshape(shape))
    labels = labels.reshape(-1)
    counts = np.bincount(labels)
    return select & (counts[labels] >= size) & (labels > 0)


def _open_onto(hidden: np.ndarray, free: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """[P] the ``hidden`` voxels joined (faces shared, through hidden voxels) to a ``free`` one."""
    from scipy.ndimage import label

    labels, _ = label((hidden | free).reshape(shape))
    labels = labels.reshape(-1)
    reached = np.unique(labels[free & (labels > 0)])
    return hidden & np.isin(labels, reached[reached > 0])


def fuse_tsdf(
    points: np.ndarray,
    views: Views,
    instance: int,
    trunc: float,
    frames: Sequence[int] | None = None,
    chunk: int = 1 << 20,
) -> FusionResult:
    """Fuse the masked depth of one instance into a truncated signed distance at ``points``.

    Per frame and voxel with ``delta = depth - z`` (positive: the voxel is in front of the observed surface):
    ``delta >= trunc`` is free space (``+trunc``, any label); ``|delta| < trunc`` on an ``instance`` pixel is a
    surface sample; ``delta <= -trunc`` on an ``instance`` pixel votes inside; ``delta <= -trunc`` on a
    background pixel (behind the room shell) votes outside. Surface samples near another instance's surface
    carry no evidence.

    Args:
        points: [P, 3] world positions (float32).
        views: Frames with depth (metres).
        instance: Instance id to fuse.
        trunc: Truncation distance, metres.
        frames: Frames to use (default: all).
        chunk: Voxels processed at once.
    """
    if views.depth is None:
        raise ValueError("fuse_tsdf needs metric depth")
    n = len(points)
    sdf_sum = np.zeros(n, np.float32)
    weight = np.zeros(n, np.float32)
    inside = np.zeros(n, np.int32)
    outside = np.zeros(n, np.int32)
    seen_free = np.zeros(n, np.int32)
    behind = np.full(n, np.inf, np.float32)
    frames = range(len(views)) if frames is None else frames
    for start in range(0, n, chunk):
        sl = slice(start, min(n, start + chunk))
        pts = points[sl]
        for i in frames:
            row, col, z, valid = views.project(i, pts)
            d = views.depth[i][row, col]
            lab = views.labels[i][row, col]
            valid &= d > 0
            delta = d - z
            own = valid & (lab == instance)
            free = valid & (delta >= trunc)
            band = own & (delta > -trunc) & ~free
            sdf_sum[sl] += np.where(band, delta, 0.0) + np.where(free, trunc, 0.0)
            weight[sl] += band | free
            inside[sl] += own & (delta <= -trunc)
            behind[sl] = np.minimum(behind[sl], np.where(own & (delta <= -trunc), -delta, np.inf))
            outside[sl] += free | (valid & (lab == 0) & (delta <= -trunc))
            seen_free[sl] += free
    tsdf = np.where(weight > 0, sdf_sum / np.maximum(weight, 1.0), trunc).astype(np.float32)
    return FusionResult(tsdf=tsdf, weight=weight, inside=inside, outside=outside, free=seen_free, behind=behind)


@dataclass(kw_only=True)
class Consensus:
    """What :func:`label_consensus` changed (pixel counts over all frames)."""

    checked: int = 0
    """Pixels with depth that enough other frames see to be checked."""
    relabelled: int = 0
    """Pixels given the label the other frames agree on (a segmenter's boundary error, fragment or lost object)."""
    unknown: int = 0
    """Pixels whose label the other frames contradict without agreeing on another (label -1: no evidence)."""
    flying: int = 0
    """Depth pixels the other frames see through (mixed or flying returns at edges; depth set to 0)."""


NEIGHBOURS = (-20, -10, -5, -3, -1, 1, 3, 5, 10, 20)
"""Frame offsets :func:`label_consensus` checks each pixel against."""


def label_consensus(views: Views, *, tol_m: float = 0.02, tol_rel: float = 0.02, min_votes: int = 2,
                    keep: float = 1 / 3, agree: float = 0.6, window: int = 5,
                    neighbours: Sequence[int] = NEIGHBOURS) -> tuple[np.ndarray, np.ndarray, Consensus]:  # fmt: skip
    """Instance labels and depth checked across frames, as a real capture needs (a video segmenter's masks and a
    depth sensor's returns are wrong near boundaries, and sometimes wholly).

    Every pixel with depth is lifted to its 3D point and projected into the frames ``neighbours`` away. Each of
    them that sees the point votes: its label there when its depth agrees with the point's (within
    ``tol_m + tol_rel * z``), "seen through" when its depth lies beyond; a frame whose depth lies in front (the
    point is occluded there), has no depth or sees it within a pixel of a label boundary (where its own labels
    are least sure, and a silhouette seen at a grazing angle puts the point on either side) does not vote. With at least
    ``min_votes`` votes:

    - a depth pixel seen through by 60% of them is a flying pixel: its depth becomes 0;
    - a label that at least a third of them confirm stays;
    - otherwise it becomes the label 60% of them agree on (the object a segmenter lost for a frame; the table
      top a dilated mug mask took), or -1 (unknown: no evidence for any instance) when they agree on none.

    Before that, within each frame: a pixel near a label boundary whose depth is not that of its label's
    pixels around it (see :func:`_off_surface`)
    holds another surface's return (a sensor's coarser depth grid, a mixed return, a mask one pixel off): its
    label becomes -1. The other frames would not catch it: the wall right behind a mug's silhouette is hidden
    behind the mug from the neighbouring frames.

    Pixels without depth keep their label. Labels are only ever checked against the capture's own labels: exact
    masks come back unchanged but for pixels on a boundary that the cameras' rounding puts on either side.

    Returns:
        (labels [N, H, W] int32 with -1 for unknown, depth [N, H, W] float32, what changed).
    """
    if views.depth is None:
        raise ValueError("label_consensus needs metric depth")
    n, h, w = views.labels.shape
    labels = views.labels.copy()
    depth = views.depth.copy()
    stats = Consensus()
    top = int(max(int(views.labels.max()), 0)) + 2  # vote slots: -> 0 .. max label, then "seen through"
    sure: dict[int, np.ndarray] = {}

    def confident(j: int) -> np.ndarray:
        if j not in sure:
            sure[j] = ~_near_label_edge(views.labels[j], 3)
        return sure[j]

    for i in range(n):
        have = views.depth[i] > 0
        if not np.any(have):
            continue
        pts = views.backproject(i, have).astype(np.float32)
        votes = np.zeros((len(pts), top), np.int32)
        for off in neighbours:
            j = i + off
            if j < 0 or j >= n:
                continue
            lab, agree, through = _seen_from(views, j, pts, tol_m, tol_rel, confident(j))
            ok = agree & (lab >= 0)
            np.add.at(votes, (np.flatnonzero(ok), lab[ok]), 1)
            votes[through, top - 1] += 1
        total = votes.sum(axis=1)
        checked = total >= min_votes
        stats.checked += int(checked.sum())
        own = labels[i][have]
        own_votes = votes[np.arange(len(own)), np.clip(own, 0, top - 2)] * (own >= 0)
        best = np.argmax(votes[:, : top - 1], axis=1)
        best_votes = votes[np.arange(len(best)), best]
        flying = checked & (votes[:, top - 1] >= 0.6 * total)
        doubt = checked & ~flying & (own_votes < keep * total)
        agreed = doubt & (best_votes >= agree * total)
        new = own.copy()
        new[agreed] = best[agreed]
        new[doubt & ~agreed] = -1
        stats.relabelled += int((agreed & (best != own)).sum())
        stats.unknown += int((doubt & ~agreed).sum())
        stats.flying += int(flying.sum())
        labels[i][have] = new
        depth[i][have] = np.where(flying, 0.0, depth[i][have])
        odd = _off_surface(views.labels[i], views.depth[i], tol_m, tol_rel, window)
        stats.unknown += int((odd & (labels[i] >= 0)).sum())
        labels[i][odd] = -1
    return labels, depth, stats


def _seen_from(views: Views, j: int, points: np.ndarray, tol_m: float, tol_rel: float,
               sure: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """What frame ``j`` shows where [P, 3] world points project: (its labels there, where its depth is the
    points' within ``tol_m + tol_rel * z``, where it lies beyond them: seen through), [P] each. A point outside
    the image, on a pixel without depth or outside the [H, W] mask ``sure`` is neither."""
    row, col, z, valid = views.project(j, points)
    d = views.depth[j][row, col]  # type: ignore[index]
    valid &= d > 0
    if sure is not None:
        valid &= sure[row, col]
    tol = tol_m + tol_rel * z
    return views.labels[j][row, col], valid & (np.abs(d - z) <= tol), valid & (d > z + tol)


def _off_surface(labels: np.ndarray, depth: np.ndarray, tol_m: float, tol_rel: float, window: int) -> np.ndarray:
    """[H, W] pixels within ``window // 2`` of a label boundary whose depth is farther from the median depth of the
    pixels of the same label in their ``window`` x ``window`` neighbourhood than the tolerance plus three times
    those depths' median absolute deviation (a surface seen at a grazing angle changes depth fast from pixel to
    pixel; a few returns from the wall behind a mug's edge do not move the median or the deviation)."""
    h, w = labels.shape
    near = _near_label_edge(labels, window) & (depth > 0)
    rows, cols = np.nonzero(near)
    if len(rows) == 0:
        return np.zeros((h, w), bool)
    half = window // 2
    offs = np.arange(-half, half + 1)
    rr = np.clip(rows[:, None, None] + offs[None, :, None], 0, h - 1).reshape(len(rows), -1)  # [P, window^2]
    cc = np.clip(cols[:, None, None] + offs[None, None, :], 0, w - 1).reshape(len(rows), -1)
    d = depth[rr, cc].astype(np.float64)
    same = (labels[rr, cc] == labels[rows, cols][:, None]) & (d > 0)
    own = np.where(same, d, np.nan)
    med = np.nanmedian(own, axis=1)  # the pixel itself is always one of them
    spread = np.nanmedian(np.abs(own - med[:, None]), axis=1)  # a surface seen at a grazing angle spreads widely
    z = depth[rows, cols]
    bad = np.abs(z - med) > tol_m + tol_rel * z + 3.0 * spread
    out = np.zeros((h, w), bool)
    out[rows[bad], cols[bad]] = True
    return out


def _near_label_edge(labels: np.ndarray, size: int) -> np.ndarray:
    """[H, W] pixels whose ``size`` x ``size`` neighbourhood holds more than one label."""
    from scipy.ndimage import maximum_filter, minimum_filter

    return maximum_filter(labels, size=size, mode="nearest") != minimum_filter(labels, size=size, mode="nearest")


def confirmed_points(cloud: np.ndarray, frame: np.ndarray, radius: float) -> np.ndarray:
    """The points of an object's back-projected cloud ([P, 3], with the [P] frame each came from) that a point of
    another frame confirms (one within ``radius``). A segmenter's false fragment, or a return from behind a
    silhouette, is seen in one frame only. All of them when fewer than half are confirmed (an object seen in a
    single frame, or frames that do not overlap)."""
    return cloud[_confirmed(cloud, frame, radius)]


def _confirmed(cloud: np.ndarray, frame: np.ndarray, radius: float) -> np.ndarray:
    """[P] the points :func:`confirmed_points` keeps."""
    from scipy.spatial import cKDTree

    if len(cloud) == 0 or len(np.unique(frame)) < 2:
        return np.ones(len(cloud), bool)
    _, idx = cKDTree(cloud).query(cloud, k=12, distance_upper_bound=radius)
    others = np.where(idx < len(cloud), frame[np.minimum(idx, len(cloud) - 1)], -1)
    confirmed = ((others >= 0) & (others != frame[:, None])).any(axis=1)
    return confirmed if confirmed.sum() >= 0.5 * len(cloud) else np.ones(len(cloud), bool)


def object_points(cloud: np.ndarray, frame: np.ndarray, radius: float, views: Views, label: int,
                  check: Sequence[int], *, min_share: float = 0.05, min_frames: int = 3, tol_m: float = 0.02,
                  tol_rel: float = 0.02) -> np.ndarray:  # fmt: skip
    """The points of instance ``label``'s back-projected cloud ([P, 3], with the [P] frame each came from) that
    belong to it: those another frame confirms (:func:`confirmed_points`), then of the pieces they fall into
    (points half a ``radius`` apart always linked, up to 1.7 ``radius`` apart sometimes: cells of half a radius
    joined to their 26 neighbours) all but the small ones few frames see that the others
    contradict: a piece holding less than ``min_share`` of the points, seen in fewer than ``min_frames`` frames
    and reaching more than ``2 * radius`` outside the bounds of the rest, goes when of the frames ``check`` that
    see its points (their depth within ``tol_m + tol_rel * z`` of the point's, or beyond it: seen through), more
    of those (point, frame) pairs show another label there or see through it than show the object.

    A segmenter's false fragments fall on the same wall or panel in two neighbouring frames often enough to
    confirm each other (the phone demo's mug: 3 wall points 2 m away in 338; its bowl: two strips of the shelf's
    side at the image's edge), and a percentile of the extent does not hold against a few such points when the
    object has only a few hundred; the frames farther along the sweep see the wall there. An object's own
    surface falls into pieces where something hides part of it or its depth is dropped at edges; such a piece
    is seen from several frames (a table's leg on a phone's half-resolution depth: 4 points in 3 frames), and the
    others' votes on it are not to be trusted (a thin leg is seen through on a coarse depth grid, the table's top
    beside a box is the box within the tolerance), so the vote decides only for pieces in one or two frames."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if views.depth is None:
        raise ValueError("object_points needs metric depth")
    keep = _confirmed(cloud, frame, radius)
    pts, frm = cloud[keep], np.asarray(frame)[keep].astype(np.int64)
    if len(pts) < 2:
        return pts
    cell = radius / 2.0  # cells linked with their 26 neighbours: points up to 1.7 * radius apart join
    keys = np.floor((pts - pts.min(axis=0)) / cell).astype(np.int64) + 1
    dims = keys.max(axis=0) + 2
    code = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    cells, inv = np.unique(code, return_inverse=True)
    rows, cols = [np.arange(len(cells))], [np.arange(len(cells))]
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                if (dx, dy, dz) <= (0, 0, 0):
                    continue
                wanted = cells + (dx * dims[1] + dy) * dims[2] + dz
                at = np.minimum(np.searchsorted(cells, wanted), len(cells) - 1)
                hit = cells[at] == wanted
                rows.append(np.flatnonzero(hit))
                cols.append(at[hit])
    r, c = np.concatenate(rows), np.concatenate(cols)
    count, piece_of_cell = connected_components(
        coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(len(cells),) * 2), directed=False)
    piece = piece_of_cell[inv].astype(np.int64)
    size = np.bincount(piece, minlength=count)
    span = int(frm.max()) + 1
    seen = np.bincount(np.unique(piece * span + frm) // span, minlength=count)  # frames per piece
    wanted = (size >= min_share * len(pts)) | (seen >= min_frames)
    wanted[np.argmax(size)] = True
    body = pts[wanted[piece]]
    lo, hi = body.min(axis=0) - 2.0 * radius, body.max(axis=0) + 2.0 * radius
    for p in np.flatnonzero(~wanted):
        mine = pts[piece == p]
        if np.all((mine >= lo) & (mine <= hi)):
            wanted[p] = True  # within the object's bounds: it does not widen the extent
            continue
        own = set(frm[piece == p].tolist())
        agree = against = 0
        for j in check:
            if int(j) in own:
                continue
            lab, sees, through = _seen_from(views, int(j), mine, tol_m, tol_rel)
            agree += int((sees & (lab == label)).sum())
            against += int((sees & (lab != label) & (lab >= 0)).sum() + through.sum())
        wanted[p] = agree >= against
    return pts[wanted[piece]]


def carve_hull(
    points: np.ndarray,
    views: Views,
    instance: int,
    frames: Sequence[int] | None = None,
    tolerance: float = 0.0,
    chunk: int = 1 << 20,
) -> tuple[np.ndarray, np.ndarray]:
    """Visual hull of one instance from masks alone.

    A voxel is carved when it projects onto background (label 0) in more than ``tolerance`` of the frames
    that see it; it is kept when it also projects onto the instance in at least one frame. Other instances'
    pixels carry no evidence (they may occlude it).

    Args:
        points: [P, 3] world positions.
        views: Frames (labels only are read).
        instance: Instance id.
        frames: Frames to use (default: all).
        tolerance: Fraction of observing frames allowed to see background (robustness to mask noise).
        chunk: Voxels processed at once.

    Returns:
        (kept [P] bool, hits [P] int32 frames seeing the instance there).
    """
    n = len(points)
    hits = np.zeros(n, np.int32)
    bg = np.zeros(n, np.int32)
    seen = np.zeros(n, np.int32)
    frames = range(len(views)) if frames is None else frames
    for start in range(0, n, chunk):
        sl = slice(start, min(n, start + chunk))
        for i in frames:
            row, col, _, valid = views.project(i, points[sl])
            lab = views.labels[i][row, col]
            seen[sl] += valid
            hits[sl] += valid & (lab == instance)
            bg[sl] += valid & (lab == 0)
    kept = (hits > 0) & (bg <= tolerance * np.maximum(seen, 1))
    return kept, hits


def sample_grid(values: np.ndarray, grid: VoxelGrid, points: np.ndarray, outside: float) -> np.ndarray:
    """Trilinear interpolation of [X, Y, Z] ``values`` at [P, 3] world points (``outside`` beyond the grid)."""
    idx = (np.asarray(points, dtype=np.float64) - grid.origin) / grid.voxel_size  # [P, 3]
    shape = np.asarray(grid.shape)
    inside = np.all((idx >= 0) & (idx <= shape - 1), axis=1)
    idx = np.clip(idx, 0, shape - 1 - 1e-6)
    base = np.floor(idx).astype(np.int64)
    base = np.minimum(base, np.maximum(shape - 2, 0))
    frac = idx - base
    out = np.zeros(len(idx))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (
                    (frac[:, 0] if dx else 1 - frac[:, 0])
                    * (frac[:, 1] if dy else 1 - frac[:, 1])
                    * (frac[:, 2] if dz else 1 - frac[:, 2])
                )
                ix = np.minimum(base[:, 0] + dx, shape[0] - 1)
                iy = np.minimum(base[:, 1] + dy, shape[1] - 1)
                iz = np.minimum(base[:, 2] + dz, shape[2] - 1)
                out += w * values[ix, iy, iz]
    return np.where(inside, out, outside).astype(np.float32)


def box_sdf(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """[P] signed distance of [P, 3] points to the axis-aligned box [lo, hi] (negative inside)."""
    centre = (np.asarray(lo) + np.asarray(hi)) / 2
    half = (np.asarray(hi) - np.asarray(lo)) / 2
    q = np.abs(points - centre) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return (outside + inside).astype(np.float32)


def signed_distance_from_occupancy(occupied: np.ndarray, voxel_size: float) -> np.ndarray:
    """[X, Y, Z] Euclidean signed distance (voxel-centre accurate, negative inside) of a boolean occupancy."""
    from scipy.ndimage import distance_transform_edt

    if not occupied.any():
        return np.full(occupied.shape, 10.0 * voxel_size * max(occupied.shape), np.float32)
    outside = distance_transform_edt(~occupied)
    inside = distance_transform_edt(occupied)
    return ((outside - inside + np.where(occupied, 0.5, -0.5)) * voxel_size).astype(np.float32)


def observed_fraction(points: np.ndarray, faces: np.ndarray, views: Views, instance_id: int,
                      depth_tolerance: float) -> float:  # fmt: skip
    """Fraction [0, 1] of a mesh's surface area that some view saw: the area share of faces whose centre, in at
    least one view, faces the camera, projects into the image onto a pixel labelled ``instance_id`` and, where
    the view has metric depth at that pixel, lies within ``depth_tolerance`` of it (not hidden behind the
    observed surface).

    Args:
        points: [V, 3] mesh vertices in world coordinates, metres.
        faces: [F, 3] triangle vertex indices.
        views: The observing views (labels; depth optional).
        instance_id: The mesh's instance id in ``views.labels``.
        depth_tolerance: Largest difference between a face centre's camera depth and the observed depth, metres.
    """
    points = np.asarray(points, dtype=np.float32)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0:
        return 0.0
    tri = points[faces]  # [F, 3, 3]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # [F, 3]
    area = 0.5 * np.linalg.norm(cross, axis=1)  # [F]
    total = float(area.sum())
    if total <= 0:
        return 0.0
    centre = tri.mean(axis=1)  # [F, 3]
    seen = np.zeros(len(faces), dtype=bool)
    for i in range(len(views)):
        row, col, z, valid = views.project(i, centre)
        to_camera = views.poses[i][:3, 3].astype(np.float32) - centre
        valid &= np.einsum("ij,ij->i", cross, to_camera) > 0
        valid &= views.labels[i][row, col] == instance_id
        if views.depth is not None:
            observed = views.depth[i][row, col]
            valid &= (observed <= 0) | (np.abs(observed - z) <= depth_tolerance)
        seen |= valid
    return float(np.clip(area[seen].sum() / total, 0.0, 1.0))
