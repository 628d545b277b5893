"""Convex decomposition that follows a fitted mesh: recursive plane cuts until every piece is convex to a tolerance.

A simulator-ready object needs convex colliders; the one-geometry rule needs them to be the rendered mesh. General
approximate decompositions (CoACD, V-HACD) bound a concavity measured relative to the object's size, so their
parts of a fitted table or shelf stand centimetres outside its surface (measured on the demo's fitted furniture:
CoACD with 8-24 parts reaches 6-12 cm out; 480-780 parts still 1 cm). Furniture is made of slabs and posts meeting
at planes, so this decomposition cuts along planes: the piece whose surface lies deepest inside its own convex
hull is cut by the plane (object axes x, y, z, at evenly spaced offsets, just either side of where its vertices
gather, and through the point of its hull farthest from it) that leaves the least hull volume in excess of the
solid (less half the volume it leaves convex), pieces falling apart are taken one by one, until every piece
lies within ``tolerance`` of its hull or ``max_parts`` is reached (then, optionally, on while a hull stands
over ``max_reach`` outside the mesh).

:func:`convexify` then makes the mesh the union of the pieces' hulls: the rendered surface grows into its
concavities by at most the tolerance reached (a few millimetres), and the collider is exactly the rendered
solid. Pieces are exact sub-solids of the mesh (manifold3d), so a flat face of the mesh (a cut base, a wall
clip, the plane between two neighbours) stays where it was: the hull of points on one side of a plane stays on
that side.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Decomposition", "convexify", "plane_decomposition"]

Mesh = tuple[np.ndarray, np.ndarray]


@dataclass(kw_only=True)
class Decomposition:
    """Convex pieces of a closed mesh."""

    parts: list[Mesh]
    """Convex hulls of the pieces, ``(points [N, 3], faces [F, 3])`` each, the mesh's frame."""
    concavity_m: float
    """Deepest point of the mesh's surface inside its piece's hull, metres: how far the union of ``parts``
    reaches outside the mesh."""
    excess_m3: float
    """Volume of the union of hulls not in the mesh, m^3."""
    intrusion_m3: float = 0.0
    """Volume of the hulls inside the keep-out solids beyond the mesh's own overlap with them, m^3 (0 without
    keep-outs)."""


@dataclass(eq=False)  # a piece is itself (lists find it by identity)
class _Piece:
    solid: object  # manifold3d.Manifold
    volume: float
    hull: object  # manifold3d.Manifold
    hull_volume: float
    vertices: np.ndarray
    concavity: float
    deepest: np.ndarray
    intrusion: float = 0.0  # volume of the hull inside the keep-out solids, m^3
    probes: np.ndarray | None = None  # samples of the hull's surface [n, 3]
    off: np.ndarray | None = None  # each probe's distance to the piece's surface [n], m
    outside: float | None = None  # how far the hull stands outside the whole mesh, m (asked for once, if at all)


def _intrusion(piece, hull, keep_out: list) -> float:  # noqa: ANN001
    """Volume of ``hull`` inside the keep-out solids ``(solid, lo [3], hi [3])`` beyond what of ``piece`` itself
    lies there (an overlap of the meshes is not the hull's doing, and no cut removes it), m^3."""
    box = np.asarray(hull.bounding_box(), float).reshape(2, 3)
    total = 0.0
    for solid, lo, hi in keep_out:
        if np.any(hi < box[0]) or np.any(lo > box[1]):
            continue
        inside = float((hull ^ solid).volume())
        if inside > 0.0:
            total += max(0.0, inside - float((piece ^ solid).volume()))
    return total


def _surface_samples(points: np.ndarray, faces: np.ndarray, extra: int, rng: np.random.Generator) -> np.ndarray:
    """A mesh's vertices, its face centroids and ``extra`` area-weighted surface samples."""
    from holousd.geometry._contact import area_samples

    tri = points[faces]
    out = [points, tri.mean(axis=1)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if extra > 0 and area.sum() > 0:
        out.append(area_samples(tri, area, extra, rng))
    return np.concatenate(out)


def _piece(solid, tolerance: float, keep_out: list | None = None) -> _Piece:  # noqa: ANN001
    """A piece and how far its hull stands off its surface: the largest distance from samples of the hull's
    surface to the piece's surface (first to the nearest of its vertices and face centroids; exactly, to its
    triangles, for the samples that puts further than half ``tolerance``); and how much of its hull lies inside
    the ``keep_out`` solids."""
    import trimesh
    from scipy.spatial import cKDTree

    from holousd.geometry._contact import _mesh, queryable

    hull = solid.hull()
    points, faces = _mesh(solid)
    hull_points, hull_faces = _mesh(hull)
    rng = np.random.default_rng(0)
    surface = _surface_samples(points, faces, 0, rng)
    probes = _surface_samples(hull_points, hull_faces, 256, rng)
    distance, _ = cKDTree(surface).query(probes)
    far = distance > 0.5 * tolerance
    if np.any(far) and len(faces):
        _, exact, _ = trimesh.proximity.closest_point(queryable((points, faces)), probes[far])
        distance[far] = exact
    k = int(np.argmax(distance))
    return _Piece(solid=solid, volume=float(solid.volume()), hull=hull, hull_volume=float(hull.volume()),
                  vertices=points, concavity=float(distance[k]), deepest=probes[k], probes=probes, off=distance,
                  intrusion=_intrusion(solid, hull, keep_out) if keep_out else 0.0)  # fmt: skip


class _Outside:
    """How far the farthest of some points lies outside a closed mesh, metres (0 when all are inside;
    :func:`farthest_outside`, deterministic); the trimesh is built on the first query."""

    def __init__(self, mesh: Mesh) -> None:
        self.mesh = mesh
        self._target = None

    def __call__(self, points: np.ndarray) -> float:
        from holousd.geometry._contact import farthest_outside, queryable

        if self._target is None:
            self._target = queryable(self.mesh)
        return farthest_outside(self._target, points)


def _outside(piece: _Piece, outside: _Outside, reach: float) -> float:
    """How far the piece's hull stands outside the whole mesh, asked once per piece: over every sample of the
    hull's surface further than ``reach`` from the piece (no nearer one can stand further than ``reach``
    outside the mesh, which holds the piece). The one farthest from the piece alone may lie in the piece beside
    it while another, nearer, stands far out (a phone capture's table kept a hull 17 cm out so)."""
    if piece.outside is None:
        piece.outside = outside(piece.probes[piece.off > reach])
    return piece.outside


def _components(solid, min_volume: float) -> list:  # noqa: ANN001
    return [p for p in solid.decompose() if p.volume() > min_volume]


def _offsets(coords: np.ndarray, lo: float, hi: float, offsets: int) -> list[float]:
    """Plane offsets to try along one axis: evenly spaced ones and the few where the piece's vertices gather
    (its flat faces: a board's inner face, an earlier cut)."""
    span = hi - lo
    found = list(lo + span * np.linspace(0.0, 1.0, offsets + 2)[1:-1])
    bins = np.round((coords - lo) / 0.002).astype(np.int64)
    values, counts = np.unique(bins, return_counts=True)
    for b in values[np.argsort(-counts, kind="stable")][:4]:  # just either side: a cut on a face leaves sheets
        face = float(np.mean(coords[bins == b]))  # where the face is, not the 2 mm bin's centre; on it too: the
        found += [face - 5e-4, face, face + 5e-4]  # cut either side of a board's face leaves a sheet of the board
    return found


def _best_split(piece: _Piece, offsets: int, min_volume: float, min_thickness: float = 0.0015) -> list | None:
    """The components of ``piece`` after the best plane cut; None when no cut helps. A cut scores the hull
    volume its pieces leave in excess of the solid, less half the volume of the pieces it leaves convex (a ring
    needs two cuts before its excess falls: the first is the one that frees a convex board). A cut that leaves a
    piece thinner than ``min_thickness`` along its normal that is not convex is not made: cuts a hair off a face
    peeled bench_00's shelf in half-millimetre sheets, each the outline of a compartment's wall, whose hulls
    spanned the compartment 16 cm outside the mesh."""

    def score(parts: list, axis: int) -> float | None:
        hulls = [float(p.hull().volume()) for p in parts]
        volumes = [float(p.volume()) for p in parts]
        convex = [h - v <= 0.02 * v for v, h in zip(volumes, hulls, strict=True)]
        for part, flat in zip(parts, convex, strict=True):
            box = np.asarray(part.bounding_box(), float).reshape(2, 3)
            if not flat and box[1, axis] - box[0, axis] < min_thickness:
                return None
        return sum(hulls) - piece.volume - 0.5 * sum(v for v, c in zip(volumes, convex, strict=True) if c)

    lo, hi = piece.vertices.min(axis=0), piece.vertices.max(axis=0)
    best, best_score = None, piece.hull_volume - piece.volume
    for axis in range(3):
        span = hi[axis] - lo[axis]
        if span <= 1e-6:
            continue
        normal = np.zeros(3)
        normal[axis] = 1.0
        candidates = [*_offsets(piece.vertices[:, axis], lo[axis], hi[axis], offsets), float(piece.deepest[axis])]
        for at in candidates:
            if not lo[axis] + 0.005 * span < at < hi[axis] - 0.005 * span:
                continue
            above, below = piece.solid.split_by_plane(tuple(normal), float(at))
            parts = [*_components(above, min_volume), *_components(below, min_volume)]
            if len(parts) < 2:
                continue
            value = score(parts, axis)
            if value is not None and value < best_score - 1e-12:
                best, best_score = parts, value
    return best


def _height_over(piece: object, normal: np.ndarray, offset: float) -> float:
    """How far ``piece`` reaches above the plane ``normal . x = offset``, metres."""
    from holousd.geometry._contact import _mesh

    return float((_mesh(piece)[0] @ np.asarray(normal, float)).max() - offset)


def _components_of_split(piece: object, normal: np.ndarray, offset: float, min_volume: float) -> list:
    """The pieces of ``piece`` on both sides of the plane ``normal . x = offset``."""
    one, other = piece.split_by_plane(tuple(float(v) for v in normal), float(offset))  # type: ignore[attr-defined]
    return _components(one, min_volume) + _components(other, min_volume)


def plane_decomposition(mesh: Mesh, *, tolerance: float = 0.003, max_parts: int = 32, offsets: int = 9,
                        cuts: list[tuple] | None = None, keep_out: list[Mesh] | None = None,
                        max_intrusion: float = 1e-8, keep_out_parts: int = 0, rim: float = 0.03,
                        max_reach: float | None = None, reach_parts: int = 0,
                        ) -> Decomposition | None:  # fmt: skip
    """Cut a closed mesh into convex pieces by planes (see the module docstring).

    Args:
        mesh: Closed manifold mesh ``(points [N, 3], faces [F, 3])``.
        tolerance: Stop cutting a piece when its surface lies within this distance of its hull, metres.
        max_parts: Most pieces cut for concavity.
        offsets: Evenly spaced plane offsets tried along each axis (plus a few where the vertices gather and one
            through the hull point farthest from the piece). Fewer are faster but not safer: on 17 fitted objects
            whose hull reaches over 1 cm outside them (fast preset, 32 parts) 3 offsets reached 33.5 cm in sum in
            37 s against 9's 41.0 cm in 65 s, yet the demo's table top then held 3 fewer of its objects.
        cuts: Planes ``(normal [3], offset)`` or ``(normal, offset, sides)`` every piece is cut by first, half
            a millimetre along ``normal`` from ``normal . x = offset``: where something rests on the mesh, its flat
            support surface (normal pointing out of it), so that no hull bridges more than that above it. With
            ``sides`` (planes ``(normal, offset)`` around the flat patch, normals outwards), what lies above the
            surface is also cut half a millimetre inside each side: the rim a patch cut into a bumpy top leaves
            around it is no ring whose hull spans the patch (cut outside the sides, it left a layer of each wall
            over the patch, and the layers met at the corners); what reaches higher than ``rim`` above the
            surface is first cut there (a shelf's side panels and upper boards stand on its board's rim).
        keep_out: Closed meshes (the mesh's frame) no piece's hull may enter: the neighbours and the support
            beside and under the object. A piece whose hull holds more than ``max_intrusion`` m^3 of them is cut
            before any other, whatever its concavity (a shelf's side and upper board as one piece: their hull
            fills the compartment where a bowl stands).
        keep_out_parts: Further pieces allowed for cutting pieces whose hull enters ``keep_out``; they do not
            count against ``max_parts`` (once they are spent, such cuts take from ``max_parts``). On the demo's
            table, cut flat under three objects, the sheets above the cuts spent the 32 parts when they counted,
            and left a hull of the top and its legs reaching 48 cm outside the mesh.
        max_reach: Once ``max_parts`` (and the keep-out parts) are spent, or every piece within ``tolerance``
            but those whose cut the budget did not allow, go on cutting the piece (one of those included) whose
            hull has a point over this far outside the whole mesh, metres (None: stop), with at most
            ``reach_parts`` more pieces: on a phone capture's lumpy table, cut under three objects, the budgets
            went to bumps and slivers and left one hull 19 cm outside the mesh, over a leg and beside it.
        reach_parts: Most pieces cut for ``max_reach``.

    Returns:
        The pieces' hulls and how far they reach outside the mesh; None when the mesh is not a closed manifold.
    """
    from holousd.geometry._contact import _mesh, _solid

    solid = _solid(mesh)
    if solid is None:
        return None
    min_volume = 1e-4 * float(solid.volume())
    solids = _components(solid, min_volume) or [solid]
    whole = len(solids)
    for normal, offset, *sides in cuts or []:  # half a millimetre off the surface: a cut on a face leaves a sheet
        split = []
        for piece in solids:
            above, below = piece.split_by_plane(tuple(float(v) for v in normal), float(offset) + 5e-4)
            over, tall = _components(above, min_volume), []
            if sides and sides[0]:  # the rim left around the patch (up to `rim` above it), cut along its sides
                high = [p for p in over if _height_over(p, normal, offset) > rim]
                over = [p for p in over if _height_over(p, normal, offset) <= rim]
                for p in high:
                    upper, lower = p.split_by_plane(tuple(float(v) for v in normal), float(offset) + rim)
                    tall += _components(upper, min_volume)
                    over += _components(lower, min_volume)
                for side, at in sides[0]:  # half a millimetre inside: a cut outside left a layer of the wall on
                    # each side over the patch, the layers one piece meeting at the corners, whose hull spanned the
                    # patch (hard/stack's box: 1.2 cm over it); inside, the walls keep their whole thickness
                    over = [part for p in over for part in _components_of_split(p, side, at - 5e-4, min_volume)]
            split += tall + over + _components(below, min_volume)
        solids = split or solids
    blocked = []
    for other in keep_out or []:
        found = _solid(other)
        if found is not None:
            box = np.asarray(found.bounding_box(), float).reshape(2, 3)
            blocked.append((found, box[0], box[1]))
    pieces = [_piece(p, tolerance, blocked) for p in solids]
    frozen: list[_Piece] = []  # pieces no plane cut improves (or whose cut the reach parts left do not allow)
    waiting: list[_Piece] = []  # pieces whose cut the budget did not allow (the reach bound may still cut them)
    # parts added by the given `cuts` and by cuts made to keep out of `keep_out` do not count against `max_parts`
    extra = len(solids) - whole
    keep_out_parts += extra
    far = 0  # parts cut beyond the budgets for pieces reaching over max_reach outside the mesh (<= reach_parts)
    outside = _Outside(mesh)
    while True:
        worst = max(range(len(pieces)), key=lambda i: (pieces[i].intrusion > max_intrusion, pieces[i].concavity),
                    default=None)  # fmt: skip
        done = worst is None or (pieces[worst].concavity <= tolerance and pieces[worst].intrusion <= max_intrusion)
        intruding = not done and pieces[worst].intrusion > max_intrusion
        count = len(pieces) + len(frozen) + len(waiting)
        reaching = False
        if done or (not intruding and count >= max_parts + extra + far):
            if max_reach is None or far >= reach_parts:
                break
            # the budget is spent: cut on only a piece whose hull stands over max_reach outside the whole mesh
            # (not merely off its own surface, towards the piece beside it), one the budget left waiting too
            found = next((p for p in sorted(pieces + waiting, key=lambda p: -p.concavity)
                          if p.concavity > max_reach and _outside(p, outside, max_reach) > max_reach), None)
            if found is None:
                break
            (pieces if found in pieces else waiting).remove(found)  # by identity (eq=False)
            piece, reaching = found, True
        else:
            piece = pieces.pop(worst)
        split = _best_split(piece, offsets, min_volume)
        added = len(split) - 1 if split is not None else 0
        if reaching:
            if split is None or far + added > reach_parts:
                frozen.append(piece)
                continue
            far += added
        elif intruding and split is not None and extra + added <= keep_out_parts:
            extra += added
        elif split is None:
            frozen.append(piece)
            continue
        elif count + added > max_parts + extra + far:
            waiting.append(piece)  # (an intruding piece beyond the keep-out parts too) the reach bound may cut it
            continue
        pieces.extend(_piece(p, tolerance, blocked) for p in split)
    pieces += frozen + waiting
    total = float(solid.volume())
    union = pieces[0].hull
    for p in pieces[1:]:
        union = union + p.hull
    return Decomposition(parts=[_mesh(p.hull) for p in pieces],
                         concavity_m=max((p.concavity for p in pieces), default=0.0),
                         excess_m3=max(0.0, float(union.volume()) - total),
                         intrusion_m3=sum(p.intrusion for p in pieces))  # fmt: skip


def convexify(mesh: Mesh, decomposition: Decomposition) -> Mesh | None:
    """The union of a decomposition's hulls as one closed mesh (the rendered solid whose collider the hulls
    are); None when manifold3d cannot form it."""
    import manifold3d

    from holousd.geometry._contact import _mesh, _solid

    solids = [s for s in (_solid(p) for p in decomposition.parts) if s is not None]
    if not solids:
        return None
    union = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add) if len(solids) > 1 else solids[0]
    if union.is_empty():
        return None
    return _mesh(union)
