"""Mesh-level contact geometry: plane and solid cuts, overlaps, collider reach, mass properties.

Everything the physics set-up does so that an object can stand is done here, to the rendered mesh itself (never
to a collider alone): cuts by planes (a flat base, a flat top, a wall, the mid-plane between two neighbours) and
subtractions of another solid (whatever of a neighbour lies inside it). The collider is then derived from the
final mesh and measured against it (:func:`collider_reach`). Meshes are ``(points [N, 3], faces [F, 3])`` pairs
in one frame (world coordinates unless said otherwise); solids go through manifold3d, which needs closed
manifolds: a mesh it cannot read is returned unchanged and the function says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "MassProperties",
    "collider_reach",
    "cut_by_plane",
    "farthest_outside",
    "inside",
    "mass_properties",
    "overlap",
    "subtract",
    "without_zero_area_faces",
]

Mesh = tuple[np.ndarray, np.ndarray]


def _by_content(cache: dict, points: np.ndarray, faces: np.ndarray, build, keep: int):  # noqa: ANN001, ANN201
    """What ``build()`` makes of a mesh, made once for the same ``points`` and ``faces`` (by content: a mesh is
    often computed anew for each call) and kept in ``cache``, the ``keep`` most recently used."""
    import hashlib

    key = hashlib.blake2b(repr((points.shape, faces.shape)).encode() + points.tobytes() + faces.tobytes(),
                          digest_size=16).digest()  # fmt: skip
    found = cache.pop(key) if key in cache else build()
    cache[key] = found  # most recent last
    while len(cache) > keep:
        del cache[next(iter(cache))]
    return found


_SOLIDS: dict[bytes, object] = {}


def _solid(mesh: Mesh):  # noqa: ANN202 - manifold3d.Manifold | None
    """The manifold3d solid of a closed mesh, None when it is not one. The same solid for the same points and
    faces (:func:`_by_content`; solids are immutable): the set-up tests the same pairs of meshes for overlap pass
    after pass, and building a fitted table's solid costs some 20 ms (hard/thin: 552 builds, 13 of its 180 s). The
    last 32 are kept."""
    import manifold3d

    points, faces = mesh
    if len(faces) == 0:
        return None
    # double precision: float32 corners of a boolean result a fraction of a micron apart would coincide, and a face
    # with two coincident corners has no area
    points = np.array(points, np.float64, order="C")
    faces = np.array(faces, np.uint64, order="C")

    def build():  # noqa: ANN202
        solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=points, tri_verts=faces))
        return None if solid.status() != manifold3d.Error.NoError or solid.is_empty() else solid

    return _by_content(_SOLIDS, points, faces, build, 32)


def _mesh(solid) -> Mesh:  # noqa: ANN001
    out = solid.to_mesh64()
    return np.asarray(out.vert_properties[:, :3], np.float64), np.asarray(out.tri_verts, np.int64)


CRUMBS = 0.05
"""Share of what a cut leaves that pieces beside its main one (or the original's pieces) may hold and be dropped
with the cut."""


def _one_piece(solid, before: float, min_keep: float, original=None):  # noqa: ANN001, ANN202
    """The solid left by a cut when it is in no more pieces than the ``original`` solid (slivers under 1% of
    ``before`` dropped; one piece without ``original``) and keeps at least ``min_keep`` of ``before``; None when
    the cut splits the object (a table cut under its top keeps four legs: that is no face of the object) or keeps
    too little. A fit may leave an object in a few pieces (the phone demo's plate came in three, 407, 37 and
    11 cm^3); its cuts keep them all. Pieces beyond those that together hold at most :data:`CRUMBS` of what is
    left are crumbs and go with the cut: bench_02's phone capture had a book fitted 2.4 cm down through its table's
    top, and the cut at the top left it 126 cm^3 above with a crumb of 3.7 cm^3 (a lump at its edge), so neither
    that cut nor the one clearing the table out of it was made, and the two meshes overlapped by 4.8 cm^3."""
    import manifold3d

    pieces = [p for p in solid.decompose() if p.volume() >= 0.01 * before]
    if len(pieces) > 1:
        allowed = 1 if original is None else sum(p.volume() >= 0.01 * before for p in original.decompose())
        if len(pieces) > allowed:  # more than the object had: the largest stay when the rest are crumbs
            pieces = sorted(pieces, key=lambda p: -p.volume())
            if sum(p.volume() for p in pieces[allowed:]) > CRUMBS * sum(p.volume() for p in pieces):
                return None
            pieces = pieces[:allowed]
    if not pieces or sum(p.volume() for p in pieces) < min_keep * before:
        return None
    return manifold3d.Manifold.compose(pieces) if len(pieces) > 1 else pieces[0]


def _result(mesh: Mesh, solid, before: float, min_keep: float, original=None) -> tuple[Mesh, float]:  # noqa: ANN001
    """What a cut of ``mesh`` (volume ``before``; the solid ``original``) that left ``solid`` returns: the new
    mesh and the volume removed, or ``mesh`` and 0 when nothing was removed or the cut is refused (see
    :func:`_one_piece`)."""
    if solid.is_empty() or before - solid.volume() <= 1e-12:
        return mesh, 0.0
    kept = _one_piece(solid, before, min_keep, original)
    if kept is None:
        return mesh, 0.0
    return _mesh(kept), float(before - kept.volume())


def cut_by_plane(mesh: Mesh, normal: np.ndarray, offset: float, *, min_keep: float = 0.2) -> tuple[Mesh, float]:
    """Keep the part of a closed mesh where ``normal . x >= offset``; returns the mesh and the volume removed.

    The mesh comes back unchanged (0 removed) when it is not a closed manifold, when the plane misses it, when
    what is left falls apart into more pieces than the mesh had (but for crumbs: :func:`_one_piece`), or when less
    than ``min_keep`` of its volume would be left (the plane is then not a face of this object).
    """
    solid = _solid(mesh)
    norm = float(np.linalg.norm(normal))
    if solid is None or not norm > 0:
        return mesh, 0.0
    before = solid.volume()
    kept = solid.trim_by_plane(tuple(float(v) / norm for v in normal), float(offset) / norm)
    return _result(mesh, kept, before, min_keep, solid)


def subtract(mesh: Mesh, other: Mesh | list[Mesh], *, min_keep: float = 0.5) -> tuple[Mesh, float]:
    """``mesh`` minus the solid(s) ``other``; returns the mesh and the volume removed.

    Unchanged when either is not a closed manifold, when they do not overlap, when what is left falls apart (into
    more pieces than the mesh had), or when less than ``min_keep`` of the mesh's volume would be left (``other``
    is then no neighbour that merely overlaps it).
    """
    solid = _solid(mesh)
    if solid is None:
        return mesh, 0.0
    others = other if isinstance(other, list) else [other]
    before = solid.volume()
    result = solid
    for o in others:
        cutter = _solid(o)
        if cutter is not None:
            result = result - cutter
    return _result(mesh, result, before, min_keep, solid)


def within(mesh: Mesh, parts: list[Mesh], *, min_keep: float = 0.9) -> tuple[Mesh, float]:
    """``mesh`` cut to what lies inside the union of the convex ``parts`` (a collider that does not cover all
    of it: pieces a decomposition dropped); returns the mesh and the volume removed. Unchanged as
    :func:`subtract` leaves it (not closed, nothing outside, falls apart, less than ``min_keep`` left)."""
    import manifold3d

    solid = _solid(mesh)
    hulls = [h for h in (_solid(p) for p in parts) if h is not None]
    if solid is None or not hulls:
        return mesh, 0.0
    union = manifold3d.Manifold.batch_boolean(hulls, manifold3d.OpType.Add)
    return _result(mesh, solid ^ union, solid.volume(), min_keep, solid)


@dataclass(kw_only=True)
class Overlap:
    """The intersection of two solids."""

    volume_m3: float
    """Volume of the intersection, m^3 (0 when they do not overlap)."""
    depth_m: float
    """Thickness of the intersection across its thinnest principal direction (how far one reaches into the
    other, whatever the objects' orientation), metres: the deepest of its solid pieces, each measured on its own.
    Faces that lie on each other (a base cut flat on a top, two neighbours cut apart at one plane) leave sheets of
    no volume in the intersection: measured with them, a lens of 0.07 cm^3 between two balls (1.9 mm thick) read
    4.2 cm (bench_00 (phone)), its sheets spanning the contact."""
    lo: np.ndarray
    """[3] lower corner of the intersection's bounding box, metres."""
    hi: np.ndarray
    """[3] upper corner of the intersection's bounding box, metres."""
    thin_axis: np.ndarray | None = None
    """[3] unit direction along which the intersection's largest piece is thinnest (None when there is none)."""


def overlap(a: Mesh, b: Mesh, *, min_volume: float = 1e-9, above: float | None = None) -> Overlap:
    """The intersection of two closed meshes (manifold3d); zero when either is not a closed manifold or the
    intersection is smaller than ``min_volume`` (m^3; 0.001 cm^3: the slivers two faces that touch leave).
    With ``above`` (a height, metres), only what of the intersection lies higher counts."""
    none = Overlap(volume_m3=0.0, depth_m=0.0, lo=np.zeros(3), hi=np.zeros(3))
    pa, pb = np.asarray(a[0]), np.asarray(b[0])
    if len(pa) == 0 or len(pb) == 0 or np.any(pa.min(0) > pb.max(0)) or np.any(pb.min(0) > pa.max(0)):
        return none
    sa, sb = _solid(a), _solid(b)
    if sa is None or sb is None:
        return none
    both = sa ^ sb
    if above is not None and not both.is_empty():
        both = both.trim_by_plane((0.0, 0.0, 1.0), float(above))
    if both.is_empty() or both.volume() < min_volume:
        return none
    box = np.asarray(both.bounding_box(), float).reshape(2, 3)
    pieces = sorted(both.decompose(), key=lambda c: -float(c.volume()))
    depth, thin_axis = 0.0, None
    for piece in pieces:  # the deepest of its solid pieces, each measured on its own (see Overlap.depth_m)
        if float(piece.volume()) < SHEET * float(pieces[0].volume()):
            break
        thickness, axis = _thinnest(piece)
        if thin_axis is None:  # the largest piece's
            thin_axis = axis
        depth = max(depth, thickness)
    return Overlap(volume_m3=float(both.volume()), depth_m=depth, lo=box[0], hi=box[1], thin_axis=thin_axis)


SHEET = 0.01
"""Share of the largest piece of an intersection below which a piece of it is no solid piece: the sheets of no
volume that faces lying on each other leave (:func:`overlap`)."""


def _thinnest(solid) -> tuple[float, np.ndarray]:  # noqa: ANN001
    """Thickness of a solid across the thinnest of its principal directions (or of its box's axes, when thinner),
    metres, and that principal direction."""
    box = np.asarray(solid.bounding_box(), float).reshape(2, 3)
    points = _mesh(solid)[0]
    centred = points - points.mean(0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)  # rows: principal directions of the solid
    extents = np.ptp(centred @ axes.T, axis=0)
    return float(min(extents.min(), (box[1] - box[0]).min())), axes[int(np.argmin(extents))]


def area_samples(tri: np.ndarray, area: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """[count, 3] points drawn uniformly on triangles ``tri`` [F, 3, 3] (faces picked by ``area`` [F])."""
    pick = rng.choice(len(tri), size=count, p=area / area.sum())
    r = rng.random((count, 2))
    flip = r.sum(1) > 1
    r[flip] = 1 - r[flip]
    t = tri[pick]
    return t[:, 0] + r[:, :1] * (t[:, 1] - t[:, 0]) + r[:, 1:] * (t[:, 2] - t[:, 0])


# ray directions for the parity test, tried in turn for the points the previous one left undecided. The first
# three run within about a degree of the z, x and y axes: trimesh finds a ray's candidate triangles by the ray's
# bounding box, which for a diagonal ray across a mesh is the whole mesh (a fitted shelf of 22826 triangles: 512
# diagonal rays met 10 million candidates, 0.2 s a call; 6000 points took 51 s, near-axis 0.8 s, and answered the
# same but for one point 2e-8 m from the surface). Not on an axis, so that a ray rarely runs along an edge or a face
# of a grid-aligned mesh; the last, diagonal, settles what they leave. Fixed (trimesh's own ``contains`` draws its
# second direction from OS entropy, so the same scene could come out two ways)
_PARITY_DIRECTIONS = np.array([[0.0131, 0.0077, 1.0], [1.0, 0.0119, 0.0087], [0.0093, 1.0, 0.0141],
                               [0.4395064455, 0.617598629942, 0.652231566745]])  # fmt: skip


def with_tree(target):  # noqa: ANN001, ANN201 - a trimesh.Trimesh, returned
    """``target`` (a trimesh) with its triangles' r-tree built now: the very tree trimesh builds on the first
    closest-point or ray query (the same candidates, in the same order; the answers do not change), bulk-loaded
    from arrays where trimesh streams it from Python one triangle at a time: 16 ms against 157 ms for a fitted
    shelf of 21 000 triangles; bench_00 (fast)'s physics set-up built 1349 trees in 13.3 s so, 2.0 s this way. A
    tree already built is kept."""
    import rtree

    if "triangles_tree" in target._cache.cache or len(target.faces) == 0:
        return target
    triangles = np.asarray(target.triangles, np.float64)
    tree = rtree.index.Index((np.arange(len(triangles), dtype=np.int64),
                              np.ascontiguousarray(triangles.min(axis=1)), np.ascontiguousarray(triangles.max(axis=1))),
                             properties=rtree.index.Property(dimension=3))  # fmt: skip
    target._cache["triangles_tree"] = tree
    return target


def queryable(mesh: Mesh):  # noqa: ANN201 - trimesh.Trimesh
    """A trimesh of ``mesh`` for closest-point and ray queries (:func:`with_tree`)."""
    import trimesh

    return with_tree(trimesh.Trimesh(vertices=np.asarray(mesh[0], np.float64), faces=np.asarray(mesh[1], np.int64),
                                     process=False))  # fmt: skip


def inside(target, points: np.ndarray) -> np.ndarray:  # noqa: ANN001 - a watertight trimesh.Trimesh
    """[N] bool: which ``points`` lie inside the closed mesh ``target``, by ray parity. A point is decided by the
    first direction whose ray forwards and backwards agree (or one of them hits nothing: free space); points no
    direction decides take the forward parity of the last one. Deterministic: the same points, the same answer."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    result = np.zeros(len(pts), bool)
    with_tree(target)
    lo, hi = target.bounds
    todo = np.flatnonzero(np.all((pts >= lo) & (pts <= hi), axis=1))
    for k, direction in enumerate(_PARITY_DIRECTIONS):
        if len(todo) == 0:
            break
        d = direction / np.linalg.norm(direction)
        rays = np.tile(d, (len(todo), 1))
        _, index_ray, _ = target.ray.intersects_location(np.vstack((pts[todo], pts[todo])),
                                                         np.vstack((rays, -rays)), multiple_hits=True)  # fmt: skip
        hits = np.bincount(index_ray, minlength=2 * len(todo)).reshape(2, -1)
        odd = hits % 2 == 1
        decided = (odd[0] == odd[1]) | (hits == 0).any(axis=0)
        result[todo] = odd[0] & (hits != 0).all(axis=0)
        if k == len(_PARITY_DIRECTIONS) - 1:
            result[todo[~decided]] = odd[0][~decided]
        todo = todo[~decided]
    return result


def collider_reach(parts: list[Mesh], mesh: Mesh, *, samples: int = 2000, seed: int = 0,
                   hulls: bool = False) -> float:  # fmt: skip
    """How far a collider reaches outside the mesh it stands for: the largest distance from a point of the
    collider's surface (its vertices and ``samples`` area-weighted surface samples) that lies outside the mesh
    to the mesh, metres. 0 when the collider stays inside the mesh. ``hulls``: measure the convex hull of each
    part (what a simulator builds from a part authored with approximation convexHull)."""
    import trimesh

    if hulls:
        parts = [(np.asarray(h.vertices), np.asarray(h.faces))
                 for h in (trimesh.convex.convex_hull(np.asarray(p, float)) for p, _ in parts)]  # fmt: skip
    target = queryable(mesh)
    rng = np.random.default_rng(seed)
    points = []
    areas = []
    for p, f in parts:
        tri = np.asarray(p, float)[np.asarray(f, np.int64)]
        areas.append(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1))
        points.append(np.asarray(p, float))
    total = sum(float(a.sum()) for a in areas)
    for (p, f), area in zip(parts, areas, strict=True):
        if total <= 0 or area.sum() <= 0:
            continue
        count = max(1, int(round(samples * float(area.sum()) / total)))
        tri = np.asarray(p, float)[np.asarray(f, np.int64)]
        points.append(area_samples(tri, area, count, rng))
    if not points:
        return 0.0
    return farthest_outside(target, np.concatenate(points))


def farthest_outside(target, points: np.ndarray) -> float:  # noqa: ANN001 - a trimesh.Trimesh
    """How far the farthest of ``points`` outside the mesh ``target`` lies from it, metres (0 when all are inside):
    a point is outside when it lies on the front side of the face it is closest to; the few closest to an edge or a
    corner, and the farthest said to be outside (until one is confirmed), are decided by ray parity, which costs
    20x more on fitted meshes than the closest-point query that gives the distances. An open ``target`` has no
    inside: the sign test alone decides."""
    import trimesh

    pts = np.asarray(points, float).reshape(-1, 3)
    if not len(pts):
        return 0.0
    with_tree(target)
    orientation = 1.0 if target.volume >= 0 else -1.0  # an inside-out mesh has its normals pointing in
    closest, distance, triangle = trimesh.proximity.closest_point(target, pts)
    off = distance > 1e-6
    side = orientation * np.einsum("ij,ij->i", pts - closest, target.face_normals[triangle])
    is_outside = side > 0
    # closest to an edge or a corner the face's normal says little (straight out from an edge it is at 90
    # degrees to the offset): those few points get the ray-parity test
    unsure = off & (np.abs(side) < 0.5 * distance)
    watertight = target.is_watertight
    if unsure.any() and watertight:
        with np.errstate(invalid="ignore", divide="ignore"):
            is_outside[unsure] = ~inside(target, pts[unsure])
    candidates = np.flatnonzero(off & is_outside)
    if not watertight:
        return float(distance[candidates].max()) if len(candidates) else 0.0
    # the sign test misreads points next to the slivers boolean operations leave: the farthest points said to
    # be outside are confirmed by ray parity, farthest first, until one is
    candidates = candidates[np.argsort(-distance[candidates])]
    for start in range(0, len(candidates), 256):
        batch = candidates[start : start + 256]
        with np.errstate(invalid="ignore", divide="ignore"):
            confirmed = batch[~inside(target, pts[batch])]
        if len(confirmed):
            return float(distance[confirmed].max())
    return 0.0


@dataclass(kw_only=True)
class MassProperties:
    """Volume, centre of mass and inertia of a solid of uniform density."""

    volume_m3: float
    """Volume, m^3."""
    mass_kg: float
    """density x volume, kg."""
    center_of_mass: np.ndarray
    """[3] centre of mass, metres (the mesh's frame)."""
    diagonal_inertia: np.ndarray
    """[3] principal moments of inertia about the centre of mass, kg m^2."""
    principal_axes: np.ndarray
    """[4] quaternion (x, y, z, w) rotating the mesh's axes onto the principal axes."""


def mass_properties(mesh: Mesh, density: float) -> MassProperties:
    """Mass properties of a closed mesh of uniform ``density`` (kg / m^3); of its convex hull when it is not
    closed (what a simulator would then do)."""
    import trimesh
    from scipy.spatial.transform import Rotation

    tm = trimesh.Trimesh(vertices=mesh[0], faces=mesh[1], process=False)
    with np.errstate(invalid="ignore", divide="ignore"):
        if not tm.is_watertight or not tm.volume > 0:
            tm = tm.convex_hull
        tm.density = float(density)
        volume = float(abs(tm.volume))
        com = np.asarray(tm.center_mass, float)
        inertia = np.asarray(tm.moment_inertia, float)  # [3, 3] about the centre of mass, mesh axes
    if not (volume > 0 and np.all(np.isfinite(com)) and np.all(np.isfinite(inertia))):
        return MassProperties(volume_m3=0.0, mass_kg=0.0, center_of_mass=np.asarray(mesh[0], float).mean(0),
                              diagonal_inertia=np.zeros(3), principal_axes=np.array([0.0, 0.0, 0.0, 1.0]))  # fmt: skip
    moments, axes = np.linalg.eigh(0.5 * (inertia + inertia.T))
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return MassProperties(volume_m3=volume, mass_kg=float(density) * volume, center_of_mass=com,
                          diagonal_inertia=np.maximum(moments, 0.0),
                          principal_axes=Rotation.from_matrix(axes).as_quat())  # fmt: skip


def without_zero_area_faces(mesh: Mesh, *, eps: float = 1e-12) -> Mesh:
    """``mesh`` with its zero-area faces removed so that a closed mesh stays closed (boolean results carry a few:
    a sliver whose three corners lie on a line, or two corners at one point; the splat binding rejects them).

    A face with two coincident corners is collapsed (its corners merged; the faces left with a repeated corner
    go); a face whose corners lie on a line goes, and the neighbour across its long edge is split at the middle
    corner, which keeps every edge paired. Where that leaves a closed mesh open (a collapse next to another
    short edge), manifold3d's edge collapse at 0.1 micron tolerance is used instead, which keeps it closed.
    """
    out = _mended(mesh, eps)
    if _paired(out) or not _paired(mesh):
        return out
    solid = _solid(mesh)
    if solid is None:
        return out
    points, faces = _mesh(solid.simplify(1e-7))
    if _paired((points, faces)) and not np.any(_twice_area(points, faces) < eps):
        return points, faces
    return out


def _twice_area(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    t = np.asarray(points, np.float64)[np.asarray(faces, np.int64)]
    return np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)


def _paired(mesh: Mesh) -> bool:
    """Every directed edge of the mesh has its reverse exactly once (a closed, consistently oriented surface)."""
    faces = np.asarray(mesh[1], np.int64)
    if len(faces) == 0:
        return False
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    n = int(edges.max()) + 1
    fwd = np.sort(edges[:, 0] * n + edges[:, 1])
    if np.any(fwd[1:] == fwd[:-1]):
        return False
    return bool(np.array_equal(fwd, np.sort(edges[:, 1] * n + edges[:, 0])))


def _mended(mesh: Mesh, eps: float) -> Mesh:
    """The face-by-face mend of :func:`without_zero_area_faces`."""
    points = np.asarray(mesh[0], np.float64)
    faces = np.asarray(mesh[1], np.int64).copy()

    def twice_area(f: np.ndarray) -> np.ndarray:
        return _twice_area(points, f)

    for _ in range(8):
        bad = np.flatnonzero(twice_area(faces) < eps)
        if len(bad) == 0:
            break
        face_of_edge = {(int(f[k]), int(f[(k + 1) % 3])): i for i, f in enumerate(faces) for k in range(3)}
        drop: set[int] = set()
        extra: list[list[int]] = []
        merge: dict[int, int] = {}
        for i in bad:
            if i in drop:
                continue
            f = [int(v) for v in faces[i]]
            corners = points[f]
            lengths = [float(np.linalg.norm(corners[(k + 1) % 3] - corners[k])) for k in range(3)]
            short = int(np.argmin(lengths))
            if lengths[short] <= 1e-9:  # two corners at one point: merge them
                a, b = f[short], f[(short + 1) % 3]
                if a != b:  # a face that repeats a corner index just goes
                    merge[max(a, b)] = min(merge.get(min(a, b), min(a, b)), min(a, b))
                drop.add(i)
                continue
            k = int(np.argmax(lengths))  # directed long edge a -> c, middle corner b
            a, c, b = f[k], f[(k + 1) % 3], f[(k + 2) % 3]
            j = face_of_edge.get((c, a))
            if j is None or j in drop or j == i:
                continue
            g = [int(v) for v in faces[j]]
            d = next((v for v in g if v not in (a, c)), None)
            if d is None:  # the neighbour repeats a corner itself: left to the next round (or the edge collapse)
                continue
            drop.update((i, j))
            extra += [[c, b, d], [b, a, d]]
        keep = np.array([i not in drop for i in range(len(faces))], bool)
        faces = np.concatenate([faces[keep], np.asarray(extra, np.int64).reshape(-1, 3)])
        if merge:
            for old in sorted(merge, reverse=True):  # follow chains of merges
                new = merge[old]
                while new in merge and merge[new] < new:  # indices only decrease: no cycle
                    new = merge[new]
                faces[faces == old] = new
            faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    faces = faces[twice_area(faces) >= eps]
    used = np.unique(faces)
    remap = np.full(len(points), -1, np.int64)
    remap[used] = np.arange(len(used))
    return points[used], remap[faces]
