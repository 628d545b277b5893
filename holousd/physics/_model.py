"""UsdPhysics stage -> Newton model, for all rigid bodies or a subset (one object dynamic on a static chain)."""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pxr import Usd

from . import _scene
from ._errors import PhysicsInputError
from ._scene import ColliderParts

__all__ = ["ColliderOverride", "ModelConfig", "PhysicsModel", "build_model", "default_device"]


@dataclass(kw_only=True)
class ColliderOverride:
    """Collider geometry that replaces an object's authored colliders for one model build."""

    parts: ColliderParts
    """``(points [N, 3], faces [F, 3])`` per part, object coordinates, metres."""
    approximation: str = "convexHull"
    """``physics:approximation`` for every part: ``"convexHull"`` (hull per part) or ``"none"`` (triangle mesh)."""


@dataclass(kw_only=True)
class ModelConfig:
    """How a stage becomes a Newton model."""

    friction: float | None = None
    """Friction coefficient forced on every collider (dimensionless); None honours the bound physics materials."""
    restitution: float | None = None
    """Restitution forced on every collider (dimensionless); None honours the bound physics materials."""
    default_friction: float = 0.5
    """Friction of colliders without a bound physics material (dimensionless)."""
    default_restitution: float = 0.0
    """Restitution of colliders without a bound physics material (dimensionless)."""
    hull_convex_meshes: bool = True
    """Split triangle-mesh colliders (approximation ``none``) into connected pieces and collide every piece that
    is exactly convex (closed, e.g. a floor slab or a wall box) as its hull: the same geometry, much cheaper
    contact. Non-convex pieces stay triangle meshes."""
    decompose_concave_meshes: bool = False
    """Also replace the non-convex pieces by a CoACD decomposition (needed by MuJoCo, which collides every mesh
    as its convex hull)."""
    max_hull_vertices: int = 1024
    """Vertex cap of the convex hulls Newton builds from ``convexHull`` colliders (qhull needs a positive cap).
    Newton's own default (64) silently rounds off detailed hulls: a ball with a flat contact disc lost the
    disc and rolled 30 degrees."""
    device: str | None = None
    """Warp device; None picks Warp's preferred device (CUDA when present, else ``"cpu"``)."""


@dataclass(kw_only=True)
class PhysicsModel:
    """A finalized Newton model plus the bookkeeping that maps it back to prims."""

    model: Any
    """The ``newton.Model``."""
    body_paths: list[str]
    """Prim path of each body, indexed by Newton body index."""
    static_paths: list[str]
    """Rigid bodies that were made static for this build (support chain)."""
    linear_damping: np.ndarray
    """[B] linear velocity damping per body, 1/s (HoloPhysicsAPI)."""
    angular_damping: np.ndarray
    """[B] angular velocity damping per body, 1/s (HoloPhysicsAPI)."""
    device: str
    """Warp device the model lives on."""
    source: str
    """The stage's file path, or ``<in-memory stage>``, for messages."""
    materials: dict[str, _scene.BodyMaterial] = field(default_factory=dict)
    """Material applied to each collider shape, keyed by collider prim path."""

    def body_index(self, path: str) -> int:
        """Newton body index of a prim path."""
        return self.body_paths.index(path)


def default_device() -> str:
    """Warp's preferred device as a string: a CUDA device when one is present, else ``"cpu"``."""
    import warp as wp

    return str(wp.get_preferred_device())


def build_model(
    source: str | os.PathLike[str] | Usd.Stage,
    *,
    dynamic: Iterable[str] | None = None,
    static: Iterable[str] = (),
    colliders: Mapping[str, ColliderOverride] | None = None,
    config: ModelConfig | None = None,
) -> PhysicsModel:
    """Build a Newton model from a UsdPhysics stage.

    Newton's USD importer (``ModelBuilder.add_usd``) reads rigid bodies, colliders (``physics:approximation``
    ``convexHull`` -> convex hull, ``none`` -> triangle mesh), MassAPI mass / density / centre of mass and
    material density. Two things it does not do are done here: friction and restitution are resolved from the
    purpose-"physics" material binding *with inheritance* (the importer only sees bindings on the collider prim
    itself), and HoloPhysicsAPI damping is returned per body for the simulation loop to apply. Triangle-mesh
    colliders are split into connected pieces and exactly convex pieces collide as hulls (``ModelConfig``);
    for MuJoCo the non-convex pieces are decomposed as well.

    Args:
        source: Stage or file path. The stage is never modified: subset edits go to a private session layer.
        dynamic: Rigid bodies to simulate. None simulates every rigid body. When given, rigid bodies that are
            neither in ``dynamic`` nor in ``static`` are left out of the model.
        static: Rigid bodies made static (their colliders stay, fixed in the world): e.g. a support chain.
        colliders: Per-body collider replacements for this build (e.g. hull vs decomposition vs mesh).
        config: Material and device options.

    Returns:
        The model and its body-to-prim mapping.

    Raises:
        PhysicsInputError: No rigid bodies, unknown paths, or units other than metres / kilograms.
    """
    import newton

    cfg = config or ModelConfig()
    stage = _scene.open_stage(source)
    label = _scene.stage_label(stage)
    all_bodies = _scene.rigid_bodies(stage)
    if not all_bodies:
        raise PhysicsInputError(
            f"{label}: no rigid bodies; apply UsdPhysics.RigidBodyAPI (and colliders) to the objects to simulate"
        )
    static = list(dict.fromkeys(static))
    _scene.check_paths(stage, static, "static body")
    if dynamic is None:
        dynamic_list = [b for b in all_bodies if b not in set(static)]
    else:
        dynamic_list = list(dict.fromkeys(dynamic))
        _scene.check_paths(stage, dynamic_list, "object")
    overlap = set(dynamic_list) & set(static)
    if overlap:
        raise PhysicsInputError(f"{label}: {sorted(overlap)[0]} is both dynamic and static; pick one")
    if not dynamic_list:
        raise PhysicsInputError(f"{label}: nothing to simulate; name at least one dynamic rigid body")
    dropped = [b for b in all_bodies if b not in set(dynamic_list) and b not in set(static)]

    work = _scene.working_stage(stage)
    _scene.deactivate(work, dropped)
    _scene.make_static(work, static)
    for path, override in (colliders or {}).items():
        _scene.check_paths(stage, [path], "collider override for")
        _scene.replace_colliders(work, path, override.parts, override.approximation)
    if cfg.hull_convex_meshes or cfg.decompose_concave_meshes:
        _convexify_mesh_colliders(work, hull_convex=cfg.hull_convex_meshes, decompose=cfg.decompose_concave_meshes)

    builder = newton.ModelBuilder(up_axis=_stage_up_axis(work))
    builder.default_shape_cfg.mu = cfg.default_friction
    builder.default_shape_cfg.restitution = cfg.default_restitution
    result = builder.add_usd(work, load_visual_shapes=False, load_sites=False, mesh_maxhullvert=cfg.max_hull_vertices)
    path_body = {str(k): int(v) for k, v in result["path_body_map"].items()}
    missing = [p for p in dynamic_list if p not in path_body]
    if missing:
        raise PhysicsInputError(
            f"{label}: Newton imported no body for {missing[0]}; give it a collider (CollisionAPI) and MassAPI"
        )

    materials = _apply_materials(builder, work, cfg)

    device = cfg.device or default_device()
    model = builder.finalize(device=device)
    body_paths = [""] * model.body_count
    for path, idx in path_body.items():
        body_paths[idx] = path
    lin = np.zeros(model.body_count)  # [B] 1/s
    ang = np.zeros(model.body_count)  # [B] 1/s
    for idx, path in enumerate(body_paths):
        if path:
            lin[idx], ang[idx] = _scene.body_damping(work, path)
    return PhysicsModel(
        model=model,
        body_paths=body_paths,
        static_paths=static,
        linear_damping=lin,
        angular_damping=ang,
        device=device,
        source=label,
        materials=materials,
    )


def _stage_up_axis(stage: Usd.Stage) -> str:
    from pxr import UsdGeom

    return "Y" if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y else "Z"


def _apply_materials(builder: Any, stage: Usd.Stage, cfg: ModelConfig) -> dict[str, _scene.BodyMaterial]:
    """Set friction / restitution of every imported collider from its (inherited) physics material binding."""
    applied: dict[str, _scene.BodyMaterial] = {}
    for idx, label in enumerate(builder.shape_label):
        prim = stage.GetPrimAtPath(label) if label.startswith("/") else None
        if prim is None or not prim:
            continue
        mat = _scene.read_material(
            prim, default_friction=cfg.default_friction, default_restitution=cfg.default_restitution
        )
        if cfg.friction is not None:
            mat.friction = cfg.friction
        if cfg.restitution is not None:
            mat.restitution = cfg.restitution
        builder.shape_material_mu[idx] = mat.friction
        builder.shape_material_restitution[idx] = mat.restitution
        applied[label] = mat
    return applied


def _convexify_mesh_colliders(stage: Usd.Stage, *, hull_convex: bool, decompose: bool) -> None:
    """Re-author triangle-mesh colliders as convex parts on the working stage (see ModelConfig).

    Each collider Mesh with ``physics:approximation = none`` is split into connected pieces (unless a piece
    bounds a cavity, e.g. a hollow room shell, when the mesh stays whole); a closed convex piece becomes its
    hull, a non-convex piece stays a triangle mesh or (``decompose``) becomes CoACD parts. When anything
    changes, the original prim is deactivated and a sibling ``<name>_HoloParts`` Xform with the same local
    transform and physics material holds the new ``Part_###`` colliders.
    """
    import trimesh
    from pxr import UsdGeom, UsdPhysics, UsdShade

    from holousd.geometry._hulls import convex_decomposition, convex_hull

    targets = []
    for prim in stage.Traverse():
        if not (prim.IsA(UsdGeom.Mesh) and prim.HasAPI(UsdPhysics.CollisionAPI)):
            continue
        if prim.HasAPI(UsdPhysics.RigidBodyAPI):
            continue  # a mesh that is its own body: parts authored beside it would leave the body
        approx = (
            UsdPhysics.MeshCollisionAPI(prim).GetApproximationAttr().Get()
            if prim.HasAPI(UsdPhysics.MeshCollisionAPI)
            else "none"
        )
        if str(approx or "none") == "none":
            targets.append(prim)
    for prim in targets:
        pts, faces = _scene.mesh_arrays(UsdGeom.Mesh(prim))
        if len(faces) == 0:
            continue
        whole = trimesh.Trimesh(pts, faces, process=True)
        pieces = whole.split(only_watertight=False)
        if any(p.is_watertight and p.volume < 0 for p in pieces):
            # a piece with inward normals bounds a cavity (a hollow room shell: outer box + inverted inner box);
            # hulling pieces one by one would fill the cavity, so the mesh must be treated as one solid
            pieces = [whole]
        parts: list[tuple[np.ndarray, np.ndarray, str]] = []
        changed = False
        for piece in pieces:
            if piece.is_watertight and piece.is_convex:
                if hull_convex:
                    parts.append((*convex_hull(piece.vertices), "convexHull"))
                    changed = True
                    continue
            elif decompose:
                for pp, pf in convex_decomposition(piece.vertices, piece.faces):
                    parts.append((pp, pf, "convexHull"))
                changed = True
                continue
            parts.append((np.asarray(piece.vertices), np.asarray(piece.faces), "none"))
        if not changed:
            continue
        material = _scene.bound_physics_material(prim)
        local = UsdGeom.Xformable(prim).GetLocalTransformation()
        holder = UsdGeom.Xform.Define(stage, prim.GetPath().GetParentPath().AppendChild(f"{prim.GetName()}_HoloParts"))
        holder.AddTransformOp().Set(local)
        for i, (pp, pf, approximation) in enumerate(parts):
            mesh = _scene.author_collider_mesh(stage, f"{holder.GetPath()}/Part_{i:03d}", pp, pf, approximation)
            if material is not None:
                UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(
                    material, UsdShade.Tokens.weakerThanDescendants, "physics"
                )
        prim.SetActive(False)
