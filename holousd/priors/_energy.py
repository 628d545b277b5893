"""E_obs: how well a candidate shape explains an object's observations, re-rendered into every frame.

Each frame is rendered exactly at the pixel centres: the candidate's surface samples (vertices plus ``samples``
area-weighted points) find the pixels it may cover, and a ray through each of those pixels' centres (and their
neighbours') gives the candidate's depth there, or a miss (trimesh's ray-triangle queries).
Per frame, on the pixels not hidden by something observed in front of the candidate (depth smaller than the
candidate's by more than ``margin``):

- mask IoU between the candidate's silhouette and the object's instance mask;
- depth residual: mean |candidate depth - observed depth| where both say "this object" and depth was measured;
- seen-through pixels: where the candidate puts its nearest surface but the camera measured depth beyond it by
  more than ``margin`` (it saw past that point to something behind), or saw background without depth. A
  candidate with more than ``max_seen_through`` of its silhouette seen through is rejected: it puts matter where
  a camera looked through empty space.

``energy = (1 - IoU) + residual / depth_scale + seen_through``, means over frames weighted by silhouette size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from holousd.priors._api import Candidate, ObjectEvidence

__all__ = ["ObservationEnergy", "observation_energy"]


@dataclass(kw_only=True)
class ObservationEnergy:
    """E_obs of one candidate and its parts."""

    energy: float
    """(1 - IoU) + depth residual / depth scale + seen-through fraction (lower is better)."""
    mask_iou: float
    """Silhouette IoU with the instance masks, in [0, 1]."""
    depth_residual_m: float
    """Mean absolute depth difference on the object's observed pixels, metres (0 without depth)."""
    seen_through: float
    """Fraction of the candidate's visible silhouette where a camera saw through it, in [0, 1]."""
    rejected: bool
    """True when ``seen_through`` exceeds the limit: matter where the cameras saw empty space."""
    frames: int
    """Frames the candidate was rendered into."""


def _surface(candidate: Candidate, evidence: ObjectEvidence, samples: int, seed: int) -> np.ndarray:
    from holousd.geometry._contact import area_samples

    points = np.asarray(candidate.mesh.points, float)
    tri = points[np.asarray(candidate.mesh.faces, np.int64)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    extra = area_samples(tri, area, samples, np.random.default_rng(seed)) if area.sum() > 0 else np.zeros((0, 3))
    return evidence.pose.apply(np.concatenate([points, extra]))


def _centre_depth(intersector, frame, pixels: np.ndarray) -> np.ndarray:  # noqa: ANN001
    """[K] z-depth of the candidate on the centre rays of ``pixels`` ([K, 2] row, col); inf where a ray misses."""
    k = frame.intrinsics
    pose = frame.camera_to_world
    rows, cols = pixels[:, 0].astype(float), pixels[:, 1].astype(float)
    d_cam = np.stack([(cols - k[0, 2]) / k[0, 0], (rows - k[1, 2]) / k[1, 1], np.ones(len(rows))], axis=1)
    directions = d_cam @ pose[:3, :3].T
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    origins = np.broadcast_to(pose[:3, 3], directions.shape)
    out = np.full(len(pixels), np.inf)
    if len(pixels) == 0:
        return out
    locations, index_ray, _ = intersector.intersects_location(origins, directions, multiple_hits=False)
    if len(index_ray):
        out[index_ray] = (locations - pose[:3, 3]) @ pose[:3, 2]
    return out


def observation_energy(candidate: Candidate, evidence: ObjectEvidence, *, samples: int = 20_000,
                       margin: float = 0.03, depth_scale: float = 0.05, max_seen_through: float = 0.05,
                       seed: int = 0) -> ObservationEnergy:  # fmt: skip
    """Score ``candidate`` against every frame of ``evidence`` (see the module docstring)."""
    import trimesh
    from scipy.ndimage import binary_dilation

    from holousd.priors._builtin import _project

    world = _surface(candidate, evidence, samples, seed)
    mesh = trimesh.Trimesh(evidence.pose.apply(candidate.mesh.points), candidate.mesh.faces, process=False)
    intersector = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    inter = union = 0
    residual_sum = residual_n = 0.0
    through = visible = 0
    used = 0
    for frame in evidence.frames:
        h, w = frame.labels.shape
        row, col, _, valid = _project(frame, world)
        if not valid.any():
            continue
        near = np.zeros((h, w), bool)
        near[row[valid], col[valid]] = True
        near = binary_dilation(near)  # every pixel whose centre ray may meet the candidate
        pixels = np.argwhere(near)
        zbuf = np.full((h, w), np.inf)
        zbuf[pixels[:, 0], pixels[:, 1]] = _centre_depth(intersector, frame, pixels)
        cand = np.isfinite(zbuf)
        mine = frame.labels == evidence.instance_id
        if frame.depth is not None:
            d = frame.depth
            measured = d > 0
            hidden = measured & ~mine & (d < zbuf - margin)  # something observed in front of the candidate
            beyond = cand & measured & (d > zbuf + margin)  # saw past it: to what is behind, or its own far side
            seen = beyond | (cand & ~measured & (frame.labels == 0))
            both = cand & mine & measured & ~hidden
            if both.any():
                residual_sum += float(np.abs(zbuf[both] - d[both]).sum())
                residual_n += int(both.sum())
        else:
            hidden = ~mine & (frame.labels != 0)  # another object's pixels: it may be in front
            seen = cand & (frame.labels == 0)
        shown = cand & ~hidden
        inter += int((shown & mine).sum())
        union += int((shown | (mine & ~hidden)).sum())
        through += int((seen & ~hidden).sum())
        visible += int(shown.sum())
        used += 1
    iou = inter / union if union else 0.0
    residual = residual_sum / residual_n if residual_n else 0.0
    seen_through = through / visible if visible else 0.0
    return ObservationEnergy(energy=(1.0 - iou) + residual / depth_scale + seen_through, mask_iou=iou,
                             depth_residual_m=residual, seen_through=seen_through,
                             rejected=seen_through > max_seen_through, frames=used)  # fmt: skip
