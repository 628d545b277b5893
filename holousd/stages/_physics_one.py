"""The one-geometry physics set-up (opt-in: ``PhysicsSetupConfig(one_geometry=True)`` of the physics stage).

Work in progress towards the default (ARCHITECTURE.md, "one geometry per object"): on the demo scene it is not
yet as stable as the default set-up (the decompositions of fitted furniture reach centimetres outside the mesh
and into what rests on it), so the stage does not use it unless asked. Everything done so that an object can
stand is done to its rendered mesh and its SDF, and the collider is derived from that final mesh alone. In
order, as small passes over the objects:

1. ``clip``: each mesh is trimmed where it runs behind one of the room's walls (the unseen back of something
   standing against a wall; the fit leaves it unbounded there).
2. ``relations``: the support tree and beside pairs (:func:`holousd.graph.infer_relations`).
3. ``rest``: breadth-first from the room, each object is set onto its support: the top of a support that others
   rest on is cut flat at the lowest point of its surface under them (at most ``top_depth`` below its highest
   point: a fitted top is a bumpy dome of facets); then each child's unseen underside is cut flat, ``clearance``
   above the higher of the support's mesh and the support's collider under it (deep enough for a base spanning
   half its width, ``base_depth``; the object moved down when it floats above, by at most ``max_shift``).
   Whatever of the support's collider still lies inside the child is cut away from the child's mesh and SDF.
   Children follow their parent's moves.
4. ``separate``: neighbours whose meshes still overlap are cut apart at the middle of the overlap, across its
   thinnest axis, as two real objects meet at one face.
5. ``colliders``: the convex hull of the final mesh when it reaches at most ``hull_tolerance`` outside it, else a
   CoACD decomposition of that mesh (the hull after all when the decomposition reaches no less far); the reach
   outside the mesh is measured and recorded either way.
6. ``mass``: mass, centre of mass and inertia (principal moments and axes) of the final mesh at ``density``.

Each object records (``HoloGeometryAPI``): its shift from the pose the fit gave (``holo:geometry:fitShift``), its
collider's reach outside the mesh, its deepest penetration into another node, its volume and the edits made.
No collider-only edit is made: where the rendered geometry cannot stand, the stability verdict says so.

The room's static collider is a set of axis-aligned floor and wall slabs fitted to the background mesh's planes
(``background_collider='slabs'``; its triangle mesh with ``'mesh'`` or when no floor plane is found): Newton's
triangle-mesh contact launched furniture resting on the fitted room shell.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from holousd._errors import SceneError
from holousd.geometry._contact import collider_reach, cut_by_plane, mass_properties, overlap, subtract
from holousd.graph import RelationConfig, Relations, infer_relations
from holousd.stages._physics_setup import (
    PHYSICS_LAYER,
    ObjectPhysics,
    PhysicsSetupResult,
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
    ``share`` of the object's width along x and y, at most ``deepest`` metres (nothing for a flat base). The
    underside of an object resting on something is never observed; the fit leaves it rounded by about a voxel,
    and a rounded base rocks or rolls (the protocol has no damping) where the real object stands."""
    top_depth: float = 0.015
    """Deepest flattening of the top of a support that others rest on, below its highest point, metres: a
    fitted top is a bumpy dome of facets (a centimetre or two on 160x120 captures); a child set on it rocks, and
    the collider's hulls bridge its dents above the rendered surface."""
    clearance: float = 0.001
    """Gap left between an object's flat base and its support's surface, metres."""
    max_shift: float = 0.01
    """Largest move of an object from its fitted pose, metres (about what its own depth and masks allow: the
    observed surface moves with it). A larger one is refused and recorded; the object stays where it was seen."""
    separate: bool = True
    """Cut apart neighbours whose meshes overlap, at the middle of the overlap."""
    min_overlap: float = 1e-7
    """Overlaps smaller than this are left alone (touching, not intersecting), m^3 (0.1 cm^3)."""
    max_separation_loss: float = 0.3
    """A cut between neighbours may remove at most this fraction of an object's volume (else it is not made)."""
    max_parts: int = 8
    """Most convex parts of a decomposition."""
    decomposition_iterations: int | None = 20
    """CoACD tree-search iterations with a coarse (300-sample) concavity metric, a one-level search and
    concavity threshold 0.1: on the demo's fitted meshes as close to the mesh as tighter settings (0.05, 40
    iterations: within 1 cm) at a tenth of the time (0.2-7 s an object). None runs
    :func:`holousd.physics.convex_decomposition` with its full settings."""
    background_collider: str = "slabs"
    """'slabs': axis-aligned floor and wall slabs fitted to the background mesh (falls back to 'mesh' when no
    floor plane is found); 'mesh': the background's triangle mesh (approximation none)."""
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
        return replace(self, mesh=MeshData(points=points, faces=faces), sdf=sdf, edits=(*self.edits, edit))

    def minus_convex(self, parts: list[tuple[np.ndarray, np.ndarray]], edit: str) -> _Body:
        """The body with whatever of the convex world-space ``parts`` (another object's collider) lies inside it
        removed from its mesh and SDF."""
        from scipy.spatial import ConvexHull, QhullError

        inverse = np.linalg.inv(self.pose.matrix())
        local = [(p @ inverse[:3, :3].T + inverse[:3, 3], f) for p, f in parts]
        (points, faces), removed = subtract((self.mesh.points, self.mesh.faces), local)
        if removed <= 0:
            return self
        sdf = self.sdf
        if sdf is not None:
            grid = _grid_points(sdf)
            values = sdf.grid.reshape(-1).astype(np.float64)
            for p, _ in local:
                try:
                    planes = ConvexHull(p).equations  # [H, 4]: n . x + d <= 0 inside
                except (QhullError, ValueError):
                    continue
                inside_part = (grid @ planes[:, :3].T + planes[:, 3]).max(axis=1)  # < 0 inside the part
                values = np.maximum(values, -inside_part)
            sdf = replace(sdf, grid=values.reshape(sdf.grid.shape).astype(np.float32))
        return replace(self, mesh=MeshData(points=points, faces=faces), sdf=sdf, edits=(*self.edits, edit))


def _grid_points(sdf: SdfField) -> np.ndarray:
    """[X*Y*Z, 3] object coordinates of an SDF's samples (C order)."""
    axes = [sdf.origin[i] + sdf.voxel_size * np.arange(n) for i, n in enumerate(sdf.grid.shape)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _base_depth(points: np.ndarray, limits: tuple[float, float]) -> float:
    """How deep to cut a body's underside flat: the least depth (up to ``limits[1]``) at which its lowest points
    span ``limits[0]`` of its width along x and along y (0 for a flat base: nothing needs cutting)."""
    share, deepest = limits
    bottom = float(points[:, 2].min())
    width = np.maximum(np.ptp(points[:, :2], axis=0), 1e-9)
    for depth in np.linspace(0.0, deepest, 17):
        low = points[points[:, 2] <= bottom + depth + 1e-9, :2]
        if np.all(np.ptp(low, axis=0) >= share * width):
            return float(depth)
    return float(deepest)


def _order(relations: Relations) -> list[str]:
    """Objects breadth-first from the room (parents before children)."""
    order: list[str] = []
    frontier = [BACKGROUND]
    while frontier:
        kids = relations.children(frontier.pop(0))
        order.extend(kids)
        frontier.extend(kids)
    return order + sorted(n for n in relations.support if n not in order)




# ----------------------------------------------------------------------------------------------- passes
def _clip(bodies: dict[str, _Body], walls: list[tuple[int, float, float]], clearance: float) -> dict[str, _Body]:
    """Trim every mesh behind the room's walls (keep ``sign * (x[axis] - at) >= clearance``)."""
    out = {}
    for name, body in bodies.items():
        for axis, sign, at in walls:
            points = body.world()[0]
            if not np.any(sign * (points[:, axis] - at) < clearance):
                continue
            normal = np.zeros(3)
            normal[axis] = sign
            body = body.cut(normal, sign * at + clearance, "clip:wall")
        out[name] = body
    return out


def _hits_below(body: _Body, support: tuple[np.ndarray, np.ndarray], band: float) -> np.ndarray:
    """[K, 3] first points of ``support`` below the body's lowest points (within ``band`` of its bottom), hit
    by rays cast straight down."""
    from trimesh.ray.ray_triangle import RayMeshIntersector

    from holousd.graph._relations import _trimesh

    points = body.world()[0]
    low = points[points[:, 2] <= float(points[:, 2].min()) + band]
    origins = low.copy()
    origins[:, 2] = float(points[:, 2].max())
    hits, _, _ = RayMeshIntersector(_trimesh(support)).intersects_location(
        origins, np.tile([0.0, 0.0, -1.0], (len(origins), 1)), multiple_hits=False)  # fmt: skip
    return np.asarray(hits, float).reshape(-1, 3)


def _support_height(body: _Body, support: tuple[np.ndarray, np.ndarray] | float, band: float) -> float | None:
    """Height of the support's surface under the body: its highest point under the body's lowest points (the
    floor's height for a floor); None when nothing is hit."""
    if isinstance(support, float):
        return support
    hits = _hits_below(body, support, band)
    return float(hits[:, 2].max()) if len(hits) else None


def _rest(bodies: dict[str, _Body], relations: Relations, room: tuple[np.ndarray, np.ndarray] | float | None,
          colliders: Callable[[_Body], tuple[str, list[MeshData], float]],
          config: PhysicsSetupConfig) -> dict[str, _Body]:  # fmt: skip
    """Set every object onto its support, parents first (see the module docstring, pass 3). ``room``: the
    floor's height (slab colliders), the room's world mesh, or None (objects on the room stay as they are);
    ``colliders``: a body's collider (from its current mesh)."""
    out = dict(bodies)
    up = np.array([0.0, 0.0, 1.0])
    band = config.relations.bottom_band
    for name in _order(relations):
        if name not in out:
            continue
        parent = relations.support.get(name, BACKGROUND)
        support_parts: list[tuple[np.ndarray, np.ndarray]] = []
        if parent != BACKGROUND and parent in out:  # the support's top, flat where its children rest on it
            out[parent] = _flatten_top(out[parent], [out[c] for c in relations.children(parent) if c in out],
                                       config)  # fmt: skip
            support_parts = [(out[parent].pose.apply(p.points), p.faces) for p in colliders(out[parent])[1]]
        body = out[name]
        surface = room if parent == BACKGROUND else (out[parent].world() if parent in out else None)
        if surface is None:
            continue
        heights = [_support_height(body, surface, band), *(_support_height(body, p, band) for p in support_parts)]
        heights = [h for h in heights if h is not None]
        if not heights:
            continue
        height = max(heights)  # on the support's mesh, and on its collider where that stands higher
        points = body.world()[0]
        bottom = float(points[:, 2].min())
        base = height + config.clearance
        depth = _base_depth(points, config.base_depth)
        drop = (base - depth) - bottom  # < 0: move down so that the underside is cut `depth` deep
        if drop < 0:
            if -drop <= config.max_shift:
                shift = np.array([0.0, 0.0, drop])
                for other in [name, *_descendants(relations, name)]:
                    if other in out:
                        out[other] = replace(out[other].moved(shift), edits=(*out[other].edits, "shift"))
                body = out[name]
            else:
                body = replace(body, refused=float(-drop))
        body = body.cut(up, base, "cut:base")
        if support_parts:  # what of the support's collider still lies inside the child
            body = body.minus_convex(support_parts, "cut:parent")
        out[name] = body
    return out


def _flatten_top(parent: _Body, children: list[_Body], config: PhysicsSetupConfig) -> _Body:
    """Cut a support's top flat at the lowest point of its surface under the children resting on that top (at
    most ``top_depth`` below its highest point): a fitted top is a shallow dome of facets, on which a child's
    flat base would rock. A flat top, or a support whose children rest lower (a shelf's boards), is left as is."""
    if "cut:top" in parent.edits or not children:
        return parent
    points = parent.world()[0]
    top = float(points[:, 2].max())
    lows = []
    for child in children:
        c = child.world()[0]
        if abs(float(c[:, 2].min()) - top) > config.max_shift + config.top_depth:
            continue  # it rests on something lower than the top
        hits = _hits_below(child, parent.world(), config.relations.bottom_band)
        hits = hits[hits[:, 2] >= top - config.top_depth]
        if len(hits):
            lows.append(float(np.percentile(hits[:, 2], 10)))  # robust to a stray dent
    if not lows:
        return parent
    plane = max(float(np.min(lows)), top - config.top_depth)
    if top - plane < 5e-4:
        return parent
    return parent.cut(np.array([0.0, 0.0, -1.0]), -plane, "cut:top")


def _separate(bodies: dict[str, _Body], relations: Relations, config: PhysicsSetupConfig) -> dict[str, _Body]:
    """Cut apart neighbours (not parent and child) whose meshes overlap, at the middle of the overlap across
    its thinnest axis; each keeps its own side."""
    out = dict(bodies)
    names = sorted(out)
    family = {n: {relations.support.get(n)} | set(relations.children(n)) for n in names}
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if b in family[a]:
                continue
            both = overlap(out[a].world(), out[b].world())
            if both.volume_m3 < config.min_overlap:
                continue
            direction = both.thin_axis if both.thin_axis is not None else np.eye(3)[int(np.argmin(both.hi - both.lo))]
            mid = float(direction @ (both.lo + both.hi) / 2)
            for name, other in ((a, b), (b, a)):
                centre = mass_properties(out[name].world(), 1.0).center_of_mass
                side = 1.0 if float(direction @ centre) >= mid else -1.0
                out[name] = out[name].cut(side * direction, side * mid + config.clearance / 2, f"cut:neighbour:{other}",
                                          min_keep=1.0 - config.max_separation_loss)  # fmt: skip
    return out


def _decompose(mesh: MeshData, config: PhysicsSetupConfig) -> list[tuple[np.ndarray, np.ndarray]]:
    """Convex decomposition of ``mesh``: the quick CoACD settings, or holousd.physics' full ones."""
    from holousd.physics import DecompositionConfig, convex_decomposition

    cfg = DecompositionConfig(max_parts=config.max_parts, seed=config.seed)
    if config.decomposition_iterations is not None:  # quick settings: coarse concavity metric, shallow search
        cfg = DecompositionConfig(max_parts=config.max_parts, seed=config.seed, threshold=0.1,
                                  preprocess_resolution=20, resolution=300, mcts_nodes=8, mcts_max_depth=1,
                                  mcts_iterations=config.decomposition_iterations)  # fmt: skip
    return convex_decomposition(mesh.points, mesh.faces, cfg)


def _collider(mesh: MeshData, config: PhysicsSetupConfig) -> tuple[str, list[MeshData], float]:
    """The hull of the mesh when it stays within ``hull_tolerance`` of it, else a decomposition of the mesh;
    with the chosen collider's reach outside the mesh, metres."""
    from holousd.physics import convex_hull

    hull = convex_hull(mesh.points, mesh.faces)
    reach = collider_reach([hull], (mesh.points, mesh.faces), seed=config.seed)
    if reach <= config.hull_tolerance:
        return "hull", [MeshData(points=hull[0], faces=hull[1])], reach
    parts = _decompose(mesh, config)
    part_reach = collider_reach(parts, (mesh.points, mesh.faces), seed=config.seed) if parts else np.inf
    if part_reach >= reach:  # the decomposition does not follow the mesh better: the simpler collider
        return "hull", [MeshData(points=hull[0], faces=hull[1])], reach
    return "decomposition", [MeshData(points=p, faces=f) for p, f in parts], part_reach


def _drop_degenerate(mesh: MeshData) -> MeshData:
    """``mesh`` without its zero-area faces (the splat binding rejects them)."""
    return _without_degenerate(mesh) or mesh


def _penetration(name: str, bodies: dict[str, _Body], slabs: list[MeshData]) -> float:
    """Deepest overlap of a body's mesh with any other body's mesh or room slab, metres."""
    own = bodies[name].world()
    depths = [overlap(own, other.world()).depth_m for key, other in bodies.items() if key != name]
    depths += [overlap(own, (s.points, s.faces)).depth_m for s in slabs]
    return float(max(depths, default=0.0))


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
    relations = infer_relations({n: b.world() for n, b in bodies.items()}, config.relations)
    cache: dict[str, tuple[MeshData, tuple[str, list[MeshData], float]]] = {}

    def colliders(body: _Body) -> tuple[str, list[MeshData], float]:
        """The body's collider from its current mesh (computed once per mesh)."""
        known = cache.get(body.name)
        if known is None or known[0] is not body.mesh:
            cache[body.name] = known = (body.mesh, _collider(body.mesh, config))
        return known[1]

    if config.rest:
        room_surface = float(floor) if slabs else ((bg_world.points, bg_world.faces) if bg_world is not None else None)
        bodies = _rest(bodies, relations, room_surface, colliders, config)
    if config.separate:
        bodies = _separate(bodies, relations, config)
    bodies = {n: replace(b, mesh=_drop_degenerate(b.mesh)) for n, b in bodies.items()}

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
        scene.set_mesh(name, body.mesh)
        if body.edits and body.sdf is not None:
            scene.set_sdf(name, body.sdf)
        shift = np.asarray(body.pose.translation, float) - np.asarray(body.fit_pose.translation, float)
        if np.any(shift != 0.0):
            scene.set_pose(name, body.pose)
        kind, parts, reach = colliders(body)
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

