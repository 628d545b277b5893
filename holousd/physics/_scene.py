"""Read the physics-relevant parts of a UsdPhysics stage: units, rigid bodies, relations, materials, damping.

Also prepares a private *working* stage (same root layer, fresh session layer) on which the model builder can
make bodies static, drop bodies, or swap colliders without touching the caller's stage.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, UsdShade

from holousd._errors import SceneError
from holousd.usd import read_mesh
from holousd.usd._layers import open_layer_stack, usd_error_text
from holousd.usd._scene import set_normals

from ._errors import PhysicsInputError

__all__ = [
    "ANGULAR_DAMPING_ATTR",
    "LINEAR_DAMPING_ATTR",
    "OBJECTS_ROOT",
    "SUPPORTED_BY_REL",
    "BodyMaterial",
    "ColliderParts",
    "author_collider_mesh",
    "body_damping",
    "bound_physics_material",
    "check_paths",
    "collider_prims",
    "deactivate",
    "make_static",
    "mesh_arrays",
    "open_stage",
    "read_material",
    "replace_colliders",
    "resolve_object",
    "rigid_bodies",
    "stage_label",
    "support_chain",
    "supported_by",
    "working_stage",
    "world_mesh",
]

LINEAR_DAMPING_ATTR = "holo:physics:linearDamping"
"""HoloPhysicsAPI linear velocity damping coefficient, 1/s."""
ANGULAR_DAMPING_ATTR = "holo:physics:angularDamping"
"""HoloPhysicsAPI angular velocity damping coefficient, 1/s."""
SUPPORTED_BY_REL = "holo:supportedBy"
"""HoloRelationsAPI relationship to the support parent."""
OBJECTS_ROOT = "/World/Objects"
"""Where the scene convention puts object prims; bare object names resolve under it."""

ColliderParts = list[tuple[np.ndarray, np.ndarray]]
"""Collider geometry: a list of ``(points [N, 3] float64, faces [F, 3] int64)`` tuples, object coordinates."""


@dataclass(kw_only=True)
class BodyMaterial:
    """Contact material of one collider as resolved from its purpose-"physics" binding."""

    friction: float
    """Dynamic friction coefficient (dimensionless)."""
    restitution: float
    """Coefficient of restitution (dimensionless, 0 = inelastic)."""
    path: str | None
    """Material prim path, or None when no physics material is bound (defaults used)."""


def stage_label(stage: Usd.Stage) -> str:
    """Name a stage for messages: its file path, or ``<in-memory stage>``."""
    layer = stage.GetRootLayer()
    return layer.realPath or layer.identifier if not layer.anonymous else "<in-memory stage>"


def open_stage(source: str | os.PathLike[str] | Usd.Stage) -> Usd.Stage:
    """Open a stage from a path (or pass a stage through) and check the units the physics domain relies on.

    Stage metadata must say metres and kilograms (``metersPerUnit = kilogramsPerUnit = 1``). A *missing*
    ``metersPerUnit`` is read as 1 with a warning: USD's fallback is 0.01 (centimetres) and some Newton versions
    scale by it, which would shrink the scene 100x; we make the assumption explicit instead.

    Args:
        source: File path of a USD layer, or an open stage.

    Returns:
        The open stage.

    Raises:
        PhysicsInputError: The file cannot be opened, or its units are not metres / kilograms.
    """
    if isinstance(source, Usd.Stage):
        stage = source
    else:
        path = os.fspath(source)
        if not os.path.isfile(path):
            raise PhysicsInputError(f"{path}: no such file; pass the path of a .usd/.usda/.usdc scene")
        suffix = os.path.splitext(path)[1]
        if Sdf.FileFormat.FindByExtension(suffix.lstrip(".")) is None:
            raise PhysicsInputError(f"{path}: not a USD file (extension {suffix!r}); give a .usda, .usdc, .usd or "
                                    ".usdz scene")  # fmt: skip
        try:
            layers = open_layer_stack(Path(path))  # a missing sublayer is an error, not a warning and a gap
            stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
            del layers
        except SceneError as exc:
            raise PhysicsInputError(str(exc)) from exc
        except Tf.ErrorException as exc:
            raise PhysicsInputError(f"{path}: cannot be opened as USD ({usd_error_text(exc)}); check the file is "
                                    "valid USD") from exc
        if stage is None:
            raise PhysicsInputError(f"{path}: cannot be opened as USD; check the file is valid USD")
    label = stage_label(stage)
    if UsdGeom.StageHasAuthoredMetersPerUnit(stage):
        mpu = UsdGeom.GetStageMetersPerUnit(stage)
        if not math.isclose(mpu, 1.0):
            raise PhysicsInputError(
                f"{label}: metersPerUnit is {mpu}; author metersPerUnit = 1 (scene in metres) on the root layer"
            )
    else:
        warnings.warn(
            f"{label}: metersPerUnit is not authored; reading the scene as metres (USD's fallback would be "
            "centimetres). Author metersPerUnit = 1 on the root layer.",
            stacklevel=2,
        )
    if UsdPhysics.StageHasAuthoredKilogramsPerUnit(stage):
        kpu = UsdPhysics.GetStageKilogramsPerUnit(stage)
        if not math.isclose(kpu, 1.0):
            raise PhysicsInputError(
                f"{label}: kilogramsPerUnit is {kpu}; author kilogramsPerUnit = 1 (masses in kg) on the root layer"
            )
    return stage


def _is_rigid_body(prim: Usd.Prim) -> bool:
    if not prim.HasAPI(UsdPhysics.RigidBodyAPI):
        return False
    enabled = UsdPhysics.RigidBodyAPI(prim).GetRigidBodyEnabledAttr().Get()
    return enabled is None or bool(enabled)


def rigid_bodies(stage: Usd.Stage) -> list[str]:
    """Prim paths of all enabled rigid bodies (``UsdPhysics.RigidBodyAPI``), in stage traversal order."""
    return [str(p.GetPath()) for p in stage.Traverse() if _is_rigid_body(p)]


def resolve_object(stage: Usd.Stage, name: str) -> str:
    """Resolve an object given by prim path or by its name under ``/World/Objects`` to a rigid-body prim path.

    Raises:
        PhysicsInputError: No rigid body matches.
    """
    bodies = rigid_bodies(stage)
    candidates = [name] if name.startswith("/") else [f"{OBJECTS_ROOT}/{name}"]
    if not name.startswith("/"):
        candidates += [b for b in bodies if b.rsplit("/", 1)[-1] == name]
    for cand in candidates:
        if cand in bodies:
            return cand
    shown = ", ".join(bodies[:5]) + (" ..." if len(bodies) > 5 else "")
    raise PhysicsInputError(
        f"{stage_label(stage)}: no rigid body named {name!r}; use a prim path or a name under {OBJECTS_ROOT} "
        f"(rigid bodies: {shown or 'none'})"
    )


def supported_by(stage: Usd.Stage, path: str) -> str | None:
    """First target of ``rel holo:supportedBy`` on the prim (HoloRelationsAPI), or None when not authored."""
    prim = stage.GetPrimAtPath(path)
    rel = prim.GetRelationship(SUPPORTED_BY_REL) if prim else None
    if not rel:
        return None
    targets = rel.GetForwardedTargets()
    return str(targets[0]) if targets else None


def support_chain(stage: Usd.Stage, path: str) -> list[str]:
    """The rigid bodies below an object, nearest first, following ``holo:supportedBy`` until a non-rigid prim.

    The chain stops at the background (or any prim without RigidBodyAPI), which is static anyway.

    Raises:
        PhysicsInputError: The relations form a cycle.
    """
    bodies = set(rigid_bodies(stage))
    chain: list[str] = []
    seen = {path}
    parent = supported_by(stage, path)
    while parent is not None and parent in bodies:
        if parent in seen:
            raise PhysicsInputError(
                f"{stage_label(stage)}: holo:supportedBy relations form a cycle through {parent}; "
                "make the relations a tree rooted at the background"
            )
        seen.add(parent)
        chain.append(parent)
        parent = supported_by(stage, parent)
    return chain


def collider_prims(stage: Usd.Stage, path: str) -> list[Usd.Prim]:
    """Active collider prims (``CollisionAPI``) at or under ``path``."""
    root = stage.GetPrimAtPath(path)
    if not root:
        return []
    return [p for p in Usd.PrimRange(root) if p.HasAPI(UsdPhysics.CollisionAPI)]


def bound_physics_material(prim: Usd.Prim) -> UsdShade.Material | None:
    """The material bound to ``prim`` for purpose ``physics`` (inherited bindings included), or None."""
    material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial("physics")
    if material and material.GetPrim().HasAPI(UsdPhysics.MaterialAPI):
        return material
    return None


def read_material(prim: Usd.Prim, *, default_friction: float, default_restitution: float) -> BodyMaterial:
    """Friction and restitution for a collider prim from its bound physics material.

    Friction is the authored dynamic friction, else the authored static friction, else ``default_friction``
    (UsdPhysics' schema fallback of 0 would make an unauthored material frictionless). Restitution is the
    authored value, else ``default_restitution``.
    """
    material = bound_physics_material(prim)
    if material is None:
        return BodyMaterial(friction=default_friction, restitution=default_restitution, path=None)
    api = UsdPhysics.MaterialAPI(material.GetPrim())
    friction = default_friction
    for attr in (api.GetDynamicFrictionAttr(), api.GetStaticFrictionAttr()):
        if attr and attr.HasAuthoredValue():
            friction = float(attr.Get())
            break
    rest_attr = api.GetRestitutionAttr()
    restitution = float(rest_attr.Get()) if rest_attr and rest_attr.HasAuthoredValue() else default_restitution
    return BodyMaterial(friction=friction, restitution=restitution, path=str(material.GetPath()))


def body_damping(stage: Usd.Stage, path: str) -> tuple[float, float]:
    """``(linear, angular)`` damping in 1/s from HoloPhysicsAPI attributes; 0 where unauthored.

    Raises:
        PhysicsInputError: A damping value is negative or not finite.
    """
    prim = stage.GetPrimAtPath(path)
    values = []
    for name in (LINEAR_DAMPING_ATTR, ANGULAR_DAMPING_ATTR):
        attr = prim.GetAttribute(name)
        value = attr.Get() if attr else None
        value = 0.0 if value is None else float(value)
        if not math.isfinite(value) or value < 0.0:
            raise PhysicsInputError(
                f"{stage_label(stage)}: {path}.{name} = {value}; damping must be a finite value >= 0 (1/s)"
            )
        values.append(value)
    return values[0], values[1]


def world_mesh(stage: Usd.Stage, path: str, *, colliders: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """All triangles of the meshes at or under ``path`` in world coordinates.

    Args:
        stage: The stage.
        path: Prim path (object, background, or a single mesh).
        colliders: If True, use only collider meshes (``CollisionAPI``); otherwise use render meshes
            (those without ``CollisionAPI``), falling back to colliders when there are none.

    Returns:
        ``(points [N, 3], faces [F, 3])`` in world coordinates, metres; polygons are fan-triangulated.
    """
    root = stage.GetPrimAtPath(path)
    if not root:
        raise PhysicsInputError(f"{stage_label(stage)}: no prim at {path}; check the prim path")
    meshes = [p for p in Usd.PrimRange(root) if p.IsA(UsdGeom.Mesh)]
    chosen = [p for p in meshes if p.HasAPI(UsdPhysics.CollisionAPI) == colliders]
    if not chosen:
        chosen = meshes
    if not chosen:
        raise PhysicsInputError(f"{stage_label(stage)}: {path} has no UsdGeom.Mesh; author Geom or Collision meshes")
    cache = UsdGeom.XformCache(Usd.TimeCode.Default())
    pts_all, faces_all, offset = [], [], 0
    for prim in chosen:
        pts, faces = mesh_arrays(UsdGeom.Mesh(prim))
        mat = np.array(cache.GetLocalToWorldTransform(prim), dtype=np.float64)  # [4, 4] row-vector convention
        pts_w = pts @ mat[:3, :3] + mat[3, :3]
        pts_all.append(pts_w)
        faces_all.append(faces + offset)
        offset += len(pts)
    return np.concatenate(pts_all), np.concatenate(faces_all)


def mesh_arrays(mesh: UsdGeom.Mesh) -> tuple[np.ndarray, np.ndarray]:
    """``(points [N, 3] float64, faces [F, 3] int64)`` of a UsdGeom.Mesh in its own coordinates (fan-triangulated)."""
    data = read_mesh(mesh.GetPrim())
    return data.points, data.faces


def working_stage(stage: Usd.Stage) -> Usd.Stage:
    """A second stage on the same root layer with a fresh session layer as edit target.

    Edits made on it (deactivating bodies, removing RigidBodyAPI, swapping colliders) never reach the caller's
    stage or any file. The caller's session-layer opinions are copied over.
    """
    session = Sdf.Layer.CreateAnonymous("holousd_physics_session.usda")
    source_session = stage.GetSessionLayer()
    if source_session is not None and not source_session.empty:
        session.TransferContent(source_session)
    work = Usd.Stage.Open(stage.GetRootLayer(), session, stage.GetPathResolverContext(), Usd.Stage.LoadAll)
    work.SetEditTarget(Usd.EditTarget(session))
    return work


def make_static(stage: Usd.Stage, paths: Iterable[str]) -> None:
    """Remove RigidBodyAPI from ``paths`` on the stage's edit target so their colliders become static geometry."""
    for path in paths:
        prim = stage.GetPrimAtPath(path)
        prim.RemoveAPI(UsdPhysics.RigidBodyAPI)


def deactivate(stage: Usd.Stage, paths: Iterable[str]) -> None:
    """Deactivate ``paths`` on the stage's edit target (they and their colliders leave the simulation)."""
    for path in paths:
        stage.GetPrimAtPath(path).SetActive(False)


def replace_colliders(stage: Usd.Stage, path: str, parts: ColliderParts, approximation: str) -> None:
    """Swap the colliders of body ``path`` for ``parts`` on the stage's edit target.

    Existing collider prims are deactivated; new Mesh prims ``<path>/HoloColliderOverride/Part_###`` get
    CollisionAPI + MeshCollisionAPI with the given approximation (``"convexHull"`` or ``"none"``) and the
    physics material the first original collider had.
    """
    old = collider_prims(stage, path)
    material = bound_physics_material(old[0]) if old else None
    for prim in old:
        prim.SetActive(False)
    scope = UsdGeom.Scope.Define(stage, f"{path}/HoloColliderOverride")
    for i, (pts, faces) in enumerate(parts):
        mesh = author_collider_mesh(stage, f"{scope.GetPath()}/Part_{i:03d}", pts, faces, approximation)
        if material is not None:
            UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(
                material, UsdShade.Tokens.weakerThanDescendants, "physics"
            )


def author_collider_mesh(
    stage: Usd.Stage, path: str, points: np.ndarray, faces: np.ndarray, approximation: str
) -> UsdGeom.Mesh:
    """Define a guide-purpose triangle Mesh with CollisionAPI + MeshCollisionAPI(approximation) at ``path``."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([Gf.Vec3f(*map(float, p)) for p in np.asarray(points)])
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    mesh.CreateFaceVertexCountsAttr([3] * len(faces))
    mesh.CreateFaceVertexIndicesAttr([int(i) for i in faces.ravel()])
    set_normals(mesh, np.asarray(points, float), faces, smooth=False)  # hulls and slabs: flat faces
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreatePurposeAttr(UsdGeom.Tokens.guide)
    UsdPhysics.CollisionAPI.Apply(mesh.GetPrim())
    UsdPhysics.MeshCollisionAPI.Apply(mesh.GetPrim()).CreateApproximationAttr(approximation)
    return mesh


def check_paths(stage: Usd.Stage, paths: Sequence[str], what: str) -> None:
    """Raise PhysicsInputError naming the first of ``paths`` that is not a rigid body of ``stage``."""
    bodies = set(rigid_bodies(stage))
    for path in paths:
        if path not in bodies:
            raise PhysicsInputError(
                f"{stage_label(stage)}: {what} {path} is not a rigid body; pass prim paths of RigidBodyAPI prims"
            )
