"""Tiny UsdPhysics scenes for the physics tests, authored with pxr directly (scene conventions of ARCHITECTURE §1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics, UsdShade


def box(hx: float, hy: float, hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed box mesh centred at the origin: (points [8, 3], faces [12, 3]), outward winding."""
    pts = np.array([[sx * hx, sy * hy, sz * hz] for sz in (-1, 1) for sy in (-1, 1) for sx in (-1, 1)], float)
    # fmt: off
    faces = np.array(
        [
            [0, 2, 1], [1, 2, 3],  # -z
            [4, 5, 6], [5, 7, 6],  # +z
            [0, 1, 4], [1, 5, 4],  # -y
            [2, 6, 3], [3, 6, 7],  # +y
            [0, 4, 2], [2, 4, 6],  # -x
            [1, 3, 5], [3, 7, 5],  # +x
        ],
        dtype=np.int64,
    )
    # fmt: on
    return pts, faces


def bowl(radius: float = 0.1, wall: float = 0.012, segments: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Open hemispherical bowl with a flat foot, rim at z = 0, foot at z = -0.8 * radius (concave, watertight)."""
    import manifold3d as mf

    shell = mf.Manifold.sphere(radius, segments) - mf.Manifold.sphere(radius - wall, segments)
    lower = mf.Manifold.cube([4 * radius] * 3, True).translate([0, 0, -2 * radius])
    above_foot = mf.Manifold.cube([4 * radius] * 3, True).translate([0, 0, 2 * radius - 0.8 * radius])
    mesh = ((shell ^ lower) ^ above_foot).to_mesh()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


def tray(half: float = 0.15, height: float = 0.08, wall: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Open box (a tray) standing on z = 0: outer half extent ``half``, walls and floor ``wall`` thick."""
    import manifold3d as mf

    outer = mf.Manifold.cube([2 * half, 2 * half, height], True).translate([0, 0, height / 2])
    inner = mf.Manifold.cube([2 * (half - wall), 2 * (half - wall), height], True).translate([0, 0, wall + height / 2])
    mesh = (outer - inner).to_mesh()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


@dataclass(kw_only=True)
class Obj:
    """One rigid object of a fixture scene."""

    name: str
    mesh: tuple[np.ndarray, np.ndarray]
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)  # w, x, y, z
    collider: str | list[tuple[np.ndarray, np.ndarray]] = "hull"  # "hull", "mesh" or explicit parts
    mass: float | None = 1.0
    supported_by: str | None = None  # object name, or None for the background
    linear_damping: float | None = None
    angular_damping: float | None = None
    material: str = "Wood"


@dataclass(kw_only=True)
class Material:
    """A physics material under /World/Materials."""

    name: str
    friction: float = 0.5
    restitution: float = 0.0
    density: float = 500.0


def _mesh(stage: Usd.Stage, path: str, pts: np.ndarray, faces: np.ndarray, approx: str | None) -> UsdGeom.Mesh:
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr([Gf.Vec3f(*map(float, p)) for p in pts])
    m.CreateFaceVertexCountsAttr([3] * len(faces))
    m.CreateFaceVertexIndicesAttr([int(i) for i in np.asarray(faces).ravel()])
    if approx is not None:
        m.CreatePurposeAttr(UsdGeom.Tokens.guide)
        UsdPhysics.CollisionAPI.Apply(m.GetPrim())
        UsdPhysics.MeshCollisionAPI.Apply(m.GetPrim()).CreateApproximationAttr(approx)
    return m


def make_scene(
    objects: list[Obj],
    *,
    path: str | None = None,
    materials: list[Material] | None = None,
    floor_half: float = 1.0,
    meters_per_unit: float | None = 1.0,
    extra_background: list[tuple[np.ndarray, np.ndarray]] | None = None,
) -> Usd.Stage:
    """A scene with a floor slab (top at z = 0, static triangle-mesh collider) and the given objects.

    Args:
        objects: Rigid objects under /World/Objects.
        path: Save to this file when given (else in memory).
        materials: Physics materials (default: Wood, friction 0.5).
        floor_half: Half extent of the square floor, m.
        meters_per_unit: Stage metersPerUnit; None leaves it unauthored.
        extra_background: Meshes (world coordinates) merged into the background's single triangle mesh.
    """
    stage = Usd.Stage.CreateNew(path) if path else Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    if meters_per_unit is not None:
        UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    scene = UsdPhysics.Scene.Define(stage, "/World/PhysicsScene")
    scene.CreateGravityDirectionAttr(Gf.Vec3f(0, 0, -1))
    scene.CreateGravityMagnitudeAttr(9.81)
    mats = {}
    for spec in materials or [Material(name="Wood")]:
        mat = UsdShade.Material.Define(stage, f"/World/Materials/{spec.name}")
        api = UsdPhysics.MaterialAPI.Apply(mat.GetPrim())
        api.CreateDynamicFrictionAttr(spec.friction)
        api.CreateStaticFrictionAttr(spec.friction)
        api.CreateRestitutionAttr(spec.restitution)
        api.CreateDensityAttr(spec.density)
        mats[spec.name] = mat
    UsdGeom.Xform.Define(stage, "/World/Background")
    fp, ff = box(floor_half, floor_half, 0.05)
    fp[:, 2] -= 0.05
    for pts, faces in extra_background or []:
        ff = np.concatenate([ff, np.asarray(faces) + len(fp)])
        fp = np.concatenate([fp, pts])
    _mesh(stage, "/World/Background/Geom", fp, ff, "none")
    UsdGeom.Xform.Define(stage, "/World/Objects")
    for obj in objects:
        opath = f"/World/Objects/{obj.name}"
        xf = UsdGeom.Xform.Define(stage, opath)
        xf.AddTranslateOp().Set(Gf.Vec3d(*obj.position))
        w, x, y, z = obj.orientation
        xf.AddOrientOp().Set(Gf.Quatf(w, x, y, z).GetNormalized())
        prim = xf.GetPrim()
        UsdPhysics.RigidBodyAPI.Apply(prim)
        mass_api = UsdPhysics.MassAPI.Apply(prim)
        if obj.mass is not None:
            mass_api.CreateMassAttr(obj.mass)
        pts, faces = obj.mesh
        _mesh(stage, f"{opath}/Geom", pts, faces, None)
        if obj.collider == "hull":
            _mesh(stage, f"{opath}/Collision", pts, faces, "convexHull")
        elif obj.collider == "mesh":
            _mesh(stage, f"{opath}/Collision", pts, faces, "none")
        else:
            UsdGeom.Scope.Define(stage, f"{opath}/Collision")
            for i, (pp, pf) in enumerate(obj.collider):
                _mesh(stage, f"{opath}/Collision/Part_{i:03d}", pp, pf, "convexHull")
        UsdShade.MaterialBindingAPI.Apply(prim).Bind(
            mats[obj.material], UsdShade.Tokens.weakerThanDescendants, "physics"
        )
        if obj.linear_damping is not None or obj.angular_damping is not None:
            prim.AddAppliedSchema("HoloPhysicsAPI")
            prim.CreateAttribute("holo:physics:linearDamping", Sdf.ValueTypeNames.Float).Set(obj.linear_damping or 0.0)
            prim.CreateAttribute("holo:physics:angularDamping", Sdf.ValueTypeNames.Float).Set(
                obj.angular_damping or 0.0
            )
        prim.AddAppliedSchema("HoloRelationsAPI")
        parent = "/World/Background" if obj.supported_by is None else f"/World/Objects/{obj.supported_by}"
        prim.CreateRelationship("holo:supportedBy", custom=False).SetTargets([Sdf.Path(parent)])
    if path:
        stage.Save()
    return stage
