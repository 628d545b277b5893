"""Camera poses refined against the capture's own depth, when the depth is better than the poses.

Poses from structure from motion or a weak tracker can be off by tenths of a degree to degrees; fused as given,
the same wall lands centimetres apart in two frames and every fitted surface comes out thick and lumpy.
:func:`refine_poses` aligns every frame's depth with that of the frames it overlaps most, all at once (a
multi-view point-to-plane alignment solved jointly for all frames by Gauss-Newton), with a Gaussian prior that
keeps each frame near its given pose:

    E = sum_(i, j) sum_p rho(n_q . (T_i p - q)) / sigma_d^2 + sum_i |dt_i|^2 / sigma_t^2 + |dw_i|^2 / sigma_r^2

where ``p`` is a depth point of frame ``i``, ``q`` the point frame ``j`` saw along the same line of sight (its
inverse depth interpolated between four pixels of one label, no depth jump between them), ``n_q`` its normal,
``rho`` Huber's loss, ``dt_i`` the move of frame ``i``'s centre and ``dw_i`` its turn about it. Pairs whose
points lie further apart than ``max_distance`` or whose normals disagree are none; correspondences are found
again each round. The prior fixes what depth leaves free (where the scene is as a whole, a frame that sees a
single wall) and is tight on centres (``sigma_translation`` 5 mm) and loose on turns (1 deg): a turn moves far
surfaces most, and a frame's weakly seen directions otherwise slide on the depth's smallest biases.

Depth sensors have errors of their own that look like a pose error (a smooth per-frame bias field tilts a wall
the way a turn does), so depth cannot tell a good tracker's poses any better than they are. Started from the
exact poses of the demo capture, the alignment moves frames five apart by 7 mm and 0.24 deg relative to each
other on the synthetic lidar sensor's depth and by 17 mm and 0.59 deg on the phone's (``holousd synth
--sensor``), fitting those errors (0.3 mm and 0.006 deg on exact depth), where the sensors' own trackers are off
by 1.5 mm / 0.08 deg and 3.8 mm / 0.27 deg. :func:`refine_poses` therefore keeps the given poses unless they
are clearly worse than the depth: the refined poses are used only when they cut the median point-to-plane
disagreement between the frames to under ``max_ratio`` of what it was with the given ones. On the lidar
sensor with its tracker's error doubled it falls to 0.43 and the relative rotation error from 0.48 to 0.22 deg;
with the tracker as it is, 0.87; on the phone sensor 0.64-0.87 at one to eight times its tracker's error.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from holousd.geometry._grid import Views

__all__ = ["PoseConfig", "PoseRefinement", "axis_angle", "refine_poses", "rotation_matrix", "spread_corrections"]


@dataclass(kw_only=True)
class PoseConfig:
    """Settings of :func:`refine_poses`."""

    points_per_frame: int = 1500
    """Depth points sampled per frame (a regular pixel grid), at most."""
    normal_radius: int = 2
    """Normals from the points this many pixels (per 160 of image width) to either side."""
    overlap_frames: int = 8
    """Frames each frame is aligned with: those its points project into most."""
    min_overlap: float = 0.2
    """A pair is aligned only when this share of one frame's points projects into the other's image."""
    rounds: int = 6
    """Rounds of correspondence search, each followed by one joint Gauss-Newton step."""
    max_distance: float = 0.05
    """Points further apart than this are no correspondence, metres."""
    min_normal_cos: float = 0.8
    """Points whose normals differ more than this (cosine) are no correspondence."""
    samples_per_pair: float = 200.0
    """A pair's correspondences count as at most this many independent measurements (their errors are not
    independent: a depth sensor's per-frame bias field, the sampling's own bias)."""
    huber: float = 0.01
    """Huber threshold of the point-to-plane residual, metres."""
    sigma_depth: float = 0.01
    """Scale of the point-to-plane residual in the data term, metres."""
    sigma_translation: float = 0.005
    """Prior on the move of a frame's centre, metres."""
    sigma_rotation_deg: float = 1.0
    """Prior on the turn of a frame, degrees."""
    max_ratio: float = 0.5
    """The refined poses are used only when the median disagreement falls below this share of the given poses'
    (see the module docstring); ``inf`` uses them whenever frames overlap and the alignment kept its
    correspondences."""
    min_kept: float = 0.8
    """... and only when the last round found at least this share of the first round's correspondences."""
    grid_offset: int = 0
    """Offset of the sampled pixel grid (frame ``i`` starts at ``grid_offset + i``; nothing here is random)."""


@dataclass(kw_only=True)
class PoseRefinement:
    """What :func:`refine_poses` found."""

    poses: np.ndarray
    """[N, 4, 4] camera-to-world poses to use: the refined ones when ``applied``, else the given ones."""
    translation: np.ndarray
    """[N] how far the alignment moved each camera centre, metres (applied or not)."""
    rotation_deg: np.ndarray
    """[N] how far it turned each camera, degrees (applied or not)."""
    residual_before: float = 0.0
    """Median |point-to-plane disagreement| between overlapping frames with the given poses, metres (inf: no
    correspondence)."""
    residual_after: float = 0.0
    """The same with the refined poses, metres."""
    pairs: int = 0
    """Frame pairs aligned."""
    applied: bool = False
    """The refined poses are used (the disagreement fell below ``max_ratio`` of the given poses')."""
    wall_s: float = 0.0
    """Wall-clock time of the alignment, seconds."""

    @property
    def ratio(self) -> float:
        """``residual_after / residual_before`` (1.0 when nothing overlapped, inf when the alignment lost every
        correspondence)."""
        if not np.isfinite(self.residual_before) or self.residual_before <= 0:
            return 1.0
        return self.residual_after / self.residual_before


def rotation_matrix(w: np.ndarray) -> np.ndarray:
    """[3, 3] rotation matrix of the axis-angle vector ``w`` (axis times angle, radians; Rodrigues)."""
    angle = float(np.linalg.norm(w))
    if angle < 1e-15:
        return np.eye(3)
    k = np.asarray(w, dtype=np.float64) / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * kx + (1.0 - np.cos(angle)) * kx @ kx


def _lift(k: np.ndarray, rows: np.ndarray, cols: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Camera-frame points of pixels (``rows``, ``cols``, any shape) at z-depth ``depth``: [..., 3]."""
    return np.stack([(cols - k[0, 2]) / k[0, 0] * depth, (rows - k[1, 2]) / k[1, 1] * depth, depth], axis=-1)


def _normals_at(views: Views, i: int, rows: np.ndarray, cols: np.ndarray, r: int) -> np.ndarray:
    """[P, 3] unit camera-frame normals of frame ``i``'s depth at pixels (``rows``, ``cols``), facing the
    camera, from the points ``r`` pixels to either side; zero where a side is outside the image, has no depth,
    lies across a depth jump (3%) or has another label."""
    assert views.depth is not None
    depth, lab, k = views.depth[i], views.labels[i], views.intrinsics[i]
    h, w = depth.shape
    inside = (rows >= r) & (rows < h - r) & (cols >= r) & (cols < w - r)
    v, u = np.where(inside, rows, r), np.where(inside, cols, r)
    centre = depth[v, u].astype(np.float64)
    ok = inside & (centre > 0)
    sides = []
    for dv, du in ((0, r), (0, -r), (r, 0), (-r, 0)):
        d = depth[v + dv, u + du].astype(np.float64)
        ok &= (d > 0) & (np.abs(d - centre) < 0.03 * centre) & (lab[v + dv, u + du] == lab[v, u])
        sides.append(_lift(k, v + dv, u + du, d))
    n = np.cross(sides[2] - sides[3], sides[0] - sides[1])  # down x along: towards the camera
    length = np.linalg.norm(n, axis=1, keepdims=True)
    ok &= length[:, 0] > 1e-12
    return np.where(ok[:, None], n / np.maximum(length, 1e-12), 0.0)


def _sample(views: Views, i: int, count: int, offset: int, r: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points and normals of frame ``i`` on a regular pixel grid of about ``count`` pixels (only
    pixels with a normal)."""
    assert views.depth is not None
    h, w = views.depth[i].shape
    stride = max(1, int(np.ceil(np.sqrt(h * w / max(count, 1)))))
    rows = np.arange(offset % stride, h, stride)
    cols = np.arange((offset // stride) % stride, w, stride)
    vv, uu = (a.ravel() for a in np.meshgrid(rows, cols, indexing="ij"))
    normal = _normals_at(views, i, vv, uu, r)
    keep = np.any(normal != 0, axis=1)
    vv, uu = vv[keep], uu[keep]
    return _lift(views.intrinsics[i], vv, uu, views.depth[i][vv, uu].astype(np.float64)), normal[keep]


def _surface_at(views: Views, j: int, pose: np.ndarray, world: np.ndarray, r: int,
                jump: float = 0.03) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Where frame ``j`` (at ``pose``) saw the surface along the lines of sight to [P, 3] ``world`` points: the
    point at the inverse depth interpolated between the four pixels around (inverse depth is linear across a
    plane's image, depth is not) and the nearest pixel's normal, world frame, and which points have one (in the
    image, the four pixels with depth agreeing within ``jump`` and one label, a normal)."""
    assert views.depth is not None
    depth = views.depth[j]
    h, w = depth.shape
    k = views.intrinsics[j]
    rot = pose[:3, :3]
    cam = (world - pose[:3, 3]) @ rot
    z = cam[:, 2]
    ok = z > 1e-3
    zs = np.where(ok, z, 1.0)
    u = k[0, 0] * cam[:, 0] / zs + k[0, 2]
    v = k[1, 1] * cam[:, 1] / zs + k[1, 2]
    ok &= (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    u0 = np.clip(np.floor(u), 0, w - 2).astype(np.int64)
    v0 = np.clip(np.floor(v), 0, h - 2).astype(np.int64)
    fu, fv = np.clip(u - u0, 0, 1), np.clip(v - v0, 0, 1)
    d = [depth[v0, u0], depth[v0, u0 + 1], depth[v0 + 1, u0], depth[v0 + 1, u0 + 1]]
    dmin, dmax = np.min(d, axis=0), np.max(d, axis=0)
    ok &= (dmin > 0) & (dmax - dmin < jump * np.maximum(dmin, 1e-6))
    lab = views.labels[j]
    corner = lab[v0, u0]
    ok &= (lab[v0, u0 + 1] == corner) & (lab[v0 + 1, u0] == corner) & (lab[v0 + 1, u0 + 1] == corner)
    inv = [1.0 / np.maximum(x, 1e-6) for x in d]
    di = 1.0 / np.maximum((inv[0] * (1 - fu) + inv[1] * fu) * (1 - fv) + (inv[2] * (1 - fu) + inv[3] * fu) * fv, 1e-6)
    nearest = np.zeros((len(world), 3))
    near_v = np.clip(np.rint(v), 0, h - 1).astype(np.int64)
    near_u = np.clip(np.rint(u), 0, w - 1).astype(np.int64)
    nearest[ok] = _normals_at(views, j, near_v[ok], near_u[ok], r)
    ok &= np.any(nearest != 0, axis=1)
    return _lift(k, v, u, di) @ rot.T + pose[:3, 3], nearest @ rot.T, ok


def _overlaps(views: Views, cams: list[np.ndarray], config: PoseConfig) -> list[tuple[int, int]]:
    """Frame pairs (i, j), i's points against j's surface: j among the ``overlap_frames`` frames that i's points
    project into most, when at least ``min_overlap`` of them do."""
    pairs = []
    for i, pts in enumerate(cams):
        if len(pts) == 0:
            continue
        world = (pts @ views.poses[i, :3, :3].T + views.poses[i, :3, 3]).astype(np.float32)
        shares = sorted(((float(views.project(j, world)[3].mean()), j) for j in range(len(views))
                         if j != i and len(cams[j])), reverse=True)  # fmt: skip
        pairs += [(i, j) for share, j in shares[: config.overlap_frames] if share >= config.min_overlap]
    return pairs


def _pair_terms(views: Views, poses: np.ndarray, i: int, j: int, x: np.ndarray, normal: np.ndarray, r: int,
                config: PoseConfig) -> tuple[np.ndarray, np.ndarray] | None:  # fmt: skip
    """Frame ``i``'s world points ``x`` (normals ``normal``) against what frame ``j`` saw: the point-to-plane
    residuals [M] and their Jacobians [M, 12] in (dt_i, dw_i, dt_j, dw_j); None with under six
    correspondences."""
    y, nq, hit = _surface_at(views, j, poses[j], x, r)
    hit &= np.linalg.norm(x - y, axis=1) <= config.max_distance
    hit &= np.einsum("ij,ij->i", normal, nq) >= config.min_normal_cos
    if int(hit.sum()) < 6:
        return None
    x, y, nq = x[hit], y[hit], nq[hit]
    # j's turn moves q (n.(w x (q - c_j))) and turns n_q ((w x n).(x - q)): together n.(w x (x - c_j))
    jac = np.concatenate([nq, np.cross(x - poses[i, :3, 3], nq), -nq, -np.cross(x - poses[j, :3, 3], nq)], axis=1)
    return np.einsum("ij,ij->i", nq, x - y), jac


def refine_poses(views: Views, config: PoseConfig | None = None) -> PoseRefinement:
    """Refine the camera poses of ``views`` (metric depth needed) against their own depth and keep them when the
    depth says they are clearly better than the given ones; see the module docstring. ``views`` is not
    changed."""
    if views.depth is None:
        raise ValueError("refine_poses needs metric depth")
    config = config or PoseConfig()
    start = time.perf_counter()
    n = len(views)
    given = np.asarray(views.poses, np.float64)
    radius = config.normal_radius * max(1, round(views.width / 160))
    samples = [_sample(views, i, config.points_per_frame, config.grid_offset + i, radius) for i in range(n)]
    pairs = _overlaps(views, [c for c, _ in samples], config)
    precision = [1.0 / config.sigma_translation**2] * 3 + [1.0 / np.radians(config.sigma_rotation_deg) ** 2] * 3
    prior = np.tile(precision, n)
    poses = given.copy()
    state = np.zeros((n, 6))  # accumulated corrections: move of the centre, turn about it (world axis-angle)
    levels: list[float] = []  # per round: median |residual| and correspondences
    counts: list[int] = []
    for round_ in range(config.rounds + 1):
        world = [c @ poses[i, :3, :3].T + poses[i, :3, 3] for i, (c, _) in enumerate(samples)]
        normals = [m @ poses[i, :3, :3].T for i, (_, m) in enumerate(samples)]
        hess = np.zeros((6 * n, 6 * n))
        grad = np.zeros(6 * n)
        residuals = []
        for i, j in pairs:
            terms = _pair_terms(views, poses, i, j, world[i], normals[i], radius, config)
            if terms is None:
                continue
            r, jac = terms
            residuals.append(np.abs(r))
            weight = np.minimum(1.0, config.huber / np.maximum(np.abs(r), 1e-12)) / config.sigma_depth**2
            jw = jac * (weight * min(1.0, config.samples_per_pair / len(r)))[:, None]
            idx = np.r_[6 * i : 6 * i + 6, 6 * j : 6 * j + 6]
            hess[np.ix_(idx, idx)] += jac.T @ jw
            grad[idx] += jw.T @ r
        levels.append(float(np.median(np.concatenate(residuals))) if residuals else np.inf)
        counts.append(sum(len(r) for r in residuals))
        if round_ == config.rounds:
            break
        hess[np.diag_indices_from(hess)] += prior
        step = -np.linalg.solve(hess, grad + prior * state.ravel()).reshape(n, 6)
        for i in range(n):
            poses[i, :3, :3] = rotation_matrix(step[i, 3:]) @ poses[i, :3, :3]
            poses[i, :3, 3] += step[i, :3]
        state += step
    moved = np.linalg.norm(poses[:, :3, 3] - given[:, :3, 3], axis=1)
    turned = np.array([np.degrees(np.linalg.norm(axis_angle(poses[i, :3, :3] @ given[i, :3, :3].T))) for i in range(n)])
    result = PoseRefinement(poses=poses, translation=moved, rotation_deg=turned, residual_before=levels[0],
                            residual_after=levels[-1], pairs=len(pairs))  # fmt: skip
    result.wall_s = time.perf_counter() - start
    # the disagreement falls on (nearly) as many correspondences as there were: a result that lost its
    # correspondences (diverged) is not an improvement however small what is left
    kept = counts[-1] >= config.min_kept * counts[0]
    result.applied = bool(pairs) and kept and result.ratio < config.max_ratio
    if not result.applied:
        result.poses = given.copy()
    return result


def spread_corrections(index: np.ndarray, given: np.ndarray, refined: np.ndarray, poses: np.ndarray,
                       smooth: float = 2.0) -> np.ndarray:  # fmt: skip
    """The corrections found on the frames ``index`` of a capture (``given`` -> ``refined``, [M, 4, 4] each)
    carried over to all of the capture's [N, 4, 4] ``poses``: a refined frame gets its own; a frame between
    refined ones gets their corrections averaged over about ``smooth`` refined frames to either side (a Gaussian
    of that width in their order) and interpolated by frame number. What neighbouring frames share is a
    tracker's drift; a frame's own jitter no other frame can tell, so carrying a neighbour's over would add its
    jitter instead of removing any. Frames beyond the first and last refined ones hold those ends' values."""
    out = np.array(poses, np.float64, copy=True)
    index = np.asarray(index)
    if len(index) == 0:
        return out
    delta_t = refined[:, :3, 3] - given[:, :3, 3]
    delta_w = np.array([axis_angle(refined[k, :3, :3] @ given[k, :3, :3].T) for k in range(len(index))])
    if smooth > 0 and len(index) > 1:
        order = np.arange(len(index))
        weight = np.exp(-0.5 * ((order[:, None] - order[None, :]) / smooth) ** 2)
        weight /= weight.sum(axis=1, keepdims=True)
        delta_t, delta_w = weight @ delta_t, weight @ delta_w
    frames = np.arange(len(out))
    t = np.stack([np.interp(frames, index, delta_t[:, a]) for a in range(3)], axis=1)
    w = np.stack([np.interp(frames, index, delta_w[:, a]) for a in range(3)], axis=1)
    for f in frames:
        out[f, :3, :3] = rotation_matrix(w[f]) @ out[f, :3, :3]
        out[f, :3, 3] += t[f]
    out[index] = refined
    return out


def axis_angle(rot: np.ndarray) -> np.ndarray:
    """[3] rotation axis times angle (radians) of the rotation matrix ``rot`` (an angle below 180 deg)."""
    angle = np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0))
    if angle < 1e-12:
        return np.zeros(3)
    axis = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]]) / (2.0 * np.sin(angle))
    return axis * angle
