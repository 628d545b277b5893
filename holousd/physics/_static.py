"""A quasi-static stability check: does a rigid body stand where it is, on what is under it?

A rigid body resting on a support under gravity is in equilibrium when the vertical through its centre of mass
passes inside the convex hull of its contact points (its support polygon) and the support's slope under it is
below the friction angle (atan of the friction coefficient). The check needs no simulation: a few hundred
downward rays and one 2-D convex hull, about a millisecond per body, which is what the tree search can afford
for every candidate; the scene's verdict is still the simulated protocol (:func:`holousd.physics.stability`).
What it does not see: toppling moments from neighbours leaning on the body, and contact on its sides (an object
held by a wall).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["StaticVerdict", "static_stability"]

Mesh = tuple[np.ndarray, np.ndarray]


@dataclass(kw_only=True)
class StaticVerdict:
    """Outcome of :func:`static_stability`."""

    stands: bool
    """The centre of mass is over the support polygon, the slope is within friction and the body touches."""
    margin_m: float
    """Horizontal distance of the centre of mass inside the support polygon's boundary, metres (negative:
    outside by that much)."""
    gap_m: float
    """Height of the body's lowest contact above the support's surface, metres (negative: sunk into it)."""
    tilt_deg: float
    """Mean slope of the support's surface under the contacts, degrees."""
    contacts: int
    """Contact points found."""

    @property
    def energy(self) -> float:
        """0 when it stands, else 1 + the centre of mass's distance outside its polygon in cm."""
        return 0.0 if self.stands else 1.0 + 100.0 * max(0.0, -self.margin_m)


def _polygon_margin(points: np.ndarray, centre: np.ndarray) -> float:
    """Signed distance of ``centre`` [2] inside the convex hull of ``points`` [N, 2] (negative outside; a hull
    that is a segment or a point gives minus the distance to it)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(points)
    except (QhullError, ValueError):
        hull = None
    if hull is None or hull.volume < 1e-8:  # 1 cm^2 of polygon at most: a line or a point of contact
        lo = points[np.argmin(points @ np.array([1.0, 0.3]))]
        hi = points[np.argmax(points @ np.array([1.0, 0.3]))]
        d = hi - lo
        t = float(np.clip((centre - lo) @ d / max(d @ d, 1e-18), 0.0, 1.0))
        return -float(np.linalg.norm(centre - (lo + t * d)))
    # hull.equations: [nx, ny, c] with n outward and n.x + c <= 0 inside
    signed = hull.equations[:, :2] @ centre + hull.equations[:, 2]
    return float(-signed.max())


def _slope(points: np.ndarray) -> float:
    """Tilt of the least-squares plane through the support's surface points under the contacts, degrees (0 for
    fewer than 3 points or points on a line: a fitted surface's facets are too bumpy to read a slope from)."""
    if len(points) < 3:
        return 0.0
    centred = points - points.mean(0)
    _, sv, axes = np.linalg.svd(centred, full_matrices=False)
    if sv[1] < 1e-6 * max(sv[0], 1e-12):
        return 0.0
    return float(np.degrees(np.arccos(min(1.0, abs(axes[2, 2])))))


def static_stability(body: Mesh, support: Mesh | float | None, *, friction: float = 0.5,
                     contact_band: float = 0.02, max_gap: float = 0.05, ray_start: float = 0.02,
                     samples: int = 1500, seed: int = 0, flatten: float = 0.0,
                     sink: float | None = None) -> StaticVerdict:  # fmt: skip
    """Quasi-static verdict of a body (world mesh, closed) resting on ``support`` (a world mesh, a floor height,
    or None: nothing under it).

    Contact points: the body's surface samples in its lowest ``contact_band + ray_start`` band whose drop to the
    support (a ray straight down from ``ray_start`` above each) is within ``contact_band`` of the smallest drop,
    as :func:`holousd.graph.infer_relations` counts contact, 2 cm by default: the physics set-up cuts a fitted
    base and the top under it flat to about that depth (a fitted underside is rounded and its legs end at
    different heights); a smallest drop beyond ``max_gap`` is no contact. The slope is that of the plane
    through the support's surface under the contacts.
    The centre of mass is the mesh's (uniform density).

    ``flatten`` (metres, support meshes only) checks the body on the support as the physics set-up will leave it:
    the support's surface under the body is taken flat (horizontal) at its lowest point there (its 10th
    percentile) but no deeper than ``flatten`` below its highest, and its dents filled up to that height from at
    most ``flatten`` below it, as the one-geometry set-up's ``top_depth`` cuts a fitted top's bumps and fills its
    dents under what rests on it; and carried over where the support is open under the body (rays fall through
    it or far deeper), within the rectangle (world axes) of its upward faces within ``flatten`` of that height and
    within its outline seen from above, as the set-up spans a top the fit left open under what rests on it. What
    lies deeper past the top's extent (an edge, a gap between boards, most of a long ramp) stays. ``sink``
    (metres, with ``flatten``): where that flat top would lie more than ``max_gap`` below the body's bottom (every
    ray under it falls through the support), it lies this far below the bottom instead (the set-up moves a body
    down onto its support by at most half its ``max_shift``, and takes the flat top no deeper)."""
    from holousd.geometry._contact import area_samples, mass_properties, queryable

    points, faces = np.asarray(body[0], float), np.asarray(body[1], np.int64)
    none = StaticVerdict(stands=False, margin_m=-np.inf, gap_m=np.inf, tilt_deg=0.0, contacts=0)
    if len(points) == 0 or len(faces) == 0 or support is None:
        return none
    props = mass_properties((points, faces), 1.0)
    com = np.asarray(props.center_of_mass, float) if props.volume_m3 > 0 else points.mean(0)
    tri = points[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    surface = np.concatenate([points, area_samples(tri, area, samples, rng) if area.sum() > 0 else points])
    low = surface[surface[:, 2] <= surface[:, 2].min() + contact_band + ray_start]
    if len(low) > 400:
        low = low[np.sort(rng.choice(len(low), 400, replace=False))]
    if isinstance(support, int | float):
        drop = low[:, 2] - float(support)
        surface_z = np.full(len(low), float(support))
        hit = np.ones(len(low), bool)
    else:
        from trimesh.ray.ray_triangle import RayMeshIntersector

        target = queryable(support)
        origins = low + np.array([0.0, 0.0, ray_start])
        where, index, face = RayMeshIntersector(target).intersects_location(
            origins, np.tile([0.0, 0.0, -1.0], (len(low), 1)), multiple_hits=False)  # fmt: skip
        drop = np.full(len(low), np.inf)
        surface_z = np.full(len(low), np.nan)
        if len(index):
            surface_z[index] = np.asarray(where, float)[:, 2]
            drop[index] = low[index, 2] - surface_z[index]
        hit = np.isfinite(drop)
        if flatten > 0.0 and hit.any():
            highest = float(surface_z[hit].max())
            plane = max(float(np.percentile(surface_z[hit], 10)), highest - flatten)
            bottom = float(points[:, 2].min())
            if sink is not None and bottom - plane > max_gap:  # open under the body: the set-up's flat top lies
                plane = bottom - sink  # no deeper than it can move the body down onto it
            patch = hit & (surface_z >= plane - flatten)  # bumps above the plane cut, dents below it filled
            # where it is open (rays fall through it or far deeper) over its own top at that height, the set-up
            # carries the top over the opening
            patch |= ~patch & _over_own_top(target, low[:, :2], plane - flatten, max(plane + flatten, highest))
            surface_z[patch] = plane
            drop[patch] = low[patch, 2] - plane
            hit = hit | patch
    if not hit.any():
        return none
    smallest = float(drop[hit].min())
    if smallest > max_gap:
        return StaticVerdict(stands=False, margin_m=-np.inf, gap_m=smallest, tilt_deg=0.0, contacts=0)
    touching = hit & (drop <= smallest + contact_band)
    margin = _polygon_margin(low[touching, :2], com[:2])
    slope = _slope(np.column_stack([low[touching, :2], surface_z[touching]]))
    stands = margin >= 0.0 and slope <= np.degrees(np.arctan(friction))
    return StaticVerdict(stands=bool(stands), margin_m=margin, gap_m=smallest, tilt_deg=slope,
                         contacts=int(touching.sum()))  # fmt: skip


def _over_own_top(support, xy: np.ndarray, lowest: float, highest: float) -> np.ndarray:  # noqa: ANN001 - trimesh
    """[K] whether each point ``xy`` [K, 2] lies inside the rectangle (world axes) of the support's upward faces
    between heights ``lowest`` and ``highest`` (2 mm above it) and inside the support's outline seen from
    above."""
    from scipy.spatial import ConvexHull, QhullError

    tri = np.asarray(support.vertices, float)[np.asarray(support.faces, np.int64)]
    normal = np.asarray(support.face_normals, float)
    height = tri[:, :, 2].mean(axis=1)
    level = (normal[:, 2] > 0.9) & (height >= lowest) & (height <= highest + 2e-3)
    if not level.any():
        return np.zeros(len(xy), bool)
    top = tri[level].reshape(-1, 3)[:, :2]
    inside = np.all((xy >= top.min(axis=0)) & (xy <= top.max(axis=0)), axis=1)
    try:
        edges = ConvexHull(np.asarray(support.vertices, float)[:, :2]).equations  # n . x + d <= 0 inside
    except QhullError:
        return np.zeros(len(xy), bool)
    return inside & np.all(xy @ edges[:, :2].T + edges[:, 2] <= 1e-9, axis=1)
