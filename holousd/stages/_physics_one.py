"""The one-geometry physics set-up: the default of the physics stage (``PhysicsSetupConfig(one_geometry=True)``).

ARCHITECTURE.md, "one geometry per object": everything done so that an object can stand is done to its rendered
mesh and its SDF, and the collider is derived from that final mesh alone. In order, as small passes over the
objects:

1. ``clip``: each mesh is trimmed where it runs behind one of the room's walls (the unseen back of something
   standing against a wall; the fit leaves it unbounded there).
2. ``relations``: the support tree and beside pairs (:func:`holousd.graph.infer_relations`: the parent is what
   an object touches, not what its overhanging ends lie above).
3. ``rest``: breadth-first from the room, each object is set onto its support. Under each child resting on a
   support, the support's surface is cut flat at the lowest point of it under the child (at most ``top_depth``
   below the highest point there that comes within ``bottom_band`` of the child's underside, and no deeper than
   the child can follow; no lower than the surface seen around the child, within ``top_depth`` of that point,
   where the child's underside is no lower: a top the fit dented under what hides it), inside the child's
   footprint (1 cm wider) up to ``top_depth`` above that surface,
   and under the child's outline up to ``2 * top_depth`` above its bottom (a lump hidden under its overhang;
   above the flat surface, for a child fitted down through it);
   its dents under the child's footprint (not the centimetre beyond, which may be a neighbour's, cut flat
   lower) are filled up to that flat surface, and where it is open under the child (rays fall through
   to a lower part of it or miss) the surface is carried over the opening within the rectangle of the
   support's own top at that height (a fitted top is a bumpy dome of facets, and no camera sees it under what
   rests on it; a wall beside stays);
   the support's shape is then settled (pass 5) with its decomposition cut along those flat surfaces. Then the child's
   unseen underside is cut flat, ``clearance`` above the higher of the support's mesh and collider under it (and under
   its whole footprint, where its lowest points hang over a lower edge; at the support's top where that runs through the
   child higher than what its lowest points found: a keel fitted down through the top), deep enough for a base spanning
   half its width with the centre of mass over it (``base_depth``, ``base_margin``), the object moved down when it
   floats above, by at most ``max_shift`` from its fitted pose counting its parent's moves (when that brings it onto its
   support, its base is cut less deep; an object that cannot reach its support is left where it was seen, and the
   refused move recorded). Whatever of the support's collider, or of its mesh (a sliver its decomposition
   dropped), still lies inside the child is cut away from the child's mesh and SDF. Children follow their
   parent's moves.
4. ``separate``: neighbours whose meshes still overlap are cut apart at the middle of the overlap, across its
   thinnest axis, within the overlap's bounds (1 cm wider), as two real objects meet at one face.
5. ``shape``: the convex hull of the mesh is the collider when it reaches at most ``hull_tolerance`` outside
   it (at most ``convexify``: the mesh and SDF then become the hull, a lumpy book or ball fitted on coarse
   cells) and enters none of the objects around it; where it does enter one, the hull cut clear of them by planes
   (against what rests on it the flat surface cut under it, else a level plane ``clearance`` under it, neither cutting
   under another object resting there; against a neighbour beside it an upright separating plane ``clearance``
   short of it) that cut at most ``convexify`` into the mesh and a quarter of its volume: the mesh and SDF become that
   one part (``convexify:cleared``); else a decomposition of that mesh
   (:func:`holousd.geometry.plane_decomposition`: plane cuts until every piece lies within ``hull_tolerance`` of its
   hull and no piece's hull enters the objects around it (their colliders once shaped, objects in name order), at most
   ``max_parts``; then, with at most ``reach_parts`` more, until no piece's hull, one that the budget left uncut
   included, stands over ``max_reach`` outside the mesh). When the decomposition reaches at most ``convexify`` outside
   the mesh and its union enters nothing around it, the mesh and SDF become the union of its parts (the rendered surface
   fills its concavities by at most that much) and the collider is exactly the rendered solid; else the reach is what it
   is, and is recorded, and what of the mesh no part covers (slivers the cuts dropped) is cut from the mesh and SDF, so
   that a simulator meets all of the rendered solid. A support is shaped before its children are set on it, keeping out
   of them (where the fit left them) and of what stands around it, with ``support_keep_out_parts`` more parts for that
   (``keep_out_parts`` for the others).
6. ``unclasp``: parts of two colliders that still overlap (hulls reaching past their meshes into a neighbour, at
   most ``hull_tolerance`` deep) are clipped apart by a plane of one's faces, pair of parts by pair of parts until
   none is left but those no clip separates, and what of the clipped body's
   mesh lay in the piece cut off goes with it (``clip:collider:<other>``).
7. ``limit``: a collider part whose hull has more than ``max_hull_vertices`` vertices (PhysX cooks at most 64 by
   default) becomes the hull of that many of its own, its lowest and highest level faces kept; what of the mesh and
   SDF that smaller part leaves out (a few millimetres) is cut away (``hullVertices:<mm>``), unless that cut drops a
   piece the smaller parts no longer join (the mesh then stays whole, a few millimetres outside them).
8. ``mass``: mass, centre of mass and inertia (principal moments and axes) of the final mesh at ``density``.

Each object records (``HoloGeometryAPI``): its shift from the pose the fit gave (``holo:geometry:fitShift``), its
collider's reach outside the mesh, its deepest penetration into another node (mesh into mesh or slab, collider
into collider), its volume and the edits made.
No collider-only edit is made: where the rendered geometry cannot stand, the stability verdict says so.

The room's static collider is a set of floor and wall slabs fitted to the background mesh's planes (walls of any
orientation about z)
(``background_collider='slabs'``; its triangle mesh with ``'mesh'`` or when no floor plane is found): Newton's
triangle-mesh contact launched furniture resting on the fitted room shell.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from holousd._errors import SceneError
from holousd.geometry._contact import (
    _by_content,
    _solid,
    collider_reach,
    cut_by_plane,
    mass_properties,
    overlap,
    queryable,
    subtract,
    within,
    without_zero_area_faces,
)
from holousd.geometry._decompose import Decomposition, convexify, plane_decomposition
from holousd.geometry._hulls import PHYSX_HULL_VERTEX_LIMIT, cut_plane, limited_hull
from holousd.geometry._meshing import meshed_only
from holousd.graph import RelationConfig, Relations, infer_relations
from holousd.stages._physics_setup import (
    PHYSICS_LAYER,
    ObjectPhysics,
    PhysicsSetupResult,
    Wall,
    _depth_inside,
    _descendants,
    _room_planes,
    _room_slabs,
    stage_inputs,
)
from holousd.stages._physics_setup import _drop_degenerate as _without_degenerate
from holousd.usd._scene import BACKGROUND, SceneGraph
from holousd.usd._types import Collider, GeometryRecord, MeshData, PhysicsProps, Pose, SdfField

__all__ = ["PhysicsSetupConfig", "setup_physics"]



@dataclass(kw_only=True)
class PhysicsSetupConfig:
    """Settings of the physics set-up stage."""

    density: float = 500.0
    """Density of every object (no material estimate yet), kg / m^3."""
    friction: float = 0.5
    """Static and dynamic friction coefficient of every node."""
    restitution: float = 0.0
    """Coefficient of restitution of every node."""
    hull_tolerance: float = 0.005
    """The convex hull of the mesh is the collider when it reaches at most this far outside the mesh, metres;
    else a convex decomposition of the mesh (a shelf's hull would fill its compartments, a bowl's its inside)."""
    clip_to_walls: bool = True
    """Trim each object's mesh where it runs behind one of the room's walls, before anything else is decided."""
    rest: bool = True
    """Set every object onto its support parent by cutting its unseen underside flat on the support's surface
    (and the support's top flat where others rest on it), moving it down by at most ``max_shift`` when it floats
    above. False: meshes and poses stay as fitted (but for the wall clip)."""
    base_depth: tuple[float, float] = (0.5, 0.008)
    """How an object's underside is cut flat: ``(share, deepest)``: deep enough that the flat base spans
    ``share`` of the object's width along x and y and holds the centre of mass ``base_margin`` inside it, at
    most ``deepest`` metres (nothing for a flat base). The underside of an object resting on something is never
    observed; the fit leaves it rounded by about a voxel, and a rounded base rocks or rolls (the protocol has no
    damping) where the real object stands."""
    base_margin: float = 0.1
    """Least distance of the centre of mass inside the flat base cut under an object, as a share of the object's
    smaller width (0.1: a cube tips past 11 degrees). Half the width along x and y is not enough: the fitted
    5 cm cube of hard/small_beside_large had its lowest 2 mm spanning 3.2 x 4 cm as a triangle with its centre of
    mass 1.2 mm outside, and it tipped onto a facet 30 degrees over in both simulators."""
    top_depth: float = 0.015
    """Deepest flattening of the top of a support that others rest on, below its highest point, metres: a
    fitted top is a bumpy dome of facets (a centimetre or two on 160x120 captures); a child set on it rocks, and
    the collider's hulls bridge its dents above the rendered surface."""
    clearance: float = 0.001
    """Gap left between an object's flat base and its support's surface, metres."""
    max_shift: float = 0.01
    """Largest move of an object from its fitted pose, metres (about what its own depth and masks allow: the
    observed surface moves with it). A larger one is refused and recorded; the object stays where it was seen."""
    max_extend: float = 0.05
    """Feet carried down, metres: once an object is set on its support (or is within one cell of its SDF grid of
    it, and at most this much), each of its feet (the pieces of it within one cell, at most this much, of its
    lowest point: the ends of legs, a base) that ends above the base is carried straight down onto it, in its mesh
    and SDF: a fit cannot end a bottom it barely sees closer than a cell (on coarse cells legs end short of the
    floor, at different heights, and the table rocks on the longest), and the observed surface stays where it
    was seen. An object farther above its support than that and ``max_shift`` is left floating (recorded)."""
    separate: bool = True
    """Cut apart neighbours whose meshes overlap, at the middle of the overlap."""
    min_overlap: float = 1e-7
    """Overlaps smaller than this and no deeper than ``clearance`` are left alone (touching, not intersecting), m^3
    (0.1 cm^3). A small one deeper is cut: a sliver of 0.04 cm^3, 3.4 mm deep, left between bench_00's two books
    side by side on the table, was the first step's push that tipped one 7 degrees in XPBD."""
    max_separation_loss: float = 0.3
    """A cut between neighbours may remove at most this fraction of an object's volume (else it is not made)."""
    max_parts: int = 32
    """Most convex parts of a decomposition cut for concavity (the mesh's bumps and hollows)."""
    support_keep_out_parts: int = 64
    """Further parts a support's plane decomposition may cut to keep its hulls out of what rests on it and
    stands around it (a fitted shelf's 32 parts spent on its bumps leave a hull spanning a compartment and the
    objects standing in it, which the simulators throw)."""
    keep_out_parts: int = 16
    """Further parts any other object's plane decomposition may cut to keep its hulls out of the colliders shaped
    before it (neighbours, in name order). Without them, hard/touching_siblings' box spent its 32 parts on its
    own bumps and kept a hull 1.1 mm into the book beside it: Newton's XPBD resolves an overlap at the first
    step as a velocity, and threw the book 2 cm (MuJoCo's soft contact did not)."""
    max_reach: float | None = 0.02
    """When the parts above are spent, a plane decomposition goes on cutting a piece whose hull stands further than
    this outside the mesh, metres, with at most ``reach_parts`` more parts (on a phone capture's lumpy fits the
    budgets went to the bumps and the cuts under what stands on a top: the phone demo's table kept a part 19 cm
    outside its mesh, over a leg and the space beside it, and its shelf one filling a compartment, 17 cm); a
    piece whose cut needed more parts than were left is cut so too. None: no such bound."""
    reach_parts: int = 64
    """Most parts cut for ``max_reach``."""
    decomposition: str = "planes"
    """'planes': :func:`holousd.geometry.plane_decomposition` (plane cuts until each piece lies within
    ``hull_tolerance`` of its hull: fitted furniture is slabs and posts); 'coacd': CoACD with the quick settings
    of ``decomposition_iterations`` (its parts of a fitted table or shelf reach 6-12 cm outside the mesh)."""
    decomposition_iterations: int | None = 20
    """CoACD only: tree-search iterations with a coarse (300-sample) concavity metric, a one-level search and
    concavity threshold 0.1. None runs :func:`holousd.physics.convex_decomposition` with its full settings."""
    convexify: float = 0.01
    """When an object's decomposition reaches at most this far outside its mesh, metres, the mesh (and SDF)
    becomes the union of the decomposition's parts: the rendered surface fills its concavities by at most that
    much (about what the object's own depth and masks allow), and the collider is then exactly the rendered
    solid. 0: never."""
    max_hull_vertices: int | None = PHYSX_HULL_VERTEX_LIMIT
    """Most vertices of one convex collider part (at least 8), or None: no limit. A part with more becomes the hull
    of that many of its own vertices (:func:`holousd.geometry._hulls.limited_hull`: inside it, its lowest and highest
    level faces kept) and the mesh is cut to what of it lies inside the parts (edit ``hullVertices:<mm>``), so the
    collider stays the rendered solid. PhysX cooks a hull of at most 64 vertices by default (Omni PhysX's
    ``hullVertexLimit``, also its GPU collision's limit) out of the points it is given: 181 of the 5665 parts of
    bench/fast and hard/fast had more (357 at most, a lumpy ball), and such a part was simulated as a hull of
    PhysX's choosing. Without the level faces kept (365aff6, every row of the README's table on the same search
    layers) the demo's ball lost the flat base it stands on and rolled 5.6 deg in both solvers (the demo 100 / 100
    -> 90 / 90) and hard/thin's book_1 tipped in XPBD; with them kept, the demo 100 / 100 and all seven hard/fast
    scenes 100 / 100 (agreement 100) on the same search layers, no part over 64 points."""
    background_collider: str = "slabs"
    """'slabs': floor and wall slabs (walls of any orientation about z) fitted to the background mesh (falls
    back to 'mesh' when no floor plane is found); 'mesh': the background's triangle mesh (approximation none)."""
    slab_thickness: float = 0.2
    """Thickness of each background slab behind its plane, metres."""
    relations: RelationConfig = field(default_factory=RelationConfig)
    """Support / beside inference settings."""
    seed: int = 0
    """Seed of CoACD and of the surface sampling."""
    provenance: str = "s2_physics_setup"
    """Writer name recorded on the nodes."""


# ----------------------------------------------------------------------------------------------- the state
@dataclass(kw_only=True, frozen=True)
class _Body:
    """One object as the passes see it: its mesh and SDF in object coordinates, its pose, what was done."""

    name: str
    mesh: MeshData
    sdf: SdfField | None
    pose: Pose
    fit_pose: Pose
    edits: tuple[str, ...] = ()
    refused: float = 0.0
    planes: tuple[tuple, ...] = ()
    """Flat support surfaces cut into the mesh: ``(normal, offset, sides)`` in object coordinates, the surface
    ``normal . x = offset`` and the vertical planes ``(normal, offset)`` around the patch cut flat (normals
    outwards): the collider's decomposition cuts along them, so no convex part bridges above a surface something
    rests on (neither from below nor from the rim of matter left standing around the patch)."""
    collider: tuple[str, list[MeshData], float] | None = None
    """The collider derived from the current mesh (kind, parts in object coordinates, reach outside the mesh),
    once :func:`_shaped` has settled the mesh; None while the mesh may still change."""

    def world(self) -> tuple[np.ndarray, np.ndarray]:
        """The mesh in world coordinates."""
        return self.pose.apply(self.mesh.points), self.mesh.faces

    def moved(self, shift: np.ndarray) -> _Body:
        """The body moved by a world ``shift`` [3]."""
        pose = Pose(translation=np.asarray(self.pose.translation, float) + shift, orientation=self.pose.orientation)
        return replace(self, pose=pose)

    def cut(self, normal: np.ndarray, offset: float, edit: str, *, min_keep: float = 0.2) -> _Body:
        """The body with what lies where ``normal . x < offset`` (world; ``normal`` a unit vector) removed from
        its mesh and SDF; unchanged when less than ``min_keep`` of it would be left or it would fall apart."""
        rotation = self.pose.matrix()[:3, :3]
        n_obj = rotation.T @ np.asarray(normal, float)
        off_obj = float(offset) - float(np.asarray(normal, float) @ np.asarray(self.pose.translation, float))
        (points, faces), removed = cut_by_plane((self.mesh.points, self.mesh.faces), n_obj, off_obj,
                                                min_keep=min_keep)  # fmt: skip
        if removed <= 0:
            return self
        sdf = self.sdf
        if sdf is not None:
            grid = _grid_points(sdf)
            outside = off_obj - grid @ n_obj  # > 0 on the removed side: distance to the half-space
            sdf = replace(sdf, grid=np.maximum(sdf.grid, outside.reshape(sdf.grid.shape)).astype(np.float32))
            sdf = _held(sdf, points, faces)
        return replace(self, mesh=MeshData(points=points, faces=faces), sdf=sdf, edits=(*self.edits, edit),
                       collider=None)

    def minus_convex(self, parts: list[tuple[np.ndarray, np.ndarray]], edit: str, *, min_keep: float = 0.5) -> _Body:
        """The body with whatever of the convex world-space ``parts`` (another object's collider) lies inside it
        removed from its mesh and SDF; unchanged when less than ``min_keep`` of it would be left or it would fall
        apart."""
        inverse = np.linalg.inv(self.pose.matrix())
        local = [(p @ inverse[:3, :3].T + inverse[:3, 3], f) for p, f in parts]
        (points, faces), removed = subtract((self.mesh.points, self.mesh.faces), local, min_keep=min_keep)
        if removed <= 0:
            return self
        sdf = self.sdf
        if sdf is not None:
            values = sdf.grid.reshape(-1).astype(np.float64)
            for inside_part in _part_distances(sdf, local):  # < 0 inside the part
                values = np.maximum(values, -inside_part)
            sdf = replace(sdf, grid=values.reshape(sdf.grid.shape).astype(np.float32))
            sdf = _held(sdf, points, faces)
        return replace(self, mesh=MeshData(points=points, faces=faces), sdf=sdf, edits=(*self.edits, edit),
                       collider=None)

    def minus_mesh(self, other: tuple[np.ndarray, np.ndarray], edit: str, *, min_keep: float = 0.7,
                   min_volume: float = 0.0) -> _Body:  # fmt: skip
        """The body with whatever of the closed world mesh ``other`` lies inside it removed from its mesh and SDF
        (around the overlap the SDF takes the new mesh's signed distance where that is larger); unchanged as
        :meth:`minus_convex` leaves it, and when they overlap by at most ``min_volume`` m^3."""
        import trimesh

        from holousd.geometry._contact import inside

        inverse = np.linalg.inv(self.pose.matrix())
        local = (np.asarray(other[0], float) @ inverse[:3, :3].T + inverse[:3, 3], np.asarray(other[1]))
        both = overlap((self.mesh.points, self.mesh.faces), local)
        if both.volume_m3 <= min_volume:
            return self
        (points, faces), removed = subtract((self.mesh.points, self.mesh.faces), local, min_keep=min_keep)
        if removed <= 0:
            return self
        points, faces = without_zero_area_faces((points, faces))  # the boolean's slivers
        if not _closed(_drop_degenerate(MeshData(points=points, faces=faces))):  # as authored (float32): a mesh
            return self  # that no longer closes has no decomposition, and its hull would fill the cut
        sdf = self.sdf
        if sdf is not None:
            values = sdf.grid.reshape(-1).astype(np.float64)
            grid = _grid_points(sdf)
            # the samples around the overlap, measured against the new mesh (the body's own: rays against the
            # other's, a table's, took gigabytes)
            margin = 2.0 * sdf.voxel_size
            near = np.flatnonzero(np.all((grid >= both.lo - margin) & (grid <= both.hi + margin), axis=1))
            if len(near):
                target = queryable((points, faces))
                distance = trimesh.proximity.closest_point(target, grid[near])[1]
                signed = np.where(inside(target, grid[near]), -distance, distance)
                values[near] = np.maximum(values[near], signed)
            sdf = replace(sdf, grid=values.reshape(sdf.grid.shape).astype(np.float32))
            sdf = _held(sdf, points, faces)
        return replace(self, mesh=MeshData(points=points, faces=faces), sdf=sdf, edits=(*self.edits, edit),
                       collider=None)

    def within_convex(self, parts: list[tuple[np.ndarray, np.ndarray]], edit: str) -> _Body:
        """The body cut to what of it lies inside its own convex ``parts`` (object coordinates: its collider),
        in its mesh and SDF; unchanged when that would split it or remove much (see :func:`within`)."""
        (points, faces), removed = within((self.mesh.points, self.mesh.faces), parts)
        if removed <= 0:
            return self
        sdf = self.sdf
        if sdf is not None:
            values = _within_union(sdf.grid.reshape(-1).astype(np.float64), _grid_points(sdf), parts)
            sdf = replace(sdf, grid=values.reshape(sdf.grid.shape).astype(np.float32))
            sdf = _held(sdf, points, faces)
        return replace(self, mesh=MeshData(points=points, faces=faces), sdf=sdf,
                       edits=(*self.edits, f"{edit}:{1e6 * removed:.1f}cm3"), collider=None)  # fmt: skip

    def as_convex(self, part: MeshData, edit: str) -> _Body:
        """The body whose solid is the convex ``part`` (object coordinates); its SDF becomes the part's (the
        plane distances of its hull: exact inside)."""
        sdf = self.sdf
        if sdf is not None:
            inside_part = next(_part_distances(sdf, [(part.points, part.faces)]), None)
            if inside_part is not None:
                sdf = replace(sdf, grid=inside_part.reshape(sdf.grid.shape).astype(np.float32))
        return replace(self, mesh=part, sdf=sdf, edits=(*self.edits, edit), collider=None)

    def plus_convex(self, parts: list[tuple[np.ndarray, np.ndarray]], mesh: MeshData, edit: str) -> _Body:
        """The body whose solid is ``mesh``, the union of its own convex ``parts`` (object coordinates) that
        cover its old mesh; its SDF takes the parts' insides."""
        sdf = self.sdf
        if sdf is not None:
            values = sdf.grid.reshape(-1).astype(np.float64)
            for inside_part in _part_distances(sdf, parts):
                values = np.minimum(values, inside_part)
            sdf = replace(sdf, grid=values.reshape(sdf.grid.shape).astype(np.float32))
        return replace(self, mesh=mesh, sdf=sdf, edits=(*self.edits, edit), collider=None)


def _part_distances(sdf: SdfField, parts: list[tuple[np.ndarray, np.ndarray]]) -> Iterator[np.ndarray]:
    """For each convex part (object coordinates) with a hull, [X*Y*Z] signed plane distances of the SDF's
    samples to it (max over its hull's face planes: < 0 inside, exact there); degenerate parts are skipped."""
    grid = _grid_points(sdf)
    for planes in _part_planes(parts):
        yield _max_plane_distance(grid, planes)


def _part_planes(parts: list[tuple[np.ndarray, np.ndarray]]) -> Iterator[np.ndarray]:
    """[H, 4] face planes (``n . x + d <= 0`` inside) of each convex part with a hull; degenerate parts skipped."""
    from scipy.spatial import ConvexHull, QhullError

    for p, _ in parts:
        try:
            planes = ConvexHull(p).equations
        except (QhullError, ValueError):
            continue
        yield planes


def _within_union(values: np.ndarray, points: np.ndarray, parts: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """``max(values, union)`` at ``points`` [N, 3], the union's field being the least of the convex parts' signed
    plane distances (:func:`_part_distances`; degenerate parts skipped). Each part is measured only at the points
    where the union of the parts before it still lies above ``values``: elsewhere the answer is ``values``
    whatever the others give (the same numbers as measuring every point, a fraction of the work: most samples of
    a grid around an object are outside it by about as much as they are outside its nearest part)."""
    union = np.full(len(values), np.inf)
    open_ = np.arange(len(values))  # where the union so far lies above the values
    for planes in _part_planes(parts):
        union[open_] = np.minimum(union[open_], _max_plane_distance(points[open_], planes))
        open_ = open_[union[open_] > values[open_]]
        if not len(open_):
            break
    return np.maximum(values, union)


def _max_plane_distance(points: np.ndarray, planes: np.ndarray, chunk: int = 32768) -> np.ndarray:
    """[N] the largest of the signed distances of ``points`` [N, 3] to ``planes`` [H, 4] (``n . x + d``), in
    blocks of ``chunk`` points: the whole [N, H] matrix at once (8 N H bytes: a gigabyte for 700 000 samples and
    200 planes) cost more in memory traffic than in arithmetic."""
    out = np.empty(len(points))
    normals, offsets = planes[:, :3].T, planes[:, 3]
    for start in range(0, len(points), chunk):
        rows = points[start : start + chunk]
        # one row would take numpy's vector-matrix product, which can round the last bit otherwise than the
        # matrix product every other block takes: a point's distance would depend on how many were measured
        block = (rows if len(rows) > 1 else np.repeat(rows, 2, axis=0)) @ normals
        block += offsets
        out[start : start + chunk] = block.max(axis=1)[: len(rows)]
    return out


def _held(sdf: SdfField, points: np.ndarray, faces: np.ndarray) -> SdfField:
    """The SDF without the pieces a cut's new mesh ``(points, faces)`` no longer holds (crumbs and slivers a cut
    dropped: :func:`holousd.geometry._contact._one_piece`), so that the field and the mesh stay one solid."""
    return replace(sdf, grid=meshed_only(sdf.grid, sdf.origin, sdf.voxel_size, MeshData(points=points, faces=faces),
                                         sdf.iso_level))  # fmt: skip


def _grid_points(sdf: SdfField) -> np.ndarray:
    """[X*Y*Z, 3] object coordinates of an SDF's samples (C order)."""
    axes = [sdf.origin[i] + sdf.voxel_size * np.arange(n) for i, n in enumerate(sdf.grid.shape)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _base_depth(mesh: tuple[np.ndarray, np.ndarray], limits: tuple[float, float], margin: float = 0.0) -> float:
    """How deep to cut a body's underside flat (world ``mesh``): the least depth (up to ``limits[1]``) at which
    the base the cut leaves spans ``limits[0]`` of its width along x and along y and holds the vertical through
    its centre of mass ``margin`` times its smaller width inside (0 for a flat base: nothing needs cutting)."""
    from holousd.physics._static import _polygon_margin

    points, faces = mesh
    share, deepest = limits
    bottom = float(points[:, 2].min())
    width = np.maximum(np.ptp(points[:, :2], axis=0), 1e-9)
    centre = mass_properties(mesh, 1.0).center_of_mass[:2] if margin > 0 else None
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    a, b = points[edges[:, 0]], points[edges[:, 1]]
    for depth in np.linspace(0.0, deepest, 17):
        level = bottom + depth + 1e-9
        low = points[points[:, 2] <= level, :2]
        if not np.all(np.ptp(low, axis=0) >= share * width):
            continue
        if centre is None:
            return float(depth)
        crossing = (a[:, 2] <= level) & (b[:, 2] > level)  # where the cut meets the edges: the base's outline
        t = (level - a[crossing, 2]) / (b[crossing, 2] - a[crossing, 2])
        outline = np.concatenate([low, a[crossing, :2] + t[:, None] * (b[crossing, :2] - a[crossing, :2])])
        if _polygon_margin(outline, centre) >= margin * float(width.min()):
            return float(depth)
    return float(deepest)


# ----------------------------------------------------------------------------------------------- passes
def _clip(bodies: dict[str, _Body], walls: list[Wall], clearance: float) -> dict[str, _Body]:
    """Trim every mesh behind the room's walls (keep ``normal . x >= offset + clearance``)."""
    out = {}
    for name, body in bodies.items():
        for wall in walls:
            if not np.any(-wall.depth(body.world()[0]) < clearance):
                continue
            body = body.cut(np.asarray(wall.normal, float), wall.offset + clearance, "clip:wall")
        out[name] = body
    return out


def _hits_below(body: _Body, support: tuple[np.ndarray, np.ndarray], band: float) -> np.ndarray:
    """[K, 3] first points of ``support`` below the body's lowest points (within ``band`` of its bottom), hit
    by rays cast straight down."""
    points = body.world()[0]
    bottom = float(points[:, 2].min())
    low = points[points[:, 2] <= bottom + band]
    origins = low.copy()
    origins[:, 2] = min(float(points[:, 2].max()), bottom + band + 0.02)  # below a board above the body
    return _first_hits_down(support, origins)[0]


_RAY_TARGETS: dict[bytes, object] = {}


def _ray_target(mesh: tuple[np.ndarray, np.ndarray]):  # noqa: ANN202 - a trimesh RayMeshIntersector
    """A ray intersector of ``mesh``, the same one for the same points and faces (by content: a body's world mesh
    is computed anew at each call): its triangle tree is built once, not at each of the set-up's ray casts (some
    2400 on bench_00, whose set-up spent 22 s of its 264 building triangle trees). The last 16 are kept."""
    from trimesh.ray.ray_triangle import RayMeshIntersector

    points, faces = np.ascontiguousarray(mesh[0], np.float64), np.ascontiguousarray(mesh[1], np.int64)
    return _by_content(_RAY_TARGETS, points, faces, lambda: RayMeshIntersector(queryable((points, faces))), 16)


def _first_hits_down(mesh: tuple[np.ndarray, np.ndarray], origins: np.ndarray,
                     up: bool = False) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """([K, 3] first points of ``mesh`` (world) hit by rays cast straight down (``up``: up) from ``origins``, [K]
    the index of the ray each came from)."""
    hits, rays, _ = _ray_target(mesh).intersects_location(
        origins, np.tile([0.0, 0.0, 1.0 if up else -1.0], (len(origins), 1)), multiple_hits=False)  # fmt: skip
    return np.asarray(hits, float).reshape(-1, 3), np.asarray(rays, int)


def _support_height(body: _Body, support: tuple[np.ndarray, np.ndarray] | float, band: float) -> float | None:
    """Height of the support's surface under the body: its highest point under the body's lowest points (the
    floor's height for a floor); None when nothing is hit."""
    if isinstance(support, float):
        return support
    hits = _hits_below(body, support, band)
    return float(hits[:, 2].max()) if len(hits) else None


def _rest(bodies: dict[str, _Body], relations: Relations, room: tuple[np.ndarray, np.ndarray] | float | None,
          config: PhysicsSetupConfig) -> dict[str, _Body]:  # fmt: skip
    """Set every object onto its support, parents first (see the module docstring, pass 3). ``room``: the
    floor's height (slab colliders), the room's world mesh, or None (objects on the room stay as they are).
    A support's shape is settled (:func:`_shaped`) before its children are set onto it."""
    out = dict(bodies)
    flattened: set[str] = set()
    up = np.array([0.0, 0.0, 1.0])
    band = config.relations.bottom_band
    for name in relations.breadth_first():
        if name not in out:
            continue
        parent = relations.support.get(name, BACKGROUND)
        support_parts: list[tuple[np.ndarray, np.ndarray]] = []
        if parent != BACKGROUND and parent in out:  # the support's top, flat where its children rest on it
            if parent not in flattened:  # once, before any of its children is set on it
                flattened.add(parent)
                out[parent] = _flatten_top(out[parent], [out[c] for c in relations.children(parent) if c in out],
                                           config)  # fmt: skip
            # its children are set onto its collider next: it keeps out of them (where the fit left them) and
            # of what stands around it
            out[parent] = _shaped(out[parent], config, _around(parent, out), config.support_keep_out_parts)
            support_parts = [(out[parent].pose.apply(p.points), p.faces) for p in out[parent].collider[1]]
        body = out[name]
        surface = room if parent == BACKGROUND else (out[parent].world() if parent in out else None)
        if surface is None:
            continue
        # the support's parts as one mesh: the highest first hit over them all is the highest over each, and one
        # ray target is built for them, not one per part (bench_00 (phone): 2471 casts at 94 parts' targets,
        # rebuilt for every child as more parts than the targets kept came in turn)
        parts = _concatenated(support_parts) if support_parts else None
        heights = [_support_height(body, surface, band), _support_height(body, parts, band) if parts else None]
        heights = [h for h in heights if h is not None]
        if parent != BACKGROUND:  # a top that runs through it, above what its lowest points found (a keel)
            sunk = _sunk_height(body, surface, band)
            if sunk is not None and sunk > max(heights, default=-np.inf) + band:
                heights.append(sunk)
        if not heights:  # nothing under it (over a hole the fit left): it stays, out of its support's solid
            if support_parts:
                out[name] = _out_of_support(body, support_parts, out[parent].world(), config)
            continue
        height = max(heights)  # on the support's mesh, and on its collider where that stands higher
        points = body.world()[0]
        bottom = float(points[:, 2].min())
        if support_parts:
            # the flat top under the whole footprint, where the child's lowest points hang over a lower edge
            # (hard/thin's book overhung the table's bevelled edge: it dipped 3 mm below the top cut flat under
            # the rest of it, its base was cut there, and its hull overlapped the top and pushed it off)
            start = bottom + 2 * config.top_depth
            top = max(_top_under(body, surface, start, band), _top_under(body, parts, start, band))
            if height < top <= height + config.top_depth:
                height = top
        base = height + config.clearance
        depth = _base_depth(body.world(), config.base_depth, config.base_margin)
        drop = (base - depth) - bottom  # < 0: move down so that the underside is cut `depth` deep
        step = 0.0
        if drop < 0:
            moved = float(np.linalg.norm(np.asarray(body.pose.translation, float)
                                         - np.asarray(body.fit_pose.translation, float)))  # fmt: skip
            allowed = max(0.0, config.max_shift - moved)  # with its parent's moves, at most max_shift in all
            # the whole move, or as much of it as allowed when that still brings the object onto its support (its
            # base then cut less deep); an object that cannot reach its support stays where it was seen
            step = min(-drop, allowed) if bottom - base <= allowed else 0.0
            if step > 0:
                shift = np.array([0.0, 0.0, -step])
                for other in [name, *_descendants(relations, name)]:
                    if other in out:
                        out[other] = replace(out[other].moved(shift), edits=(*out[other].edits, "shift"))
                body = out[name]
        if -drop > step:  # the rest is refused: the base is cut less deep (or the object floats)
            body = replace(body, refused=float(-drop - step))
        unextended = body.cut(up, base, "cut:base")
        body = unextended
        cell = body.sdf.voxel_size if body.sdf is not None else 0.0  # what the fit could not resolve
        if cell > 0 and float(out[name].world()[0][:, 2].min()) - base <= min(config.max_extend, cell):
            # on its support but for a cell or less: feet the fit ended short are carried down onto it
            extended = _extend_down(replace(out[name], refused=0.0), base - depth, min(config.max_extend, cell),
                                    surface=base)  # fmt: skip
            if extended is not None:
                body = extended.cut(up, base, "cut:base")
                if not _closed(_drop_degenerate(body.mesh)):  # the base cut left what cannot be mended: as seen
                    body = unextended
        if support_parts:
            body = _out_of_support(body, support_parts, out[parent].world(), config)
        out[name] = body
    return out


def _out_of_support(body: _Body, support_parts: list[tuple[np.ndarray, np.ndarray]],
                    support: tuple[np.ndarray, np.ndarray], config: PhysicsSetupConfig) -> _Body:  # fmt: skip
    """The child without what of its support's collider (``support_parts``, world) still lies inside it, and
    without what of the support's mesh (``support``, world) does: a sliver of it the decomposition dropped (under
    1e-4 of its volume) is no part of the collider (the phone demo's shelf kept 2.8 cm^3 of a fitted lump in its
    bottle's back, 5 cm deep). Also for a child with nothing under it (the phone capture of bench_02: a box over a
    hole the fit left in its shelf's board kept a part 2.2 cm deep in one of the board's, was thrown at the first
    step and knocked the table beside over)."""
    body = body.minus_convex(support_parts, "cut:parent")
    return body.minus_mesh(support, "cut:parent:mesh", min_keep=1.0 - config.max_separation_loss,
                           min_volume=config.min_overlap)  # fmt: skip


def _extend_down(body: _Body, target: float, reach: float, surface: float | None = None) -> _Body | None:
    """The body with each of its feet carried straight down to height ``target`` (world), in its mesh and SDF.

    Feet are the pieces of the solid lying less than ``reach`` above its lowest point, or above ``surface`` (the
    support's) where that lies higher: the ends of legs the fit ended at different heights, some sunk into the
    floor and some short of it (hard/stack's table stood on two legs, the other two 1.7 cm up, and rocked), a
    base. Each whose bottom lies above ``target`` gets the convex hull of itself and its shadow at ``target``
    united with the mesh. None when nothing is to be carried down or the mesh is not a closed manifold."""
    from scipy.spatial import ConvexHull, QhullError

    from holousd.geometry._contact import _mesh, _solid

    world = _solid(body.world())
    if world is None:
        return None
    bottom = max(float(body.world()[0][:, 2].min()), -np.inf if surface is None else surface)
    near = world.trim_by_plane((0.0, 0.0, -1.0), -(bottom + reach))  # keeps z <= bottom + reach
    inverse = np.linalg.inv(body.pose.matrix())
    parts, longest = [], 0.0
    for foot in near.decompose():
        q = _mesh(foot)[0]
        lowest = float(q[:, 2].min())
        if lowest <= target + 1e-4 or foot.volume() <= 0:
            continue
        shadow = q.copy()
        shadow[:, 2] = target
        prism = np.concatenate([q, shadow]) @ inverse[:3, :3].T + inverse[:3, 3]  # object coordinates
        try:
            hull = ConvexHull(prism)
        except (QhullError, ValueError):
            continue
        faces = hull.simplices.copy()
        centre = prism[hull.vertices].mean(0)
        normal = np.cross(prism[faces[:, 1]] - prism[faces[:, 0]], prism[faces[:, 2]] - prism[faces[:, 0]])
        flip = np.einsum("ij,ij->i", normal, prism[faces[:, 0]] - centre) < 0
        faces[flip] = faces[flip][:, ::-1]
        parts.append((prism, faces))
        longest = max(longest, lowest - target)
    feet = [p for p in parts if _solid(p) is not None]
    united = _united(body.mesh, feet)
    if united is None:  # slivers it could not mend: as seen
        return None
    return body.plus_convex(parts, united, f"extend:base:{len(feet)}x{100 * longest:.1f}cm")


def _united(mesh: MeshData, parts: list[tuple[np.ndarray, np.ndarray]]) -> MeshData | None:
    """The union of a closed mesh and convex ``parts`` (the same coordinates), without zero-area faces; None
    when the mesh or every part is no closed solid, or the union comes out empty or open."""
    import manifold3d

    from holousd.geometry._contact import _mesh, _solid

    solid = _solid((mesh.points, mesh.faces))
    solids = [s for s in (_solid(p) for p in parts) if s is not None]
    if solid is None or not solids:
        return None
    union = manifold3d.Manifold.batch_boolean([solid, *solids], manifold3d.OpType.Add)
    if union.is_empty():
        return None
    points, faces = without_zero_area_faces(_mesh(union))
    out = MeshData(points=points, faces=faces)
    return out if _closed(out) else None


def _local_plane(pose: Pose, normal: np.ndarray, offset: float) -> tuple[tuple[float, float, float], float]:
    """The world plane ``normal . x = offset`` in the object coordinates of ``pose``."""
    rotation = pose.matrix()[:3, :3]
    return tuple(float(v) for v in rotation.T @ normal), float(offset - normal @ np.asarray(pose.translation, float))


def _box(lo: Sequence[float], hi: Sequence[float]) -> np.ndarray:
    """[8, 3] corners of the axis-aligned box from ``lo`` to ``hi`` (x slowest, z fastest)."""
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], np.float64)


def _flatten_top(parent: _Body, children: list[_Body], config: PhysicsSetupConfig) -> _Body:
    """Cut a support's surface flat under each child resting on it: what of the support stands above the
    lowest point of its surface under the child (at most ``top_depth`` below the highest point there that comes
    within ``bottom_band`` of the child's underside, and no deeper than the child can follow), inside the
    child's footprint (1 cm wider) up to ``top_depth`` above it, and under the child's outline up to ``2 *
    top_depth`` above the child's bottom (above the flat surface, for a child sunk below it), is cut away from the
    support's mesh and SDF (``cut:top``, ``cut:under``); the dents under the footprint below that surface are
    filled up to it, or where the support is open under the child, the surface carried over the opening
    (:func:`_filled_up_to`). A fitted top is a bumpy dome of facets, on which a child's flat base would rock; a
    wall or rim beside the child and a board above it stay (but for what of them lies within 1 cm of the
    footprint, up to ``top_depth`` above its surface)."""
    from scipy.spatial import ConvexHull, QhullError

    from holousd.physics import convex_hull

    if not children:
        return parent
    body = parent
    for child in children:
        hits = _hits_below(child, body.world(), config.relations.bottom_band)
        if len(hits) == 0:
            continue
        bottom = float(child.world()[0][:, 2].min())
        # the support's surface under the child's edge, where the child's underside rides up over a bump (its
        # bottom band does not reach there), is the child's too: cut flat with the rest, up to twice top_depth
        # above the child's bottom
        start = bottom + 2 * config.top_depth
        highest = max(float(hits[:, 2].max()), _top_under(child, body.world(), start, config.relations.bottom_band))
        # the lowest of the surface under the child (robust to a stray dent), no deeper than the child can follow
        # (half the largest move: its own base cut takes the rest)
        plane = max(float(np.percentile(hits[:, 2], 10)), highest - config.top_depth, bottom - config.max_shift / 2)
        c = child.world()[0]
        # no lower than the surface seen around the child, where that lies above the plane and no higher than the
        # child's underside over most of its outline (its median): the top under a child is hidden by it, and a fit
        # leaves it dented there as often as domed (bench_02's box was fitted 1.2 cm low under the mug on it; the top
        # was cut flat in the dent, the mug's front, fitted down into it, became its base with the centre of mass 2 cm
        # outside, and it tipped); a child standing in a recess, lower than the rim around it, stays on its floor
        underside = _underside(child, _outline_grid(c))
        underside = underside[np.isfinite(underside)]
        if len(underside):
            # up to the child's underside: a child fitted with a keel under a base resting on the top seen
            # around it (bench_05's mug, default preset: its keel 1.5 cm under its base, the surface seen around
            # 1.8 cm over the keel's bottom) stands on that surface, not on the keel's bottom
            level = float(np.median(underside)) + config.clearance
            around = _level_around(c, body.world(), plane, config.top_depth, upto=level)
            if plane < around <= level:
                plane = around
        lo = np.array([*(c[:, :2].min(axis=0) - 0.01), plane])
        # bumps in the footprint's corners up to top_depth above the flat surface go with it (a hull spanning
        # one and the flat surface bridged demo's bowl base 1.6 cm up); a wall beside keeps what stands higher
        hi = np.array([*(c[:, :2].max(axis=0) + 0.01), max(highest, plane + config.top_depth) + 1e-3])
        cut = body.minus_convex([convex_hull(_box(lo, hi))], f"cut:top:{child.name}")
        # under the child's outline, up to where the flat top is looked for: hidden under the child (demo's bowl
        # had a lump of the shelf's fitted back 3 cm up under its rim; it rested against it and tipped)
        # a child fitted down through the top (a keel) is cut at the flat surface: what of the support stands
        # over that inside its outline, up to as high (at most its top), is the child's space too (a phone
        # capture's table was fitted with a 2 cm plateau under a book whose keel ran through the top; the book
        # was then cut on the plateau, 2 cm up, and kept a 1 cm sliver of itself)
        under = max(start, min(plane + 2 * config.top_depth, float(c[:, 2].max())))
        try:  # (a child sunk 3 cm into its support and thinner than that has nothing hidden under it)
            outline = c[:, :2][ConvexHull(c[:, :2]).vertices] if under - plane > 1e-3 else None
        except (QhullError, ValueError):  # a degenerate child: no outline to cut under
            outline = None
        if outline is not None:
            column = np.concatenate([np.column_stack([outline, np.full(len(outline), z)]) for z in (plane, under)])
            cut = cut.minus_convex([convex_hull(column)], f"cut:under:{child.name}")
        # dents are filled under the child's own footprint, not the 1 cm beyond: that can be a neighbour's, cut
        # flat lower (the phone demo's table: a box's fill stood 1.5 cm up under the edge of the book beside it,
        # which then rested on that ridge and tipped 5 degrees)
        inner = (np.array([*c[:, :2].min(axis=0), plane]), np.array([*c[:, :2].max(axis=0), hi[2]]))
        cut = _filled_up_to(cut, *inner, config.top_depth, f"fill:top:{child.name}")
        if cut is not body:  # flat at `plane` there now: the collider's decomposition cuts along it
            axes = np.eye(3)
            sides = tuple(_local_plane(cut.pose, sign * axes[k], sign * bound[k])
                          for k in (0, 1) for sign, bound in ((1, hi), (-1, lo)))  # fmt: skip
            body = replace(cut, planes=(*cut.planes, (*_local_plane(cut.pose, axes[2], plane), sides)))
    return body


def _level_around(points: np.ndarray, support: tuple[np.ndarray, np.ndarray], plane: float, depth: float,
                  spacing: float = 0.01, share: float = 0.25, upto: float = -np.inf) -> float:
    """The height of ``support``'s surface (a world mesh) seen around a child (its world ``points``), near
    ``plane``: the median of the first hits of rays cast down on two rectangles 1.5 and 2.5 cm outside the
    child's footprint, every ``spacing``, of those that land within ``depth`` of it (or between it and ``upto``),
    when at least ``share`` of the rays do (past the support's edge or on a wall they do not); -inf else."""
    lo, hi = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    rings = []
    for out in (0.015, 0.025):
        a, b = lo - out, hi + out
        nx, ny = (max(2, int(np.ceil((b[k] - a[k]) / spacing)) + 1) for k in (0, 1))
        xs, ys = np.linspace(a[0], b[0], nx), np.linspace(a[1], b[1], ny)
        rings += [np.column_stack([xs, np.full(nx, y)]) for y in (a[1], b[1])]
        rings += [np.column_stack([np.full(ny - 2, x), ys[1:-1]]) for x in (a[0], b[0])]
    ring = np.concatenate(rings)
    top = max(plane + depth, upto)
    hits, _ = _first_hits_down(support, np.column_stack([ring, np.full(len(ring), top + 0.01)]))
    level = hits[(hits[:, 2] >= plane - depth) & (hits[:, 2] <= top), 2] if len(hits) else np.zeros(0)
    return float(np.median(level)) if len(level) >= share * len(ring) else -np.inf


def _concatenated(meshes: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Meshes ``(points, faces)`` as one (a collider's parts, for ray casts)."""
    offsets = np.cumsum([0, *(len(p) for p, _ in meshes[:-1])])
    return (np.concatenate([np.asarray(p, float) for p, _ in meshes]),
            np.concatenate([np.asarray(f, np.int64) + o for (_, f), o in zip(meshes, offsets, strict=True)]))


def _top_under(child: _Body, support: tuple[np.ndarray, np.ndarray], start: float, gap: float) -> float:
    """The highest point of the surface of ``support`` (a world mesh) straight under ``child``'s footprint (its
    outline seen from above) and at most ``gap`` below the child's underside there, hit by rays cast down from
    height ``start``; -inf when none is hit. What of the support lies further below the child's underside, under a
    bowl's rim that curves up from its base, holds nothing up (demo's bowl: a lump of the shelf's fitted back 3 cm
    up under its rim set the flat top, and then the bowl, on a ledge 1.6 cm above the board; it tipped)."""
    c = child.world()[0]
    grid = _outline_grid(c)
    if len(grid) == 0:
        return -np.inf
    hits, rays = _first_hits_down(support, np.column_stack([grid, np.full(len(grid), start)]))
    if len(hits) == 0:
        return -np.inf
    underside = _underside(child, grid)
    near = hits[:, 2] >= underside[rays] - gap
    return float(hits[near, 2].max()) if near.any() else -np.inf


def _outline_grid(points: np.ndarray) -> np.ndarray:
    """[G, 2] a 9 x 9 grid over the points' footprint, those inside its outline (not a round base's corners)."""
    from scipy.spatial import ConvexHull, QhullError

    lo, hi = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    xs, ys = np.meshgrid(np.linspace(lo[0], hi[0], 11)[1:-1], np.linspace(lo[1], hi[1], 11)[1:-1])
    grid = np.column_stack([xs.ravel(), ys.ravel()])
    try:  # its convex hull's edge lines, n . x + d <= 0 inside
        edges = ConvexHull(points[:, :2]).equations  # (a Delaunay point location took seconds on a cut mesh's points)
    except QhullError:
        return np.zeros((0, 2))
    return grid[np.all(grid @ edges[:, :2].T + edges[:, 2] <= 1e-12, axis=1)]


def _underside(child: _Body, grid: np.ndarray) -> np.ndarray:
    """[G] height of the child's underside over each grid point (inf where nothing of it is above)."""
    c = child.world()[0]
    below = np.column_stack([grid, np.full(len(grid), c[:, 2].min() - 1.0)])
    under, up_rays = _first_hits_down((c, child.mesh.faces), below, up=True)
    underside = np.full(len(grid), np.inf)
    underside[up_rays] = under[:, 2]
    return underside


def _sunk_height(child: _Body, support: tuple[np.ndarray, np.ndarray], sink: float) -> float | None:
    """Height of the support's top where the child's mesh runs down through it: the median of the support's
    surface hit by rays cast down from the child's top over its outline, where that lies inside the child (over
    ``sink`` above its underside there, below its top by more than a quarter of its height); None when fewer
    than two rays find it so. A phone capture's box on a table had a keel fitted 11 cm down through the top, out
    under it between the legs: no ray from its lowest points found the table, its base was never cut, and it
    stood 6 cm deep in the table's mesh (a bottom a few centimetres into the top has its lowest points' rays meet
    the top's underside instead)."""
    c = child.world()[0]
    bottom, top = float(c[:, 2].min()), float(c[:, 2].max())
    grid = _outline_grid(c)
    if len(grid) == 0:
        return None
    hits, rays = _first_hits_down(support, np.column_stack([grid, np.full(len(grid), top - 1e-4)]))
    if len(hits) == 0:
        return None
    underside = _underside(child, grid)[rays]
    ceiling = top - max(sink, 0.25 * (top - bottom))
    sunk = (hits[:, 2] > underside + sink) & (hits[:, 2] <= ceiling)
    return float(np.median(hits[sunk, 2])) if sunk.sum() >= 2 else None


def _filled_up_to(body: _Body, lo: np.ndarray, hi: np.ndarray, depth: float, edit: str) -> _Body:
    """The body with the dents of its surface inside the box ``lo``-``hi`` (world; ``lo[2]`` the flat surface's
    height) filled up to that surface, in its mesh and SDF: what rests there is seen from above and beside,
    never under it, and a convex part of the support spans those dents at the surface's height anyway. Where
    rays down the box fall through the support or hit deeper than ``depth`` below the surface, the surface is
    carried over that hole instead, within the support's top around it (:func:`_spanned`)."""

    from holousd.physics import convex_hull

    plane = float(lo[2])
    xs, ys = np.meshgrid(np.linspace(lo[0] + 1e-3, hi[0] - 1e-3, 9), np.linspace(lo[1] + 1e-3, hi[1] - 1e-3, 9))
    origins = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, plane + 0.01)])
    hits, rays = _first_hits_down(body.world(), origins)
    if len(rays) < len(origins) or hits[:, 2].min() < plane - depth:  # over a hole, past an edge or a step
        return _spanned(body, lo, hi, depth, edit)
    deepest = float(hits[:, 2].min())
    if plane - deepest < 5e-4:
        return body
    inverse = np.linalg.inv(body.pose.matrix())
    corners = _box((*lo[:2], deepest - 1e-3), (*hi[:2], plane))
    part = convex_hull(corners @ inverse[:3, :3].T + inverse[:3, 3])
    united = _united(body.mesh, [part])
    return body if united is None else body.plus_convex([part], united, edit)


def _spanned(body: _Body, lo: np.ndarray, hi: np.ndarray, depth: float, edit: str) -> _Body:
    """The body with its flat surface at height ``lo[2]`` (world) carried over what is missing of it inside the
    box ``lo``-``hi`` (a child's footprint), in its mesh and SDF: a slab ``depth`` thick (no lower than 1 mm above
    the body's bottom) over the box where it lies inside the rectangle, along the body's own axes, of its upward
    faces at that height (within ``depth`` of it: a board 3 mm above the flat top the child's base cut allows),
    and inside its outline seen from above. That rectangle and outline are the whole support's: on a top that is
    not convex (an L-shaped desk, a sink cut-out) a gap under the child's footprint is bridged too.

    What rests on a support hides the support's top under it from every camera; a fit may leave it open there
    (hard/shelf's board was fitted as its seen front edge alone under a 20 cm box, which then rested on that edge
    and tipped back). The surface is carried only within its own extent: a child overhanging a table's edge, or
    a support's end, still overhangs it, and a step down stays a step."""
    import manifold3d

    from holousd.geometry._contact import _mesh, _solid

    plane = float(lo[2])
    world = body.world()[0]
    bottom = float(world[:, 2].min())
    floor = max(plane - depth, bottom + 1e-3)
    if plane - floor < 1e-3:
        return body
    faces = body.mesh.faces
    tri = world[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    height = tri[:, :, 2].mean(axis=1)
    level = (normal[:, 2] > 0.9 * np.linalg.norm(normal, axis=1)) & (np.abs(height - plane) <= depth)
    if not level.any():
        return body
    local = np.asarray(body.mesh.points, float)
    top = local[np.unique(faces[level])]  # object coordinates: the axes the fit squared the object to
    z_lo, z_hi = float(local[:, 2].min()) - 1.0, float(local[:, 2].max()) + 1.0
    inverse = np.linalg.inv(body.pose.matrix())
    box = _box((*lo[:2], floor), (*hi[:2], plane))
    rect = _box((*top[:, :2].min(axis=0), z_lo), (*top[:, :2].max(axis=0), z_hi))
    outline = np.concatenate([np.column_stack([local[:, :2], np.full(len(local), z)]) for z in (z_lo, z_hi)])
    hull = manifold3d.Manifold.hull_points
    slab = (hull(np.ascontiguousarray(box @ inverse[:3, :3].T + inverse[:3, 3])) ^ hull(rect)
            ^ hull(np.ascontiguousarray(outline)))  # fmt: skip
    if slab.is_empty() or slab.volume() < 1e-7:  # under 0.1 cm^3
        return body
    part = _mesh(slab)
    if _solid(part) is None:
        return body
    united = _united(body.mesh, [part])
    if united is None:
        return body
    before, after = _solid((local, faces)), _solid((united.points, united.faces))
    if before is None or after is None or after.volume() - before.volume() < 1e-7:  # nothing was missing
        return body
    return body.plus_convex([part], united, edit.replace("fill:", "span:", 1))


def _separate(bodies: dict[str, _Body], relations: Relations, config: PhysicsSetupConfig) -> dict[str, _Body]:
    """Cut apart neighbours (not parent and child) whose meshes overlap, at the middle of the overlap across
    its thinnest axis, within the overlap's bounds (1 cm wider); each keeps its own side. Where they still overlap
    after that (both centres on one side of the middle: a box fitted down through a shelf's bottom board, both
    kept the side above it), the other's mesh is taken out of the one whose mesh loses the smaller share of its
    volume and stays whole (:func:`_taken_apart`)."""
    import manifold3d

    from holousd.geometry._contact import _mesh

    out = dict(bodies)
    names = sorted(out)
    family = {n: {relations.support.get(n)} | set(relations.children(n)) for n in names}
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if b in family[a]:
                continue
            both = overlap(out[a].world(), out[b].world())
            if both.volume_m3 < config.min_overlap and both.depth_m <= config.clearance:
                continue
            direction = both.thin_axis if both.thin_axis is not None else np.eye(3)[int(np.argmin(both.hi - both.lo))]
            mid = float(direction @ (both.lo + both.hi) / 2)
            box = manifold3d.Manifold.hull_points(_box(both.lo - 0.01, both.hi + 0.01))
            for name, other in ((a, b), (b, a)):
                centre = mass_properties(out[name].world(), 1.0).center_of_mass
                side = 1.0 if float(direction @ centre) >= mid else -1.0
                # what of the overlap's bounds lies on the other's side: a plane through the whole object took
                # bench_04's table top from under the box on it, to free a chair's leg from the table's
                beyond = box.trim_by_plane(tuple(-side * direction), -(side * mid + config.clearance / 2))
                if beyond.is_empty():
                    continue
                out[name] = out[name].minus_convex([_mesh(beyond)], f"cut:neighbour:{other}",
                                                   min_keep=1.0 - config.max_separation_loss)  # fmt: skip
            left = overlap(out[a].world(), out[b].world())
            if left.volume_m3 >= config.min_overlap or left.depth_m > config.clearance:
                out[a], out[b] = _taken_apart(out[a], out[b], config)
    return out


def _taken_apart(a: _Body, b: _Body, config: PhysicsSetupConfig) -> tuple[_Body, _Body]:
    """``a`` and ``b`` with the other's mesh taken out of the one whose mesh loses the smaller share of its
    volume and stays closed and whole (``max_separation_loss`` at most); both unchanged when neither can. The
    phone capture of hard/shelf: its box fitted down through the shelf's bottom board to the floor, both centres
    above the board's middle, each kept the side above it, and a 3 cm^3 lump of the board stayed 4 cm deep in the
    box; the shelf and everything on it were thrown."""
    options = []
    for which, (body, other) in enumerate(((a, b), (b, a))):
        solid = _solid((body.mesh.points, body.mesh.faces))
        cut = body.minus_mesh(other.world(), f"cut:neighbour:{other.name}", min_keep=1.0 - config.max_separation_loss)
        after = _solid((cut.mesh.points, cut.mesh.faces)) if cut is not body else None
        if solid is not None and after is not None and solid.volume() > 0:
            options.append((1.0 - after.volume() / solid.volume(), which, cut))
    if not options:
        return a, b
    _, which, cut = min(options, key=lambda o: o[:2])
    return (cut, b) if which == 0 else (a, cut)


def _decompose(mesh: MeshData, config: PhysicsSetupConfig, planes: tuple = (), keep_out: tuple = (),
               extra_parts: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:  # fmt: skip
    """Convex decomposition of ``mesh``: plane cuts (``decomposition='planes'``, first along ``planes``) or
    CoACD."""
    from holousd.physics import DecompositionConfig, convex_decomposition

    if config.decomposition == "planes":
        found = plane_decomposition((mesh.points, mesh.faces), tolerance=config.hull_tolerance,
                                    max_parts=config.max_parts,
                                    cuts=[(np.asarray(n), o, [(np.asarray(m), q) for m, q in sides])
                                          for n, o, sides in planes],
                                    keep_out=list(keep_out), keep_out_parts=extra_parts,
                                    max_reach=config.max_reach, reach_parts=config.reach_parts)  # fmt: skip
        return found.parts if found is not None else []
    cfg = DecompositionConfig(max_parts=config.max_parts, seed=config.seed)
    if config.decomposition_iterations is not None:  # quick settings: coarse concavity metric, shallow search
        cfg = DecompositionConfig(max_parts=config.max_parts, seed=config.seed, threshold=0.1,
                                  preprocess_resolution=20, resolution=300, mcts_nodes=8, mcts_max_depth=1,
                                  mcts_iterations=config.decomposition_iterations)  # fmt: skip
    return convex_decomposition(mesh.points, mesh.faces, cfg)


def _intrusion(part: tuple[np.ndarray, np.ndarray], mesh: MeshData, keep_out: tuple) -> float:
    """Volume of ``part`` inside the ``keep_out`` meshes beyond the mesh's own overlap with them, m^3."""
    own = (mesh.points, mesh.faces)
    return sum(max(0.0, overlap(part, k).volume_m3 - overlap(own, k).volume_m3) for k in keep_out)


def _collider(mesh: MeshData, config: PhysicsSetupConfig, planes: tuple = (), keep_out: tuple = (),
              extra_parts: int = 0) -> tuple[str, list[MeshData], float]:  # fmt: skip
    """The hull of the mesh when it stays within ``hull_tolerance`` of it (or within ``convexify``: the mesh then
    becomes its hull) and enters none of the ``keep_out`` meshes (its neighbours and support, the mesh's frame);
    where it does enter one, that hull cut clear of them by planes that cut at most ``convexify`` into the mesh
    (kind ``"cleared"``: the mesh becomes it, see :func:`_cleared_hull`); else a decomposition of the mesh; with
    the chosen collider's reach outside the mesh (the uncut hull's for ``"cleared"``), metres."""
    from holousd.physics import convex_hull

    hull = convex_hull(mesh.points, mesh.faces)
    reach = collider_reach([hull], (mesh.points, mesh.faces), seed=config.seed)
    if reach <= max(config.hull_tolerance, config.convexify):
        if _intrusion(hull, mesh, keep_out) <= 1e-8:
            return "hull", [MeshData(points=hull[0], faces=hull[1])], reach
        surfaces = [(np.asarray(n, float), float(o)) for n, o, _ in planes]
        cleared = _cleared_hull(hull, mesh, keep_out, config.convexify, config.clearance, surfaces)
        if cleared is not None:
            return "cleared", [MeshData(points=cleared[0], faces=cleared[1])], reach
    parts = _decompose(mesh, config, planes, keep_out, extra_parts)
    part_reach = collider_reach(parts, (mesh.points, mesh.faces), seed=config.seed) if parts else np.inf
    if part_reach >= reach:  # the decomposition does not follow the mesh better: the simpler collider
        return "hull", [MeshData(points=hull[0], faces=hull[1])], reach
    return "decomposition", [MeshData(points=p, faces=f) for p, f in parts], part_reach


def _cleared_hull(hull: tuple[np.ndarray, np.ndarray], mesh: MeshData, keep_out: tuple, deepest: float,
                  gap: float, surfaces: Sequence[tuple[np.ndarray, float]] = (), max_planes: int = 6,
                  max_candidates: int = 64, max_loss: float = 0.25, max_tilt: float = 0.1,
                  ) -> tuple[np.ndarray, np.ndarray] | None:  # fmt: skip
    """``hull`` (of ``mesh``) cut by planes until it enters none of the ``keep_out`` meshes (beyond the mesh's own
    overlap with them), or None when that takes more than ``max_planes`` planes, a plane that cuts more than
    ``deepest`` into the mesh, or more than ``max_loss`` of its volume in all. Each plane separates the hull from
    one mesh it enters: one of the mesh's flat ``surfaces`` (``normal . x = offset``, object coordinates: where its
    top was cut flat under what rests on it) that has that mesh on its far side, else ``gap`` short of that mesh:
    for a mesh resting on its top (its bottom at most ``deepest`` under the top), the level plane; for one beside
    it, one of the upright separating directions (``|n_z| <= max_tilt``) of two convex solids (the hull's face
    normals, the other's reversed, the axes); of those, of the ``max_candidates`` that cut least deep, the one that
    takes the least volume off the mesh. A plane against what rests on the top cuts nothing under the others
    resting there (a sibling on a higher step keeps its step); a tilted plane bridging such a step, chosen as the
    cheapest, had tilted the whole top a degree. A
    lumpy convex object under or beside another (a book fitted thick, its cover standing 6-10 mm over the patch cut
    flat under the mug on it; a box beside its neighbour) keeps one convex part flush with its neighbours rather
    than a decomposition of its lumps: hard/stack's book of 34 such parts slid 4 cm in MuJoCo under its mug and
    both fell, where its one hull stood."""
    from scipy.spatial import ConvexHull, QhullError

    points = np.asarray(mesh.points, float)
    solid = _solid((mesh.points, mesh.faces))
    if solid is None:
        return None
    volume = solid.volume()
    flat = [(np.asarray(n, float) / np.linalg.norm(n), float(o) / np.linalg.norm(n)) for n, o in surfaces]
    top = float(points[:, 2].max())
    resting = [(k, np.asarray(k[0], float)) for k in keep_out if float(np.asarray(k[0])[:, 2].min()) >= top - deepest]
    own = [overlap((mesh.points, mesh.faces), k).volume_m3 for k in keep_out]  # the mesh's: the planes keep it
    lost = 0.0  # volume the planes take off the mesh (each measured alone: an upper bound), m^3
    for planes in range(max_planes + 1):  # (as _intrusion, each mesh's own overlap measured once, not per plane)
        entered = next((k for k, v in zip(keep_out, own, strict=True) if overlap(hull, k).volume_m3 - v > 1e-8), None)
        if entered is None:
            return hull
        if planes == max_planes:
            return None
        other = np.asarray(entered[0], float)
        lo, hi = hull[0].min(axis=0) - deepest, hull[0].max(axis=0) + deepest
        near = other[np.all((other >= lo) & (other <= hi), axis=1)]  # a large non-convex neighbour: the part near
        near = near if len(near) >= 4 else other
        beyond = [(n, o) for n, o in flat if float((near @ n).min()) >= o]
        on_top = any(k is entered for k, _ in resting)
        if beyond:
            normals, offsets = np.array([n for n, _ in beyond]), np.array([o for _, o in beyond])
        elif on_top:  # resting on it, no surface cut flat under it: level, just under it (a tilt would tilt the top)
            normals, offsets = np.array([[0.0, 0.0, 1.0]]), np.array([float(near[:, 2].min()) - gap])
        else:  # beside it: upright planes only (a tilted one bridging a step would tilt the top too)
            directions = [_face_planes(hull)[0], np.eye(3), -np.eye(3)]
            try:
                directions.append(-ConvexHull(near).equations[:, :3])  # outward unit normals of the other's hull
            except (QhullError, ValueError):  # flat (a neighbour's face within reach): the hull's own and the axes
                pass
            normals = np.unique(np.round(np.concatenate(directions), 9), axis=0)
            normals = normals[np.abs(normals[:, 2]) <= max_tilt]
            offsets = (near @ normals.T).min(axis=0) - gap  # the other stays on the far side of n . x = offset
        depth = (points @ normals.T).max(axis=0) - offsets  # how deep into the mesh the plane cuts
        if on_top:  # no cut under what else rests on the top, where that stands higher (a sibling on a step)
            others = [points_of for k, points_of in resting if k is not entered]
            depth[~_spared(solid, normals, offsets, others)] = np.inf
        shallow = np.flatnonzero(depth <= deepest)
        if len(shallow) == 0:
            return None
        # the least volume off the mesh (the deepest cut alone would tilt a book's flat cover to spare a bump)
        shallow = shallow[np.argsort(depth[shallow], kind="stable")[:max_candidates]]
        removed = [0.0 if depth[i] <= 0 else volume - solid.trim_by_plane(
            tuple(-normals[i]), float(-offsets[i])).volume() for i in shallow]  # fmt: skip
        best = int(shallow[int(np.argmin(removed))])
        lost += min(removed)
        if lost > max_loss * volume:
            return None
        kept = cut_plane([hull], -normals[best], -offsets[best])
        if len(kept) != 1:
            return None
        hull = kept[0]
    return None


def _spared(solid, normals: np.ndarray, offsets: np.ndarray, resting: list[np.ndarray]) -> np.ndarray:  # noqa: ANN001
    """[P] for each plane ``normal . x = offset``, whether it leaves whole what of ``solid`` (a manifold) lies under
    each of the ``resting`` point sets (their footprints: x-y bounding boxes): nothing of it there past the plane."""
    ok = np.ones(len(normals), bool)
    for i, (n, o) in enumerate(zip(normals, offsets, strict=True)):
        past = solid.trim_by_plane(tuple(float(v) for v in n), float(o) + 1e-4)  # what the plane would take off
        for other in resting:
            if past.is_empty():
                break
            lo, hi = other[:, :2].min(axis=0), other[:, :2].max(axis=0)
            under = past
            for axis in (0, 1):
                for sign, bound in ((1.0, lo[axis]), (-1.0, hi[axis])):
                    normal = [0.0, 0.0, 0.0]
                    normal[axis] = sign
                    under = under.trim_by_plane(tuple(normal), sign * float(bound))
            if under.volume() > 1e-9:
                ok[i] = False
                break
    return ok


def _face_planes(mesh: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The planes ``normal . x = offset`` of a mesh's faces: [F, 3] unit normals (as wound) and [F] offsets,
    degenerate faces left out."""
    tri = np.asarray(mesh[0], float)[np.asarray(mesh[1], np.int64)]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normals, axis=1)
    keep = length > 1e-12
    normals = normals[keep] / length[keep, None]
    return normals, np.einsum("ij,ij->i", normals, tri[keep, 0])


def _shaped(body: _Body, config: PhysicsSetupConfig, keep_out: list[tuple[np.ndarray, np.ndarray]] | None = None,
            extra_parts: int = 0) -> _Body:  # fmt: skip
    """The body with its collider derived from its mesh (``body.collider``); when that is a hull or a
    decomposition reaching at most ``convexify`` outside the mesh, the mesh and SDF become the hull or the union of
    its parts (the collider then is the rendered solid). No part enters the ``keep_out`` meshes (world: what
    stands beside and under it) where a decomposition can avoid it, with ``extra_parts`` more parts for that. A
    body already shaped comes back as it is."""
    if body.collider is not None:
        return body
    body = replace(body, mesh=_drop_degenerate(body.mesh))  # the collider from the mesh as it will be authored
    inverse = np.linalg.inv(body.pose.matrix())
    local = tuple((p @ inverse[:3, :3].T + inverse[:3, 3], f) for p, f in keep_out or [])
    kind, parts, reach = _collider(body.mesh, config, body.planes, local, extra_parts)
    if kind == "cleared":  # the hull cut clear of its neighbours: it is the mesh too, what of the mesh lay past
        hull = parts[0]  # its planes (bumps, at most convexify deep) cut off
        return replace(body.as_convex(hull, f"convexify:cleared:{100 * reach:.1f}cm"), collider=("hull", parts, 0.0))
    if kind == "hull" and config.hull_tolerance < reach <= config.convexify:  # a lumpy convex object (a book,
        hull = parts[0]  # a ball fitted on coarse cells): its hull, one part, is both collider and mesh
        grown = body.plus_convex([(hull.points, hull.faces)], hull, f"convexify:hull:{100 * reach:.1f}cm")
        return replace(grown, collider=(kind, parts, 0.0))
    if kind == "decomposition" and reach > config.convexify:
        # what of the mesh no part covers (slivers the decomposition's cuts dropped) is cut from the mesh and SDF:
        # a simulator meets all of the rendered solid, and nothing rests inside a part of it that it does not see
        local = [(p.points, p.faces) for p in parts]
        trimmed = body.within_convex(local, "trim:uncovered")
        if trimmed is not body:
            trimmed = replace(trimmed, mesh=_drop_degenerate(trimmed.mesh))
            if _closed(trimmed.mesh):
                # a piece the trim dropped (joined to the rest by what no part covered: under 1% of the volume)
                # takes its parts with it: they would stand in empty space (the demo's shelf had three parts
                # 13 cm from its rendered mesh, in a compartment)
                mesh = (trimmed.mesh.points, trimmed.mesh.faces)
                parts = [p for p in parts if overlap((p.points, p.faces), mesh).volume_m3
                         > 0.01 * mass_properties((p.points, p.faces), 1.0).volume_m3]  # fmt: skip
                reach = collider_reach([(p.points, p.faces) for p in parts], mesh, seed=config.seed)
                return replace(trimmed, collider=(kind, parts, reach))
    if kind != "decomposition" or not 0.0 < reach <= config.convexify:
        return replace(body, collider=(kind, parts, reach))
    united = convexify((body.mesh.points, body.mesh.faces),
                       Decomposition(parts=[(p.points, p.faces) for p in parts], concavity_m=reach, excess_m3=0.0))
    if united is None:
        return replace(body, collider=(kind, parts, reach))
    united = without_zero_area_faces(united)  # a boolean union leaves slivers; the splat binding rejects them
    if not _closed(_drop_degenerate(MeshData(points=united[0], faces=united[1]))):  # as it would be authored
        return replace(body, collider=(kind, parts, reach))  # the union came out open: the mesh stays as seen
    if _intrusion(united, body.mesh, local) > 1e-8:  # the parts could not all keep out: the mesh stays as seen
        return replace(body, collider=(kind, parts, reach))
    left = collider_reach([(p.points, p.faces) for p in parts], united, seed=config.seed)
    if left > 1e-3:  # the boolean union lost a sliver of a part: the mesh stays as seen
        return replace(body, collider=(kind, parts, reach))
    grown = body.plus_convex([(p.points, p.faces) for p in parts], MeshData(points=united[0], faces=united[1]),
                             f"convexify:{100 * reach:.1f}cm")  # fmt: skip
    return replace(grown, collider=(kind, parts, left))


def _around(name: str, bodies: dict[str, _Body], margin: float = 0.01) -> list[tuple[np.ndarray, np.ndarray]]:
    """World meshes of what a body's collider must keep out of: every other body whose bounding box comes
    within ``margin`` of its own, as its collider's parts once it has one (they are what a simulator meets),
    else its mesh."""
    own = bodies[name].world()[0]
    lo, hi = own.min(0) - margin, own.max(0) + margin
    out = []
    for other in sorted(bodies):
        body = bodies[other]
        points = body.world()[0]
        if other == name or np.any(points.min(0) > hi) or np.any(points.max(0) < lo):
            continue
        if body.collider is None:
            out.append(body.world())
        else:
            out += [(body.pose.apply(p.points), p.faces) for p in body.collider[1]]
    return out


def _closed(mesh: MeshData) -> bool:
    import trimesh

    return bool(trimesh.Trimesh(mesh.points, mesh.faces, process=False).is_watertight)


def _drop_degenerate(mesh: MeshData) -> MeshData:
    """``mesh`` without its zero-area faces (the splat binding rejects them); ``mesh`` itself when removing them
    would open it (the demo's fitted table, closed, has two faces of 4e-13 m^2 whose removal left an edge
    unpaired: the open mesh got no decomposition, and its convex hull, 50 cm outside it, became its collider)."""
    found = _without_degenerate(mesh)
    if found is None:
        return mesh
    if _closed(mesh) and not _closed(found):
        from holousd.geometry._contact import _twice_area

        as_authored = np.asarray(mesh.points, np.float32).astype(np.float64)  # USD stores float32 points
        if _twice_area(as_authored, mesh.faces).min() >= 1e-14:  # what the splat binding accepts
            return mesh
    return found


def _penetration(name: str, bodies: dict[str, _Body], slabs: list[MeshData]) -> float:
    """Deepest overlap of a body's mesh with any other body's mesh or room slab, or of its collider with any
    other body's collider, metres."""
    own = bodies[name].world()
    depths = [overlap(own, other.world()).depth_m for key, other in bodies.items() if key != name]
    depths += [overlap(own, (s.points, s.faces)).depth_m for s in slabs]
    parts = _world_parts(bodies[name])
    for key, other in bodies.items():
        if key != name and _colliders_meet(bodies[name], other):
            others = _world_parts(other)
            depths += [overlap(p, q).depth_m for p in parts for q in others]
    return float(max(depths, default=0.0))


def _world_parts(body: _Body) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(body.pose.apply(p.points), p.faces) for p in body.collider[1]] if body.collider is not None else []


def _colliders_meet(a: _Body, b: _Body) -> bool:
    """The bounding boxes of two bodies' colliders meet (False while either has none)."""
    pa, pb = _world_parts(a), _world_parts(b)
    if not pa or not pb:
        return False
    a_points, b_points = np.concatenate([p for p, _ in pa]), np.concatenate([p for p, _ in pb])
    return not (np.any(a_points.min(0) > b_points.max(0)) or np.any(b_points.min(0) > a_points.max(0)))


def _unclasped(bodies: dict[str, _Body], config: PhysicsSetupConfig) -> dict[str, _Body]:
    """Colliders that still overlap, at most as deep as a collider may reach outside its mesh (``hull_tolerance``, or
    ``max_reach`` where that is more; at any depth where the two meshes overlap by less than ``min_overlap`` and the
    clip takes at most 1% of the clipped body's mesh), clipped apart: of each pair of overlapping convex parts, one
    is cut by a plane of the other's faces, 0.2 mm off it (a convex part cut by a plane stays convex), the one whose
    body's mesh loses least (:func:`_clipped_apart`). Such overlaps are hulls reaching past their meshes into a
    neighbour where its decomposition could not keep out; deeper ones, where the meshes overlap, are the mesh edits'
    business. Every overlapping pair of parts gets one try (a clip separates its pair for good; a pair no clip
    separates is left, and recorded as penetration), however many there are: two 50-part balls pressed together
    overlap in 46. Newton's XPBD resolves an overlap at the first step as a velocity: hard/touching_siblings' box kept a
    hull 1.1 mm into the book beside it, and the book was thrown 2 cm; on the phone capture of hard/shelf, a part of
    the box reaching 1.6 cm past its mesh overlapped a part of the shelf's bottom board 1.5 cm deep (their meshes
    apart), and the box was kicked 4 mm and 1.3 deg at the first step; on the phone capture of bench_02, a box over
    a hole in its shelf's board kept a part 2.03 cm into one of the board's (the board's mesh cut out of the box's),
    was thrown at the first step and knocked the table beside it over."""
    out = dict(bodies)
    names = sorted(out)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if not _colliders_meet(out[a], out[b]):
                continue
            limit = max(config.hull_tolerance, config.max_reach or 0.0)
            meshes = (out[a].world(), out[b].world())  # as they were before any clip of this pair
            meshes_overlap = None  # m^3, asked once per pair
            deepest = np.inf
            pairs = _PartOverlaps(out[a], out[b])
            # one try per overlapping pair of parts: a clip separates its pair for good (parts only shrink), so the
            # loop ends after at most as many clips as pairs overlapped (bench_00 phone's two 50-part balls pressed
            # together: 46; a budget of 32 clips per body pair left 14 pairs up to 3.5 mm deep)
            while (found := pairs.worst(deepest)) is not None:
                j, k, depth = found
                # the meshes' overlap (a boolean of both) only asked once a part overlaps deeper than a part may
                # reach: where the meshes overlap, deeper is the mesh edits' business
                if depth > limit and meshes_overlap is None:
                    meshes_overlap = overlap(*meshes).volume_m3
                if depth > limit and meshes_overlap >= config.min_overlap:
                    deepest = limit
                    continue
                pairs.tried.add((j, k))
                # deeper than a part may reach: only a clip that takes next to nothing of the mesh (a hull over a
                # compartment, clipped at what stands in it, would take the shelf's bottom board with it)
                clipped = _clipped_apart(out[a], j, out[b], k, max_share=np.inf if depth <= limit else 0.01)
                if clipped is None:  # that pair stays (it is recorded as penetration)
                    continue
                side = 0 if clipped[0] is not out[a] else 1
                out[a], out[b] = clipped
                pairs.changed(side, j if side == 0 else k, clipped[side])
    return out


class _PartOverlaps:
    """The overlaps of every pair of two bodies' collider parts whose boxes meet, kept up to date as parts are
    clipped (only the clipped part's pairs are measured again)."""

    def __init__(self, a: _Body, b: _Body) -> None:
        self.parts = [_world_parts(a), _world_parts(b)]
        self.boxes = [_boxes(self.parts[0]), _boxes(self.parts[1])]  # [A, 2, 3], [B, 2, 3]
        self.tried: set[tuple[int, int]] = set()  # pairs a clip was tried on
        self.found: dict[tuple[int, int], tuple[float, float]] = {}  # (j, k) -> (volume m^3, depth m)
        for j in range(len(self.parts[0])):
            self._measure(j, range(len(self.parts[1])))

    def _measure(self, j: int, ks: Iterable[int]) -> None:
        box_a, box_b = self.boxes
        for k in ks:
            self.found.pop((j, k), None)
            if not ((box_a[j, 0] > box_b[k, 1]).any() or (box_b[k, 0] > box_a[j, 1]).any()):
                o = overlap(self.parts[0][j], self.parts[1][k])
                if o.volume_m3 > 0.0:
                    self.found[(j, k)] = (o.volume_m3, o.depth_m)

    def worst(self, deepest: float) -> tuple[int, int, float] | None:
        """The pair of parts (``a``'s, ``b``'s) overlapping most by volume, at most ``deepest`` deep and not tried
        yet (ties: the first in row-major order), and how deep; or None."""
        best, pick = 0.0, None
        for key in sorted(self.found):
            volume, depth = self.found[key]
            if volume > best and depth <= deepest and key not in self.tried:
                best, pick = volume, (key[0], key[1], depth)
        return pick

    def changed(self, side: int, index: int, body: _Body) -> None:
        """``body`` (side 0: ``a``, 1: ``b``) had its part ``index`` clipped."""
        self.parts[side][index] = _world_parts(body)[index]
        self.boxes[side][index] = _boxes([self.parts[side][index]])[0]
        if side == 0:
            self._measure(index, range(len(self.parts[1])))
        else:
            for j in range(len(self.parts[0])):
                self._measure(j, [index])


def _within_vertex_limit(bodies: dict[str, _Body], config: PhysicsSetupConfig) -> dict[str, _Body]:
    """Every collider part with at most ``max_hull_vertices`` vertices: a part with more becomes the hull of that
    many of its own (inside it), and the mesh and SDF are cut to what lies inside the parts, where the hull left out
    a vertex (edit ``hullVertices:<mm>``, the farthest one's distance), so that the collider stays the rendered
    solid; its reach outside the mesh is measured again. A cut that would leave a part farther outside the mesh
    than before (it dropped, as a crumb, a piece that the smaller parts no longer join) is not made."""
    if config.max_hull_vertices is None:
        return bodies
    out = dict(bodies)
    for name, body in bodies.items():
        kind, parts, reach = body.collider
        limited, dropped, changed = [], 0.0, False
        for part in parts:
            if len(part.points) <= config.max_hull_vertices:
                limited.append(part)
                continue
            points, faces, off = limited_hull(part.points, config.max_hull_vertices)
            limited.append(MeshData(points=points, faces=faces))
            dropped, changed = max(dropped, off), True
        if not changed:
            continue
        if dropped <= 0.0:  # points that were no vertices: the same solid
            out[name] = replace(body, collider=(kind, limited, reach))
            continue
        edit = f"hullVertices:{1000 * dropped:.1f}mm"
        trimmed = body
        if _left_out(body.mesh.points, parts, limited):
            trimmed = body.within_convex([(p.points, p.faces) for p in limited], edit)
        if trimmed is not body:
            trimmed = replace(trimmed, mesh=_drop_degenerate(trimmed.mesh))
            if not _closed(trimmed.mesh):
                trimmed = body
        if trimmed is not body:
            mesh = (trimmed.mesh.points, trimmed.mesh.faces)
            left = collider_reach([(p.points, p.faces) for p in limited], mesh, seed=config.seed)
            if left <= reach + 1e-3:
                out[name] = replace(trimmed, collider=(kind, limited, left))
                continue
            # farther out than before: the smaller parts no longer meet, and the cut dropped the piece one of them
            # holds as a crumb (hard/top_only (phone)'s table lost 5.6 cm^3 so, a part left 4.8 cm from its mesh;
            # a coffee table made the union of its parts lost a leg, its part 35 cm from the mesh)
        # nothing of the mesh outside the parts, a cut that would open it, or one that would drop a piece: the mesh
        # stays whole (a few millimetres outside the smaller parts), recorded, and the reach as measured before (the
        # smaller parts reach no farther)
        out[name] = replace(body, edits=(*body.edits, edit), collider=(kind, limited, reach))
    return out


def _left_out(points: np.ndarray, parts: list[MeshData], limited: list[MeshData], eps: float = 1e-7) -> bool:
    """Whether any of ``points`` (a mesh's vertices) lies in one of ``parts`` and in none of ``limited`` (the same
    parts, some of them made smaller)."""
    for before, after in zip(parts, limited, strict=True):
        if after is before:
            continue
        lo, hi = before.points.min(axis=0) - eps, before.points.max(axis=0) + eps
        near = points[np.all((points >= lo) & (points <= hi), axis=1)]
        near = near[_depth_inside(before.points, near) >= -eps]
        for part in limited:
            if not len(near):
                break
            near = near[_depth_inside(part.points, near) < -eps]
        if len(near):
            return True
    return False


def _boxes(parts: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """[N, 2, 3] each part's bounding box (lower, upper corner); an empty part's is inside out (meets nothing)."""
    empty = np.array([np.full(3, np.inf), np.full(3, -np.inf)])
    return np.array([(p.min(axis=0), p.max(axis=0)) if len(p) else empty for p, _ in parts], float).reshape(-1, 2, 3)


def _clipped_apart(a: _Body, j: int, b: _Body, k: int, max_share: float = np.inf) -> tuple[_Body, _Body] | None:
    """``a``'s part ``j`` and ``b``'s part ``k`` no longer overlapping: the one cut (either part, by a plane of the
    other's faces) that takes the least of its body's mesh, then the least of the part; None when no cut
    separates them, or none takes at most ``max_share`` of its body's mesh volume."""
    from holousd.physics import convex_hull

    p, q = _world_parts(a)[j], _world_parts(b)[k]
    options = []
    for which, cut, other, mesh in ((0, p, q, a.world()), (1, q, p, b.world())):
        most = max_share * mass_properties(mesh, 1.0).volume_m3 if np.isfinite(max_share) else np.inf
        normals, offsets = _face_planes(other)
        flip = normals @ other[0].mean(axis=0) > offsets  # outwards: the other part on the plane's inner side
        normals[flip], offsets[flip] = -normals[flip], -offsets[flip]
        planes = np.unique(np.round(np.column_stack([normals, offsets]), 6), axis=0)
        for n, d in zip(planes[:, :3], planes[:, 3], strict=True):
            kept, removed = cut_by_plane(cut, n, d + 2e-4, min_keep=0.5)
            if removed > 0 and overlap(kept, other).volume_m3 == 0.0:
                lost = overlap(mesh, cut_by_plane(cut, -n, -(d + 2e-4), min_keep=0.0)[0]).volume_m3
                if lost <= most:
                    options.append((lost, removed, which, kept, n, d + 2e-4))
    if not options:
        return None
    lost, _, which, kept, n, d = min(options, key=lambda o: o[:2])  # the rendered solid first: the hull reaching out
    bodies = [a, b]
    body, index = (a, j) if which == 0 else (b, k)
    part = p if which == 0 else q
    other = b if which == 0 else a
    edit = f"clip:collider:{other.name}"
    kind, parts, reach = body.collider
    edits = body.edits if edit in body.edits else (*body.edits, edit)  # once per neighbour
    trimmed = replace(body, edits=edits)
    if lost > 1e-8:  # what of the body's mesh lay in the piece cut off goes with it (where the mesh stays closed)
        cut = body.minus_convex([cut_by_plane(part, -n, -d, min_keep=0.0)[0]], edit)
        if cut is not body and _closed(_drop_degenerate(cut.mesh)):
            trimmed = replace(cut, edits=edits)
    hull = convex_hull(*kept)
    inverse = np.linalg.inv(body.pose.matrix())
    local = MeshData(points=hull[0] @ inverse[:3, :3].T + inverse[:3, 3], faces=hull[1])
    bodies[which] = replace(trimmed, collider=(kind, [*parts[:index], local, *parts[index + 1:]], reach))
    return bodies[0], bodies[1]


# ----------------------------------------------------------------------------------------------- the stage
def setup_physics(scene: SceneGraph, config: PhysicsSetupConfig | None = None,
                  out_dir: str | os.PathLike[str] | None = None) -> PhysicsSetupResult:  # fmt: skip
    """Infer relations, set every object onto its support on its rendered mesh, and author colliders derived
    from that mesh, rigid bodies, materials and the per-object records as the layer ``20_physics.usda``.

    Args:
        scene: A file-backed scene whose objects have meshes (after s1_fit).
        config: Settings.
        out_dir: Folder of the new layer (default: the folder of the scene's root layer).
    """
    config = config or PhysicsSetupConfig()
    out_dir, meshes, skipped = stage_inputs(scene, config.background_collider, out_dir)
    bodies: dict[str, _Body] = {}
    for name, mesh in meshes.items():
        try:
            sdf = scene.get_sdf(name)
        except SceneError:
            sdf = None
        pose = scene.get_pose(name)
        bodies[name] = _Body(name=name, mesh=mesh, sdf=sdf, pose=pose, fit_pose=pose)
    try:
        background = scene.get_mesh(BACKGROUND)
    except SceneError:
        background = None
    floor, walls, slabs = None, [], []
    bg_world = None
    if background is not None and len(background.faces):
        bg_world = MeshData(points=scene.get_pose(BACKGROUND).apply(background.points), faces=background.faces)
        floor, walls = _room_planes(bg_world)
        if config.background_collider == "slabs":
            slabs = _room_slabs(bg_world, config.slab_thickness)
    if config.clip_to_walls:
        bodies = _clip(bodies, walls, config.clearance)
    relations = infer_relations({n: b.world() for n, b in bodies.items()}, config.relations, floor=floor)
    if config.rest:
        room_surface = float(floor) if slabs else ((bg_world.points, bg_world.faces) if bg_world is not None else None)
        bodies = _rest(bodies, relations, room_surface, config)
    if config.separate:
        bodies = _separate(bodies, relations, config)
    for name in sorted(bodies):  # one by one: each keeps out of what was shaped before it
        bodies[name] = _shaped(bodies[name], config, _around(name, bodies), config.keep_out_parts)
    bodies = _unclasped(bodies, config)
    bodies = _within_vertex_limit(bodies, config)

    scene.push_layer(Path(out_dir) / PHYSICS_LAYER, provenance=config.provenance, replace=True)
    material = dict(static_friction=config.friction, dynamic_friction=config.friction,
                    restitution=config.restitution)  # fmt: skip
    if background is not None and len(background.faces):
        cleaned = _drop_degenerate(background)
        if cleaned is not background:
            scene.set_mesh(BACKGROUND, cleaned)
        if slabs:
            bg_inverse = [(s.points, s.faces) for s in slabs]
            inverse = np.linalg.inv(scene.get_pose(BACKGROUND).matrix())
            parts = [MeshData(points=p @ inverse[:3, :3].T + inverse[:3, 3], faces=f) for p, f in bg_inverse]
            scene.set_collider(BACKGROUND, Collider(approximation="convexDecomposition", parts=parts))
        else:
            scene.set_collider(BACKGROUND, Collider(approximation="none", parts=[cleaned]))
        scene.set_physics(BACKGROUND, PhysicsProps(mass=None, density=config.density, **material))
    room = slabs if slabs else ([bg_world] if bg_world is not None and config.background_collider == "mesh" else [])
    results: list[ObjectPhysics] = []
    for name, body in bodies.items():
        body = replace(body, mesh=_drop_degenerate(body.mesh))  # as authored (float32): no face of zero area
        scene.set_mesh(name, body.mesh)
        if body.edits and body.sdf is not None:
            scene.set_sdf(name, body.sdf)
        shift = np.asarray(body.pose.translation, float) - np.asarray(body.fit_pose.translation, float)
        if np.any(shift != 0.0):
            scene.set_pose(name, body.pose)
        kind, parts, reach = body.collider
        scene.set_collider(name, Collider(approximation="convexDecomposition" if len(parts) > 1 else "convexHull",
                                          parts=parts))  # fmt: skip
        props = mass_properties((body.mesh.points, body.mesh.faces), config.density)
        mass = max(props.mass_kg, 1e-3)
        inertia = props.diagonal_inertia * (mass / max(props.mass_kg, 1e-12))  # the same mesh as the mass
        scene.set_physics(name, PhysicsProps(mass=mass, center_of_mass=props.center_of_mass,
                                             diagonal_inertia=inertia, principal_axes=props.principal_axes,
                                             density=config.density, **material))  # fmt: skip
        parent = relations.support[name]
        scene.set_support(name, parent)
        scene.set_beside(name, relations.beside.get(name, []))
        penetration = _penetration(name, bodies, room)
        record = ObjectPhysics(name=name, parent=parent, beside=relations.beside.get(name, []), collider=kind,
                               parts=len(parts), convexity=float("nan"), collider_reach_m=reach,
                               penetration_m=penetration, settled_m=[float(v) for v in shift],
                               shift_refused_m=body.refused, volume_m3=props.volume_m3, mass_kg=mass,
                               edits=list(body.edits))  # fmt: skip
        scene.set_geometry_record(name, GeometryRecord(fit_shift=shift, collider_reach=reach, penetration=penetration,
                                                       volume=props.volume_m3, edits=list(body.edits)))  # fmt: skip
        results.append(record)
    scene.save()
    return PhysicsSetupResult(scene=scene, relations=relations, objects=results, skipped=skipped)

