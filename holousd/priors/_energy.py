"""E_obs: how well a candidate shape explains an object's observations, re-rendered into every frame.

Each frame is rendered exactly at the pixel centres (:func:`zbuffer`: the candidate's depth where a ray through a
pixel's centre meets it, or a miss), as a z-buffer over its triangles' projections.
Per frame, on the pixels not hidden by something observed in front of the candidate (depth smaller than the
candidate's by more than ``margin``; where the sensor measured no depth, another object's pixels, as in a frame
without depth: a phone's depth has holes and none at depth edges, where an occluder's outline lies):

- mask IoU between the candidate's silhouette and the object's instance mask;
- depth residual: mean |candidate depth - observed depth| where both say "this object" and depth was measured,
  each pixel's difference capped at ``depth_scale`` (a pixel off by more costs what a missed mask pixel does: a
  segmenter's mask spills a pixel or two onto the neighbours, and on an object seen in a few dozen pixels those
  pixels' depth, the neighbour's, would outweigh the rest. hard/top_only's bin on a phone capture, seen from
  above down a well between two cabinets: the true shape's residual was 31 cm over its mask pixels, mostly the
  cabinets' tops, and E_obs ranked it below a fitted lump 40 cm off the floor; capped, 4.7 cm, it ranks first);
- seen-through pixels: where the candidate puts its nearest surface but the camera measured depth beyond it by
  more than ``margin`` (it saw past that point to something behind), or saw background without depth. A
  candidate with more than ``max_seen_through`` of its silhouette seen through is rejected: it puts matter where
  a camera looked through empty space.

``energy = (1 - IoU) + residual / depth_scale + seen_through``, means over frames weighted by silhouette size.

Among an object's candidates the limit is relative (:func:`seen_through_limit`): the fitted shape (``stage1``)
is never rejected, and its own seen-through share, up to ``max_seen_through`` again, is added to the limit of
the others (on 2.4 cm cells a fitted table is already about 6% seen through); a candidate seen through no more
than the fitted shape is never rejected for it. With ``max_obs_gain``
(:func:`scored_among`) a candidate whose energy exceeds the fitted shape's by more than that is rejected too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from holousd.priors._api import Candidate, ObjectEvidence

__all__ = ["Limit", "ObservationEnergy", "observation_energy", "zbuffer"]


@dataclass(kw_only=True)
class ObservationEnergy:
    """E_obs of one candidate and its parts."""

    energy: float
    """(1 - IoU) + depth residual / depth scale + seen-through fraction (lower is better)."""
    mask_iou: float
    """Silhouette IoU with the instance masks, in [0, 1]."""
    depth_residual_m: float
    """Mean absolute depth difference on the object's observed pixels, each capped at the depth scale, metres (0
    without depth)."""
    seen_through: float
    """Fraction of the candidate's visible silhouette where a camera saw through it, in [0, 1]."""
    rejected: bool
    """True when ``seen_through`` exceeds the limit (matter where the cameras saw empty space) or, among an
    object's candidates with ``max_obs_gain`` (:func:`scored_among`), the energy exceeds the fitted shape's by
    more than that."""
    frames: int
    """Frames the candidate was rendered into."""


def _clip_near(tri: np.ndarray, near: float) -> np.ndarray:
    """Camera-space triangles [F, 3, 3] clipped to z >= ``near``: those wholly behind dropped, those crossing
    the plane cut there (one corner behind: two triangles; two behind: one)."""
    behind = tri[:, :, 2] < near
    count = behind.sum(axis=1)
    out = [tri[count == 0]]
    for n_behind in (1, 2):
        sel = tri[count == n_behind]
        if len(sel) == 0:
            continue
        odd = behind[count == n_behind] if n_behind == 1 else ~behind[count == n_behind]
        first = np.argmax(odd, axis=1)  # the corner on its own side of the plane comes first
        order = (first[:, None] + np.arange(3)[None, :]) % 3
        a, b, c = (np.take_along_axis(sel, order[:, j, None, None].repeat(3, axis=2), axis=1)[:, 0] for j in range(3))

        def cut(p: np.ndarray, q: np.ndarray) -> np.ndarray:
            t = ((near - p[:, 2]) / (q[:, 2] - p[:, 2]))[:, None]
            return p + t * (q - p)

        ab, ac = cut(a, b), cut(a, c)
        if n_behind == 1:  # a behind: the quad ab, b, c, ac
            out += [np.stack([ab, b, c], axis=1), np.stack([ab, c, ac], axis=1)]
        else:  # a in front alone
            out.append(np.stack([a, ab, ac], axis=1))
    return np.concatenate(out) if out else tri[:0]


def zbuffer(points: np.ndarray, faces: np.ndarray, intrinsics: np.ndarray, camera_to_world: np.ndarray,
            shape: tuple[int, int], *, near: float = 1e-3, chunk: int = 2_000_000) -> np.ndarray:  # fmt: skip
    """[H, W] z-depth of a world mesh at every pixel centre (pixel (r, c) is the point u = c, v = r), inf where
    no triangle covers it: each triangle's projection is tested against the pixel centres in its bounding box
    (edge functions) and its depth there is the perspective-correct interpolation, exact for a planar triangle,
    so the result equals a ray cast through each centre. Triangles are clipped at ``near`` in front of the
    camera (a camera standing over a table sees its top, not the legs behind it through the clipped part). At
    most ``chunk`` (triangle, pixel) pairs are held at once."""
    h, w = shape
    k = np.asarray(intrinsics, float)
    pose = np.asarray(camera_to_world, float)
    cam = (np.asarray(points, float) - pose[:3, 3]) @ pose[:3, :3]
    zbuf = np.full(h * w, np.inf)
    faces = np.asarray(faces, np.int64)
    if len(faces) == 0:
        return zbuf.reshape(h, w)
    tri = _clip_near(cam[faces], near)  # [F, 3, 3] camera coordinates, every corner at z >= near
    tz = tri[:, :, 2]
    tu = k[0, 0] * tri[:, :, 0] / tz + k[0, 2]
    tv = k[1, 1] * tri[:, :, 1] / tz + k[1, 2]
    c0 = np.clip(np.ceil(tu.min(1)), 0, w).astype(np.int64)
    c1 = np.clip(np.floor(tu.max(1)), -1, w - 1).astype(np.int64)
    r0 = np.clip(np.ceil(tv.min(1)), 0, h).astype(np.int64)
    r1 = np.clip(np.floor(tv.max(1)), -1, h - 1).astype(np.int64)
    width, height = np.maximum(c1 - c0 + 1, 0), np.maximum(r1 - r0 + 1, 0)
    area = (tu[:, 1] - tu[:, 0]) * (tv[:, 2] - tv[:, 0]) - (tu[:, 2] - tu[:, 0]) * (tv[:, 1] - tv[:, 0])
    count = np.where(np.abs(area) > 1e-12, width * height, 0)
    keep = np.nonzero(count)[0]
    cum = np.cumsum(count[keep])
    start = 0
    while start < len(keep):
        done = int(cum[start - 1]) if start else 0
        stop = max(int(np.searchsorted(cum, done + chunk, side="right")), start + 1)
        sel, start = keep[start:stop], stop
        n = count[sel]
        tri = np.repeat(sel, n)
        offset = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        col = c0[tri] + offset % width[tri]
        row = r0[tri] + offset // width[tri]
        pu, pv = col.astype(float), row.astype(float)
        x, y = tu[tri], tv[tri]
        e0 = (x[:, 1] - pu) * (y[:, 2] - pv) - (x[:, 2] - pu) * (y[:, 1] - pv)
        e1 = (x[:, 2] - pu) * (y[:, 0] - pv) - (x[:, 0] - pu) * (y[:, 2] - pv)
        b0, b1 = e0 / area[tri], e1 / area[tri]
        b2 = 1.0 - b0 - b1
        inside = (b0 >= 0) & (b1 >= 0) & (b2 >= 0)
        if not inside.any():
            continue
        zz = tz[tri[inside]]
        depth = 1.0 / (b0[inside] / zz[:, 0] + b1[inside] / zz[:, 1] + b2[inside] / zz[:, 2])
        np.minimum.at(zbuf, row[inside] * w + col[inside], depth)
    return zbuf.reshape(h, w)


def seen_through_limit(stage1: float, max_seen_through: float = 0.05) -> float:
    """The seen-through share above which an object's candidates are rejected, given the share of its fitted
    shape: ``max_seen_through`` plus that share, capped at ``max_seen_through`` (what the fit's resolution
    gives is no evidence against a candidate; more than twice the limit is), and never below the fitted shape's
    own share (a candidate seen through no more than the shape it completes adds no matter where a camera
    looked through: a phone capture's table, fitted 12% seen through, its far legs mirrored at 11%)."""
    share = max(stage1, 0.0)
    return max(max_seen_through + min(share, max_seen_through), share)


class Limit(NamedTuple):
    """The running rejection limits among an object's candidates (:func:`scored_among`)."""

    seen_through: float
    """Seen-through share above which a candidate is rejected."""
    energy: float = float("inf")
    """E_obs above which a candidate is rejected (the fitted shape's plus ``max_obs_gain``, once it is scored)."""


def scored_among(candidate: Candidate, evidence: ObjectEvidence, limit: float | Limit, *, baseline: bool,
                 max_seen_through: float = 0.05, max_obs_gain: float | None = None,
                 ) -> tuple[ObservationEnergy, Limit]:  # fmt: skip
    """E_obs of one of an object's candidates under the running rejection ``limit``, and the limit for the
    candidates after it. With ``baseline`` and a ``stage1`` candidate (the fitted shape) the candidate is never
    rejected, its own seen-through share sets the seen-through limit (:func:`seen_through_limit`) and, with
    ``max_obs_gain``, its E_obs plus that gain the limit on E_obs: a candidate that explains the observations
    that much worse than the fit does (its silhouette off the masks, its surface off the depth) is no completion
    of what was seen, however well it stands. The limit returned is a :class:`Limit` (a float given is taken
    as a seen-through limit alone); pass it back in for the next candidate."""
    from dataclasses import replace

    limit = limit if isinstance(limit, Limit) else Limit(float(limit))
    energy = observation_energy(candidate, evidence, max_seen_through=limit.seen_through)
    if baseline and candidate.proposer == "stage1":
        gain = float("inf") if max_obs_gain is None else energy.energy + max_obs_gain
        return replace(energy, rejected=False), Limit(seen_through_limit(energy.seen_through, max_seen_through), gain)
    if energy.energy > limit.energy:
        energy = replace(energy, rejected=True)
    return energy, limit


def observation_energy(candidate: Candidate, evidence: ObjectEvidence, *, margin: float = 0.03,
                       depth_scale: float = 0.05, max_seen_through: float = 0.05) -> ObservationEnergy:  # fmt: skip
    """Score ``candidate`` against every frame of ``evidence`` (see the module docstring)."""
    world = evidence.pose.apply(candidate.mesh.points)
    faces = np.asarray(candidate.mesh.faces, np.int64)
    inter = union = 0
    residual_sum = residual_n = 0.0
    through = visible = 0
    used = 0
    for frame in evidence.frames:
        zbuf = zbuffer(world, faces, frame.intrinsics, frame.camera_to_world, frame.labels.shape)
        cand = np.isfinite(zbuf)
        if not cand.any():
            continue
        mine = frame.labels == evidence.instance_id
        other = ~mine & (frame.labels != 0)  # another object's pixels: it may be in front
        if frame.depth is not None:
            d = frame.depth
            measured = d > 0
            # something observed in front of the candidate; where nothing was measured, as in a frame without depth
            hidden = (~mine & measured & (d < zbuf - margin)) | (other & ~measured)
            beyond = cand & measured & (d > zbuf + margin)  # saw past it: to what is behind, or its own far side
            seen = beyond | (cand & ~measured & (frame.labels == 0))
            both = cand & mine & measured & ~hidden
            if both.any():
                residual_sum += float(np.minimum(np.abs(zbuf[both] - d[both]), depth_scale).sum())  # robust: capped
                residual_n += int(both.sum())
        else:
            hidden = other
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
