"""Support tree and beside pairs inferred from geometry alone (world-space triangle meshes).

Support: an object rests on the node it touches directly below its lowest points. Rays are cast straight down from
the object's lowest vertices (started a little above them, so that a slight penetration still finds the surface it
sank into); each ray finds the closest surface below it within ``max_gap``. Only rays that end within
``contact_band`` of the shortest drop of all count: they are where the object touches (the ends of a block
crossing the one under it overhang a lower block; those rays fall further and do not vote). The node most of those
rays hit is the parent. Only nodes whose bottom is lower than the object's bottom can be parents, which keeps the
graph a tree. Where no ray finds anything within ``max_gap`` (an object higher than the lowest ones), what lies
under its footprint within ``max_gap`` of its bottom votes (from at least ``footprint_share`` of its rays);
failing that, a top that runs through it (its hidden underside fitted down through a table's top); failing that,
the surface around its footprint at its bottom's height (a board the fit left open under and around it). Nothing
below -> the background. With the floor's height given, the floor is one of the surfaces a contact ray may end on
(within ``floor_gap``, where nothing else is nearer), so an object standing on the floor is on the room however few
of its rays meet another object it was fitted into.

Beside: siblings (same parent) whose surfaces come within ``beside_distance`` of each other.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from holousd._sampling import evenly_spaced
from holousd.geometry._contact import inside as inside_mesh
from holousd.geometry._contact import queryable

__all__ = ["RelationConfig", "Relations", "infer_relations", "push_out_of", "settle_offsets"]

BACKGROUND = "background"
"""Name of the root node (same as :data:`holousd.usd.BACKGROUND`)."""

Mesh = tuple[np.ndarray, np.ndarray]
"""``(points [N, 3], faces [F, 3])`` in world coordinates, metres."""


@dataclass(kw_only=True)
class RelationConfig:
    """Settings of the relation inference."""

    bottom_band: float = 0.01
    """Vertices within this height of an object's lowest point are its contact points, metres."""
    max_rays: int = 64
    """Most rays cast per object (contact points are subsampled evenly)."""
    ray_start: float = 0.02
    """Rays start this far above each contact point (tolerates that much penetration), metres."""
    max_gap: float = 0.05
    """Largest drop from a contact point to a supporting surface, metres."""
    contact_band: float = 0.01
    """Rays whose distance to the nearest upward surface (below the contact point, or above it where the object
    sank into it) exceeds the object's smallest such distance by more than this do not vote, metres: they pass
    over an edge of what the object rests on, or start inside a neighbour whose fitted side overlaps it (a few
    millimetres of fitted gap or overlap still count as contact)."""
    footprint_share: float = 0.25
    """An object whose contact rays meet nothing (higher than the lowest objects) is on what at least this share of
    the rays cast down from its lowest ``max_gap`` meets (a ball over a hole in a board: half of them; a bin seen
    only from above, its fitted rim 41 cm over the floor, 1 ray in 64 grazed a cabinet's side beside it: no
    support, and the search carries it down to the floor)."""
    ring: float = 0.02
    """Width of the ring around an object's footprint searched last, metres: an object whose rays meet nothing
    under it (higher than the lowest objects) is on what at least ``ring_share`` of the rays cast down around its
    footprint meet within ``max_gap`` below its bottom (up to ``ray_start`` above it)."""
    ring_share: float = 0.1
    """Least share of the ring's rays for a parent. Low: it is the last test before the room, and an object it
    misses floats over what is under it. bench_02 (fast): the fit left a shelf's middle board open under a box
    and for centimetres around it, the box's rays fell 35 cm to the bottom board and it was put on the room; 69 of
    the 256 rays around it (27%) met the board's remnants within 3 cm of its bottom."""
    floor_gap: float = 0.02
    """With the floor's height known, contact points up to this far above it (or ``ray_start`` into it) may end
    on the floor, where nothing else is nearer, metres: a fitted chair's visual hull standing 1.2 cm over the
    floor and 1 cm into a table's foot beside it was put on the table by the 2 rays of 64 that met the foot (no ray
    voted for the floor), and the set-up cut the table's top flat at the chair. Less than ``max_gap``: a book 3.5 cm
    over the floor, on a shelf's bottom board the fit left a hole in, is on the shelf (what lies under its
    footprint)."""
    beside_distance: float = 0.01
    """Siblings whose surfaces come this close touch each other, metres."""
    beside_samples: int = 2000
    """Surface samples per object for the beside test."""
    seed: int = 0
    """Seed of the surface sampling."""


@dataclass(kw_only=True)
class Relations:
    """The inferred scene graph."""

    support: dict[str, str] = field(default_factory=dict)
    """Object name -> the node it rests on ('background' for the floor / room)."""
    beside: dict[str, list[str]] = field(default_factory=dict)
    """Object name -> touching siblings (symmetric; every object has an entry)."""
    votes: dict[str, dict[str, int]] = field(default_factory=dict)
    """Object name -> rays that hit each candidate parent (diagnostics)."""

    def children(self, parent: str) -> list[str]:
        """Objects resting directly on ``parent``, in name order."""
        return sorted(k for k, v in self.support.items() if v == parent)

    def breadth_first(self) -> list[str]:
        """Every object, breadth-first from the room along the support tree (parents before their children,
        siblings in name order); any the tree does not reach (a cycle) last, in name order."""
        order: list[str] = []
        frontier = [BACKGROUND]
        while frontier:
            kids = self.children(frontier.pop(0))
            order.extend(kids)
            frontier.extend(kids)
        return order + sorted(n for n in self.support if n not in order)

    def tree_lines(self, root: str = BACKGROUND) -> list[str]:
        """The support tree as indented text lines (root first), beside pairs in brackets."""
        lines = [root]

        def walk(node: str, depth: int) -> None:
            for child in self.children(node):
                beside = self.beside.get(child) or []
                extra = f"  [beside: {', '.join(beside)}]" if beside else ""
                lines.append(f"{'  ' * depth}- {child}{extra}")
                walk(child, depth + 1)

        walk(root, 1)
        return lines


def _contact_points(mesh: Mesh, config: RelationConfig) -> np.ndarray:
    """[K, 3] points of the mesh's underside within ``bottom_band`` of its lowest point: its low vertices and a
    regular grid over the faces lying in the band (a box's bottom has vertices at its corners only; where it
    touches may be its middle), at most ``max_rays``, evenly subsampled."""
    points, faces = np.asarray(mesh[0], float), np.asarray(mesh[1], np.int64)
    top = points[:, 2].min() + config.bottom_band
    low = points[points[:, 2] <= top]  # [K, 3]
    tri = points[faces]
    tri = tri[(tri[:, :, 2] <= top).all(axis=1)]  # [T, 3, 3] faces in the band
    if len(tri):
        lo, hi = tri[:, :, :2].reshape(-1, 2).min(axis=0), tri[:, :, :2].reshape(-1, 2).max(axis=0)
        side = np.linspace(0.0, 1.0, 16)[1:-1]
        grid = np.stack(np.meshgrid(lo[0] + side * (hi[0] - lo[0]), lo[1] + side * (hi[1] - lo[1])), -1).reshape(-1, 2)
        a, b, c = tri[:, 0, :2], tri[:, 1, :2], tri[:, 2, :2]  # [T, 2]
        det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
        ok = np.abs(det) > 1e-14
        a, b, c, det, z = a[ok], b[ok], c[ok], det[ok], tri[ok, :, 2]
        d = grid[:, None, :] - a[None]  # [G, T, 2]
        u = (d[..., 0] * (c[:, 1] - a[:, 1]) - d[..., 1] * (c[:, 0] - a[:, 0])) / det
        v = (d[..., 1] * (b[:, 0] - a[:, 0]) - d[..., 0] * (b[:, 1] - a[:, 1])) / det
        inside = (u >= 0) & (v >= 0) & (u + v <= 1)
        g, t = np.nonzero(inside)
        if len(g):
            first = np.unique(g, return_index=True)[1]  # one face per grid point (the band is nearly flat)
            g, t = g[first], t[first]
            height = z[t, 0] + u[g, t] * (z[t, 1] - z[t, 0]) + v[g, t] * (z[t, 2] - z[t, 0])
            low = np.concatenate([low, np.column_stack([grid[g], height])])
    return low[evenly_spaced(len(low), config.max_rays)]


def infer_relations(meshes: dict[str, Mesh], config: RelationConfig | None = None, *,
                    floor: float | None = None) -> Relations:  # fmt: skip
    """Infer the support tree and beside pairs of objects from their world-space meshes.

    Args:
        meshes: Object name -> ``(points [N, 3], faces [F, 3])`` in world coordinates (background excluded).
        config: Settings.
        floor: The room's floor height, when known: an object's upward surface within ``contact_band`` of it is
            the floor's (a fitted cabinet's base, rounded a voxel under the floor, reaches under the small box
            standing beside it; the box is on the floor, not on the cabinet).

    Returns:
        Support parent per object (a tree rooted at 'background') and beside lists.
    """
    from trimesh.ray.ray_triangle import RayMeshIntersector

    config = config or RelationConfig()
    names = [n for n, m in meshes.items() if len(m[0]) and len(m[1])]
    tms = {n: queryable(meshes[n]) for n in names}
    bounds = {n: tms[n].bounds for n in names}  # [2, 3]
    intersectors = {n: RayMeshIntersector(tms[n]) for n in names}
    result = Relations()
    lowest = min((float(bounds[n][0][2]) for n in names), default=0.0)  # what stands on the room stands about here
    for name in names:
        pts = np.asarray(meshes[name][0], float)
        low = _contact_points(meshes[name], config)
        bottom = float(pts[:, 2].min())
        votes: dict[str, int] = {}
        origins = low + np.array([0.0, 0.0, config.ray_start])
        directions = np.tile([0.0, 0.0, -1.0], (len(origins), 1))
        best = np.full(len(origins), np.inf)  # [K] distance to the nearest upward surface (above: sunk into it)
        owner = np.full(len(origins), "", dtype=object)
        for other in names:
            if other == name:
                continue
            lo, hi = bounds[other]
            if lo[2] >= bottom - 1e-6 or hi[2] < bottom - config.max_gap:  # parents sit lower and reach up to it
                continue
            inside = (low[:, 0] >= lo[0]) & (low[:, 0] <= hi[0]) & (low[:, 1] >= lo[1]) & (low[:, 1] <= hi[1])
            if not inside.any():
                continue
            locations, ray_index, tri = intersectors[other].intersects_location(origins, directions)
            if len(ray_index) == 0:
                continue
            drop = origins[ray_index, 2] - locations[:, 2] - config.ray_start  # from the contact point, metres
            # a surface to rest on faces up (a downward ray leaves a solid through the faces under it)
            up = tms[other].face_normals[tri, 2] > 0.0
            ok = up & (drop >= -config.ray_start) & (drop <= config.max_gap)
            if floor is not None:
                ok &= locations[:, 2] > floor + config.contact_band
            for r, d in zip(ray_index[ok], np.abs(drop[ok]), strict=True):
                if d < best[r]:
                    best[r], owner[r] = d, other
        if floor is not None:  # the floor is a surface to rest on too, where nothing else is nearer
            drop = low[:, 2] - floor
            near = (drop >= -config.ray_start) & (drop <= config.floor_gap) & (np.abs(drop) < best)
            best[near], owner[near] = np.abs(drop[near]), BACKGROUND
        hit = owner != ""
        touching = hit & (best <= (best[hit].min() if hit.any() else 0.0) + config.contact_band)
        for o in owner[touching]:
            votes[o] = votes.get(o, 0) + 1
        if not votes and bottom > lowest + config.max_gap:
            votes = _votes_under_footprint(name, meshes[name], names, intersectors, bounds, tms, config, floor)
        if not votes and bottom > lowest + config.max_gap:
            votes = _votes_sunk_into(name, meshes[name], names, intersectors, bounds, tms, config)
        if not votes and bottom > lowest + config.max_gap:
            votes = _votes_around_footprint(name, meshes[name], names, intersectors, bounds, tms, config, floor)
        result.votes[name] = votes
        result.support[name] = max(sorted(votes), key=lambda k: votes[k]) if votes else BACKGROUND
    result.beside = {n: [] for n in names}
    rng = np.random.default_rng(config.seed)
    samples = {}
    for n in names:
        s, _ = _sample(tms[n], config.beside_samples, rng)
        samples[n] = s
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if result.support[a] != result.support[b]:
                continue
            gap = np.maximum(bounds[a][0] - bounds[b][1], bounds[b][0] - bounds[a][1]).max()
            if gap > config.beside_distance:
                continue
            if (
                _surface_distance(tms[b], samples[a]) <= config.beside_distance
                or _surface_distance(tms[a], samples[b]) <= config.beside_distance
            ):
                result.beside[a].append(b)
                result.beside[b].append(a)
    for n in names:
        result.beside[n].sort()
    return result


def _votes_under_footprint(name: str, mesh: Mesh, names: list[str], intersectors: dict, bounds: dict,
                           tms: dict, config: RelationConfig, floor: float | None = None,
                           ) -> dict[str, int]:  # fmt: skip
    """Votes for the parent of an object whose contact points lie over nothing within ``max_gap`` (a hole the
    fit left in the board under it: hard/shelf's ball on the top board, its contact rays fell 40 cm to the board
    below and it was put on the room, 1.2 m above the floor): rays down from every point of its lowest
    ``max_gap``, each voting for the object whose upward face it meets first, at most ``max_gap`` below the
    object's bottom; an object with fewer than ``footprint_share`` of the rays does not count."""
    points = np.asarray(mesh[0], float)
    bottom = float(points[:, 2].min())
    low = points[points[:, 2] <= bottom + config.max_gap]
    low = low[evenly_spaced(len(low), config.max_rays)]
    origins = low + np.array([0.0, 0.0, config.ray_start])
    owner = _first_upward_below(origins, name, bottom, names, intersectors, bounds, tms, config, floor)
    return _counted(owner, config.footprint_share * len(origins))


def _first_upward_below(origins: np.ndarray, name: str, bottom: float, names: list[str], intersectors: dict,
                        bounds: dict, tms: dict, config: RelationConfig, floor: float | None,
                        ) -> np.ndarray:  # fmt: skip
    """[K] per ray cast straight down from ``origins`` [K, 3], the object (not ``name``; lower than its
    ``bottom``) whose upward face it meets first, at most ``max_gap`` below ``bottom`` and not the floor's
    (``contact_band`` above ``floor``); ``""`` for none."""
    directions = np.tile([0.0, 0.0, -1.0], (len(origins), 1))
    best = np.full(len(origins), -np.inf)  # [K] height of the highest upward face met
    owner = np.full(len(origins), "", dtype=object)
    for other in names:
        lo, hi = bounds[other]
        if other == name or lo[2] >= bottom - 1e-6 or hi[2] < bottom - config.max_gap:
            continue
        locations, ray_index, tri = intersectors[other].intersects_location(origins, directions)
        if len(ray_index) == 0:
            continue
        ok = (tms[other].face_normals[tri, 2] > 0.0) & (locations[:, 2] >= bottom - config.max_gap)
        if floor is not None:  # the floor's, not the object's (see infer_relations)
            ok &= locations[:, 2] > floor + config.contact_band
        _keep_highest(best, owner, ray_index[ok], locations[ok, 2], other)
    return owner


def _votes_sunk_into(name: str, mesh: Mesh, names: list[str], intersectors: dict, bounds: dict, tms: dict,
                     config: RelationConfig) -> dict[str, int]:  # fmt: skip
    """Votes for the parent of an object whose underside runs down through another's top, deeper than
    ``ray_start`` (a phone capture's box on a table, its hidden bottom fitted 11 cm down through the top and out
    under it, between the legs: nothing lay under its contact points): rays down from the object's top over its
    low points, each voting for the object whose upward face it meets highest inside it (above its underside
    there and its bottom by more than ``ray_start``, below its top by more than a quarter of its height: what it
    stands on is not up there); an object with fewer than ``footprint_share`` of the rays does not count."""
    points = np.asarray(mesh[0], float)
    bottom, top = float(points[:, 2].min()), float(points[:, 2].max())
    low = points[points[:, 2] <= bottom + config.max_gap]
    low = low[evenly_spaced(len(low), config.max_rays)]
    origins = np.column_stack([low[:, :2], np.full(len(low), top)])
    directions = np.tile([0.0, 0.0, -1.0], (len(origins), 1))
    best = np.full(len(origins), -np.inf)
    owner = np.full(len(origins), "", dtype=object)
    ceiling = top - max(config.ray_start, 0.25 * (top - bottom))
    from_below = np.column_stack([low[:, :2], np.full(len(low), bottom - 1.0)])
    hits, rays, _ = intersectors[name].intersects_location(from_below, -directions, multiple_hits=False)
    underside = np.full(len(origins), np.inf)  # the object's own underside over each ray
    underside[rays] = np.asarray(hits, float).reshape(-1, 3)[:, 2]
    for other in names:
        lo, hi = bounds[other]
        if other == name or lo[2] >= bottom - 1e-6 or hi[2] <= bottom + config.ray_start:
            continue
        locations, ray_index, tri = intersectors[other].intersects_location(origins, directions)
        if len(ray_index) == 0:
            continue
        z = locations[:, 2]
        ok = (tms[other].face_normals[tri, 2] > 0.0) & (z > bottom + config.ray_start) & (z <= ceiling)
        ok &= z > underside[ray_index] + config.bottom_band
        _keep_highest(best, owner, ray_index[ok], z[ok], other)
    return _counted(owner, config.footprint_share * len(origins))


def _ring(points: np.ndarray, width: float, count: int) -> np.ndarray:
    """[K, 2] points ``width`` outside the convex outline of ``points`` ([N, 2]) seen from above, evenly along it."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        corners = points[ConvexHull(points).vertices]  # counter-clockwise
    except QhullError:  # a degenerate outline (a point, a line): its box, a tenth of a millimetre wider
        lo, hi = points.min(axis=0) - 1e-4, points.max(axis=0) + 1e-4
        corners = np.array([lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]])
    edges = np.roll(corners, -1, axis=0) - corners
    length = np.linalg.norm(edges, axis=1)
    keep = length > 1e-9
    corners, edges, length = corners[keep], edges[keep], length[keep]
    outward = np.column_stack([edges[:, 1], -edges[:, 0]]) / length[:, None]  # right of a counter-clockwise edge
    at = np.linspace(0.0, float(length.sum()), count, endpoint=False)
    edge = np.searchsorted(np.cumsum(length), at, side="right")
    start = np.concatenate([[0.0], np.cumsum(length)[:-1]])
    along = (at - start[edge]) / length[edge]
    return corners[edge] + along[:, None] * edges[edge] + width * outward[edge]


def _votes_around_footprint(name: str, mesh: Mesh, names: list[str], intersectors: dict, bounds: dict,
                            tms: dict, config: RelationConfig, floor: float | None = None,
                            ) -> dict[str, int]:  # fmt: skip
    """Votes for the parent of an object with nothing under it (see ``RelationConfig.ring``): rays down from
    ``ray_start`` above its bottom, on a ring ``ring`` outside the outline of its lowest ``max_gap``, each voting for
    the object whose upward face it meets first, at most ``max_gap`` below the object's bottom; an object with
    fewer than ``ring_share`` of the rays does not count."""
    points = np.asarray(mesh[0], float)
    bottom = float(points[:, 2].min())
    low = points[points[:, 2] <= bottom + config.max_gap]
    around = _ring(low[:, :2], config.ring, 4 * config.max_rays)
    origins = np.column_stack([around, np.full(len(around), bottom + config.ray_start)])
    owner = _first_upward_below(origins, name, bottom, names, intersectors, bounds, tms, config, floor)
    return _counted(owner, config.ring_share * len(origins))


def _keep_highest(best: np.ndarray, owner: np.ndarray, rays: np.ndarray, heights: np.ndarray, other: str) -> None:
    """Per ray, the highest hit so far (``best`` [K], in place) and whose it is (``owner`` [K])."""
    for r, z in zip(rays, heights, strict=True):
        if z > best[r]:
            best[r], owner[r] = z, other


def _counted(owner: np.ndarray, least: float) -> dict[str, int]:
    """Rays per owner (``""``: none), for the owners with at least ``least`` of them."""
    votes: dict[str, int] = {}
    for o in owner[owner != ""]:
        votes[o] = votes.get(o, 0) + 1
    return {o: v for o, v in votes.items() if v >= least}


def _sample(tm, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
    import trimesh

    pts, face = trimesh.sample.sample_surface(tm, count, seed=int(rng.integers(2**31)))
    return np.concatenate([np.asarray(pts), np.asarray(tm.vertices)]), face


def _surface_distance(tm, points: np.ndarray) -> float:  # noqa: ANN001
    """Smallest distance from ``points`` [P, 3] to the surface of ``tm``, metres."""
    import trimesh

    lo, hi = tm.bounds
    near = points[np.all((points >= lo - 0.05) & (points <= hi + 0.05), axis=1)]
    if len(near) == 0:
        return float("inf")
    _, dist, _ = trimesh.proximity.closest_point(tm, near)
    return float(np.min(dist))


def settle_offsets(meshes: dict[str, Mesh], background: Mesh | None, relations: Relations,
                   config: RelationConfig | None = None, *, clearance: float = 0.001,
                   max_offset: float = 0.06) -> dict[str, float]:  # fmt: skip
    """Vertical shifts that set each object onto its support parent (the state adjustment of s2, z only).

    Parents are settled before their children (breadth-first from the background) and children move with
    their parent's shift first. For each object, rays are cast down onto its parent's surface from above its
    contact points; the object is moved so that its lowest point sits ``clearance`` above the highest hit.
    Fitted meshes typically sink a voxel or two into their support, which a simulator resolves violently.

    Args:
        meshes: Object name -> world ``(points [N, 3], faces [F, 3])`` before the shift; also the surface its
            children are set onto (pass colliders to set children on what the simulator will see).
        background: World mesh of the background (parent 'background'), or None (then such objects stay).
        relations: The support tree from :func:`infer_relations`.
        config: Ray settings (``bottom_band``, ``max_rays``).
        clearance: Gap left between an object's lowest point and its parent's surface, metres.
        max_offset: Larger shifts are not applied (the parent is probably wrong), metres.

    Returns:
        Object name -> total z shift, metres (its own plus its ancestors').
    """
    from trimesh.ray.ray_triangle import RayMeshIntersector

    config = config or RelationConfig()
    shift: dict[str, float] = {}
    surfaces: dict[str, Mesh] = dict(meshes)
    if background is not None and len(background[1]):
        surfaces[BACKGROUND] = background
    order = relations.breadth_first()
    order.extend(sorted(n for n in meshes if n not in order))  # without a support entry (should not happen)
    for name in order:
        parent = relations.support.get(name, BACKGROUND)
        base = shift.get(parent, 0.0) if parent != BACKGROUND else 0.0
        pts = np.asarray(meshes[name][0], float) + np.array([0.0, 0.0, base])
        own = 0.0
        if parent in surfaces:
            low = _contact_points(meshes[name], config)
            bottom = float(pts[:, 2].min())
            ppts, pfaces = surfaces[parent]
            ppts = np.asarray(ppts, float) + np.array([0.0, 0.0, shift.get(parent, 0.0)])
            tm = queryable((ppts, pfaces))
            origins = low.copy()
            origins[:, 2] = bottom + max_offset
            locations, _, _ = RayMeshIntersector(tm).intersects_location(
                origins, np.tile([0.0, 0.0, -1.0], (len(origins), 1)), multiple_hits=False
            )
            if len(locations):
                below = locations[locations[:, 2] >= bottom - max_offset, 2]
                if len(below):
                    target = float(np.max(below)) + clearance  # no contact point stays inside the parent
                    if abs(target - bottom) <= max_offset:
                        own = target - bottom
        shift[name] = base + own
    return shift


def push_out_of(mesh: Mesh, solid: Mesh, *, samples: int = 400, clearance: float = 0.002,
                max_offset: float = 0.06) -> np.ndarray:  # fmt: skip
    """Horizontal shift [3] that moves ``mesh`` out of the closed mesh ``solid`` (e.g. an object out of a wall).

    Up to ``samples`` vertices of ``mesh`` are tested for lying inside ``solid``; each one inside whose closest
    surface point lies more sideways than up or down is pushed to that point, and the shift is the largest push
    along x and along y (z is left to :func:`settle_offsets`). Zero when nothing is inside, ``solid`` is not
    watertight, or the shift would exceed ``max_offset`` (metres).
    """
    import trimesh

    solid_tm = queryable(solid)
    if not solid_tm.is_watertight:
        return np.zeros(3)
    pts = np.asarray(mesh[0], float)
    pts = pts[evenly_spaced(len(pts), samples)]
    lo, hi = solid_tm.bounds
    pts = pts[np.all((pts >= lo) & (pts <= hi), axis=1)]
    if len(pts) == 0:
        return np.zeros(3)
    inside = inside_mesh(solid_tm, pts)
    if not inside.any():
        return np.zeros(3)
    closest, _, _ = trimesh.proximity.closest_point(solid_tm, pts[inside])
    push = closest - pts[inside]  # [K, 3] from the inside point to the surface
    push = push[np.linalg.norm(push[:, :2], axis=1) > np.abs(push[:, 2])]  # sideways only (floors: settle)
    if len(push) == 0:
        return np.zeros(3)
    shift = np.zeros(3)
    for axis in (0, 1):
        pos, neg = push[:, axis].max(), push[:, axis].min()
        shift[axis] = pos if abs(pos) >= abs(neg) else neg
        if abs(shift[axis]) < 1e-9:
            shift[axis] = 0.0
        else:
            shift[axis] += np.sign(shift[axis]) * clearance
    if np.abs(shift).max() > max_offset:
        return np.zeros(3)
    return shift
