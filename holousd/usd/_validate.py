"""Scene validation: every OpenUSD validator (pxr.UsdValidation) plus holousd's own rules.

Each problem names the prim (or layer) and says how to fix it. ``holousd validate`` exits 0 only when no
problem of severity 'error' or 'warning' is found.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdPhysics, UsdValidation, UsdVol

from holousd._errors import SceneError
from holousd.geometry._hulls import PHYSX_HULL_VERTEX_LIMIT
from holousd.usd._plugin import API_SCHEMAS, SCHEMA_VERSION
from holousd.usd._scene import BACKGROUND_PATH, OBJECTS_PATH, schema_version_of

__all__ = ["ValidationIssue", "ValidationReport", "validate"]


@dataclass(kw_only=True, frozen=True)
class ValidationIssue:
    """One problem found in a scene."""

    rule: str
    """Identifier of the rule: 'holousd:<rule>' or the name of the OpenUSD validator."""
    severity: str
    """'error', 'warning' or 'info'."""
    where: str
    """Prim path, property path or layer the problem is about."""
    message: str
    """What is wrong."""
    fix: str
    """How to fix it."""

    def __str__(self) -> str:
        return f"{self.severity}: {self.where}: {self.message} (fix: {self.fix}) [{self.rule}]"


@dataclass(kw_only=True)
class ValidationReport:
    """All problems found by :func:`validate`."""

    scene: str
    """Root layer of the validated scene."""
    issues: list[ValidationIssue] = field(default_factory=list)
    """Problems, in the order found."""

    @property
    def ok(self) -> bool:
        """True when no error or warning was found (info notes are allowed)."""
        return not any(i.severity in ("error", "warning") for i in self.issues)

    def to_dict(self) -> dict:
        """JSON-ready form: ``{"scene", "ok", "issues": [{"rule", "severity", "where", "message", "fix"}]}``."""
        return {"scene": self.scene, "ok": self.ok, "issues": [asdict(i) for i in self.issues]}


def _err(rule: str, where: str, message: str, fix: str) -> ValidationIssue:
    """An error-severity issue of holousd rule ``holousd:<rule>``."""
    return ValidationIssue(rule=f"holousd:{rule}", severity="error", where=where, message=message, fix=fix)


_SEVERITY = {
    UsdValidation.ValidationErrorType.Error: "error",
    UsdValidation.ValidationErrorType.Warn: "warning",
    UsdValidation.ValidationErrorType.Info: "info",
}


def _usd_validators(stage: Usd.Stage) -> list[ValidationIssue]:
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    issues = []
    for error in UsdValidation.ValidationContext(validators).Validate(stage):
        if error.HasNoError():
            continue
        sites = []
        for site in error.GetSites():
            if site.IsProperty():
                sites.append(str(site.GetProperty().GetPath()))
            elif site.IsPrim():
                sites.append(str(site.GetPrim().GetPath()))
            elif site.GetLayer():
                sites.append(site.GetLayer().identifier)
        validator = error.GetValidator()
        name = validator.GetMetadata().name if validator else error.GetName()
        issues.append(
            ValidationIssue(
                rule=f"{name}:{error.GetName()}",
                severity=_SEVERITY.get(error.GetType(), "error"),
                where=", ".join(sites) or stage.GetRootLayer().identifier,
                message=error.GetMessage(),
                fix="see the OpenUSD validator's documentation for this rule",
            )
        )
    return issues


def _metadata_rules(stage: Usd.Stage) -> list[ValidationIssue]:
    root = stage.GetRootLayer()
    issues = []

    def add(rule: str, message: str, fix: str) -> None:
        issues.append(_err(rule, root.identifier, message, fix))

    if not root.pseudoRoot.HasInfo("upAxis") or UsdGeom.GetStageUpAxis(stage) != UsdGeom.Tokens.z:
        add(
            "up-axis",
            'root layer does not author upAxis = "Z"',
            "UsdGeom.SetStageUpAxis(stage, 'Z') on the root layer (copy it into every new layer)",
        )
    if not root.pseudoRoot.HasInfo("metersPerUnit") or UsdGeom.GetStageMetersPerUnit(stage) != 1.0:
        add(
            "meters-per-unit",
            "root layer does not author metersPerUnit = 1 (Newton assumes 0.01 when missing)",
            "UsdGeom.SetStageMetersPerUnit(stage, 1.0) and author positions in metres",
        )
    if not root.pseudoRoot.HasInfo("kilogramsPerUnit") or UsdPhysics.GetStageKilogramsPerUnit(stage) != 1.0:
        add(
            "kilograms-per-unit",
            "root layer does not author kilogramsPerUnit = 1",
            "UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0) and author masses in kilograms",
        )
    default = stage.GetDefaultPrim()
    if not default or default.GetPath() != Sdf.Path("/World"):
        add("default-prim", "defaultPrim is not /World", "stage.SetDefaultPrim(stage.GetPrimAtPath('/World'))")
    version = schema_version_of(root)
    uses_holo = any(any(s.startswith("Holo") for s in p.GetAppliedSchemas()) for p in stage.Traverse())
    if version is None and uses_holo:
        add(
            "schema-version",
            "root layer has no customLayerData holousd.schemaVersion",
            f"set root.customLayerData = {{'holousd': {{'schemaVersion': {SCHEMA_VERSION}}}}}",
        )
    elif version is not None and version > SCHEMA_VERSION:
        add(
            "schema-version",
            f"written with holousd schema version {version}, newer than {SCHEMA_VERSION}",
            "upgrade holousd",
        )
    return issues


def _schema_rules(stage: Usd.Stage) -> list[ValidationIssue]:
    issues = []
    for prim in stage.Traverse():
        meta = prim.GetMetadata("apiSchemas")
        names = list(meta.GetAddedOrExplicitItems()) if meta else []
        for name in names:
            if name.startswith("Holo") and name not in API_SCHEMAS:
                issues.append(
                    _err(
                        "unknown-schema",
                        str(prim.GetPath()),
                        f"applies unknown holousd schema {name!r} (this release knows {', '.join(API_SCHEMAS)})",
                        "upgrade holousd, or remove the schema from the prim's apiSchemas",
                    )
                )
    return issues


def _support_rules(stage: Usd.Stage) -> list[ValidationIssue]:
    issues = []
    background = stage.GetPrimAtPath(BACKGROUND_PATH)
    objects_root = stage.GetPrimAtPath(OBJECTS_PATH)
    objects = [p for p in objects_root.GetChildren() if p.HasAPI("HoloNodeAPI")] if objects_root else []
    if objects and not background:
        issues.append(
            _err(
                "support-tree",
                str(BACKGROUND_PATH),
                "scene has objects but no background node to root the support tree",
                "SceneGraph.add_background()",
            )
        )
    parent_of: dict[Sdf.Path, Sdf.Path] = {}
    for prim in objects:
        where = str(prim.GetPath())
        beside = prim.GetRelationship("holo:beside")
        for other in beside.GetTargets() if beside else []:
            other_prim = stage.GetPrimAtPath(other)
            if not other_prim or not other_prim.HasAPI("HoloNodeAPI"):
                issues.append(
                    _err(
                        "dangling-relationship",
                        f"{where}.holo:beside",
                        f"targets {other}, which is not a node of the scene",
                        "remove the target or add the missing object",
                    )
                )
        rel = prim.GetRelationship("holo:supportedBy")
        targets = rel.GetTargets() if rel else []
        if len(targets) != 1:
            issues.append(
                _err(
                    "support-tree",
                    where,
                    f"has {len(targets)} holo:supportedBy targets, needs exactly one",
                    "SceneGraph.set_support(name, parent) with the node it rests on ('background' for the floor)",
                )
            )
            continue
        target = stage.GetPrimAtPath(targets[0])
        if not target or not target.HasAPI("HoloNodeAPI"):
            issues.append(
                _err(
                    "dangling-relationship",
                    f"{where}.holo:supportedBy",
                    f"targets {targets[0]}, which is not a node of the scene",
                    "retarget it to an existing object or /World/Background",
                )
            )
            continue
        parent_of[prim.GetPath()] = targets[0]
    reported: set[Sdf.Path] = set()
    for start in parent_of:
        seen = [start]
        node = start
        while node in parent_of:
            node = parent_of[node]
            if node in seen:
                cycle = seen[seen.index(node) :]
                if not reported.intersection(cycle):
                    reported.update(cycle)
                    chain = " -> ".join(str(p) for p in [*cycle, node])
                    issues.append(
                        _err(
                            "support-cycle",
                            str(node),
                            f"support relations form a cycle: {chain}",
                            "make one object of the cycle rest on another node or the background",
                        )
                    )
                break
            seen.append(node)
    return issues


def _physics_rules(stage: Usd.Stage) -> list[ValidationIssue]:
    issues = []
    objects_root = stage.GetPrimAtPath(OBJECTS_PATH)
    objects = [p for p in objects_root.GetChildren() if p.HasAPI("HoloNodeAPI")] if objects_root else []
    for prim in objects:
        where = str(prim.GetPath())
        if not prim.HasAPI(UsdPhysics.RigidBodyAPI):
            issues.append(
                _err(
                    "rigid-body",
                    where,
                    "object has no UsdPhysics.RigidBodyAPI",
                    "SceneGraph.set_physics(name, PhysicsProps(mass=...))",
                )
            )
        mass = UsdPhysics.MassAPI(prim).GetMassAttr().Get() if prim.HasAPI(UsdPhysics.MassAPI) else None
        if not mass or mass <= 0:
            issues.append(
                _err(
                    "mass",
                    where,
                    "object has no positive mass authored",
                    "SceneGraph.set_physics(name, PhysicsProps(mass=...)) in kilograms",
                )
            )
        if not any(p.HasAPI(UsdPhysics.CollisionAPI) for p in Usd.PrimRange(prim)):
            issues.append(
                _err(
                    "collider",
                    where,
                    "object has no collider (no prim with UsdPhysics.CollisionAPI)",
                    "SceneGraph.set_collider(name, Collider(...))",
                )
            )
    background = stage.GetPrimAtPath(BACKGROUND_PATH)
    if background and not any(p.HasAPI(UsdPhysics.CollisionAPI) for p in Usd.PrimRange(background)):
        issues.append(
            _err(
                "collider",
                str(BACKGROUND_PATH),
                "background has no collider: objects would fall forever",
                "SceneGraph.set_collider('background', Collider(approximation='none', ...))",
            )
        )
    return issues


def _asset_rules(stage: Usd.Stage) -> list[ValidationIssue]:
    issues = []
    for prim in stage.Traverse():
        if prim.HasAPI("HoloSdfAPI"):
            asset = prim.GetAttribute("holo:sdf:file").Get()
            if asset is None or not asset.resolvedPath:
                issues.append(
                    _err(
                        "asset",
                        f"{prim.GetPath()}.holo:sdf:file",
                        f"SDF file {asset.path if asset else '<unset>'!r} cannot be resolved",
                        "restore the assets/ folder beside the layer that wrote it, or re-run that stage",
                    )
                )
        if prim.GetName() == "Splats" and prim.GetParent().HasAPI("HoloNodeAPI"):
            if not prim.IsA(UsdVol.ParticleField3DGaussianSplat):
                issues.append(
                    _err(
                        "asset",
                        str(prim.GetPath()),
                        "Splats prim is not a ParticleField3DGaussianSplat (its .usdc reference did not resolve?)",
                        "restore the assets/ folder beside the layer that wrote it, or rewrite the splats",
                    )
                )
                continue
            issues.extend(_splat_rules(stage, prim))
    return issues


def _splat_rules(stage: Usd.Stage, prim: Usd.Prim) -> list[ValidationIssue]:
    gs = UsdVol.ParticleField3DGaussianSplat(prim)

    def length(attr: Usd.Attribute) -> int | None:
        value = attr.Get() if attr else None
        return None if value is None else len(value)

    n = length(gs.GetPositionsAttr()) or 0
    degree = gs.GetRadianceSphericalHarmonicsDegreeAttr().Get()
    k = (int(degree) + 1) ** 2 if degree is not None else 1
    expected = {
        "orientations": (gs.GetOrientationsAttr(), n),
        "scales": (gs.GetScalesAttr(), n),
        "opacities": (gs.GetOpacitiesAttr(), n),
        "radiance:sphericalHarmonicsCoefficients": (gs.GetRadianceSphericalHarmonicsCoefficientsAttr(), n * k),
    }
    if prim.HasAPI("HoloGaussianOnMeshAPI"):
        for name in ("faceIndex", "barycentric", "normalOffset", "inPlaneRotation", "inPlaneScale"):
            expected[f"holo:gom:{name}"] = (prim.GetAttribute(f"holo:gom:{name}"), n)
    issues = []
    for name, (attr, want) in expected.items():
        got = length(attr)
        if got != want:
            issues.append(
                _err(
                    "splat-arrays",
                    f"{prim.GetPath()}.{name}",
                    f"has {got if got is not None else 'no'} elements, expected {want} ({n} splats)",
                    "rewrite the splats with SceneGraph.set_gaussians()",
                )
            )
    if prim.HasAPI("HoloGaussianOnMeshAPI"):
        targets = prim.GetRelationship("holo:gom:mesh").GetTargets()
        mesh = stage.GetPrimAtPath(targets[0]) if targets else None
        if not mesh or not mesh.IsA(UsdGeom.Mesh):
            issues.append(
                _err(
                    "splat-binding",
                    f"{prim.GetPath()}.holo:gom:mesh",
                    "bound splats do not target an existing mesh",
                    "target the node's Geom mesh (SceneGraph.set_gaussians does this)",
                )
            )
        else:
            counts = UsdGeom.Mesh(mesh).GetFaceVertexCountsAttr().Get() or []
            faces = prim.GetAttribute("holo:gom:faceIndex").Get()
            if faces is not None and len(faces) and int(np.max(faces)) >= len(counts):
                issues.append(
                    _err(
                        "splat-binding",
                        f"{prim.GetPath()}.holo:gom:faceIndex",
                        f"face index {int(np.max(faces))} but {mesh.GetPath()} has {len(counts)} faces",
                        "refit the splats on the current mesh (stage s3_refine)",
                    )
                )
    return issues


def validate(stage: Usd.Stage) -> ValidationReport:
    """Run all OpenUSD validators and holousd's rules on ``stage``.

    holousd's rules: root-layer metadata (upAxis Z, metersPerUnit 1, kilogramsPerUnit 1, defaultPrim /World,
    schema version); support relations form one tree rooted at the background (exactly one parent each, no
    cycles, no dangling targets); each object has a rigid body, a positive mass and a collider; SDF and splat
    assets resolve; splat array lengths agree with each other and with the bound mesh; every object's rendered
    mesh is watertight, its collider reaches at most 1 cm outside it, and no two objects' meshes overlap by more
    than 1 cm^3; a note (info) where a collider part's hull has more vertices than PhysX cooks by default (64).
    """
    report = ValidationReport(scene=stage.GetRootLayer().identifier)
    for rules in (_usd_validators, _metadata_rules, _schema_rules, _support_rules, _physics_rules, _asset_rules,
                  _geometry_rules):  # fmt: skip
        report.issues.extend(rules(stage))
    return report


MAX_COLLIDER_REACH = 0.01
"""A collider may reach at most this far outside its object's rendered mesh, metres."""
MAX_OVERLAP = 1e-6
"""Two objects' rendered meshes may overlap by at most this volume, m^3 (1 cm^3)."""
MAX_HULL_VERTICES = PHYSX_HULL_VERTEX_LIMIT
"""Collider parts with more hull vertices than this are noted (see :data:`PHYSX_HULL_VERTEX_LIMIT`)."""


def _geometry_rules(stage: Usd.Stage) -> list[ValidationIssue]:
    """One geometry per object: a watertight rendered mesh, a collider that stays within
    :data:`MAX_COLLIDER_REACH` of it, and no two objects' meshes overlapping by more than :data:`MAX_OVERLAP`."""
    from holousd.geometry._contact import collider_reach, overlap
    from holousd.usd._scene import SceneGraph

    scene = SceneGraph(stage)
    world: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    issues = []
    for name in scene.objects():
        prim = scene.stage.GetPrimAtPath(scene.node_info(name).path)
        try:
            mesh = scene.get_mesh(name)
        except SceneError:
            continue  # _physics_rules / the schema rules say what is missing
        if len(mesh.faces) == 0:
            continue
        if not _watertight(mesh):
            issues.append(_err("watertight", f"{prim.GetPath()}/Geom", "the rendered mesh is not watertight (it "
                               "has holes or non-manifold edges), so it has no volume, mass or inside",
                               "close it (re-mesh its SDF) before simulating"))  # fmt: skip
        try:
            collider = scene.get_collider(name)
        except SceneError:
            collider = None
        if collider is not None and collider.approximation != "none":
            reach = collider_reach([(p.points, p.faces) for p in collider.parts], (mesh.points, mesh.faces),
                                   samples=500, hulls=True)  # fmt: skip
            counts = [_hull_vertices(part.points) for part in collider.parts]
            many = [c for c in counts if c > MAX_HULL_VERTICES]
            if many:  # one note per object
                issues.append(ValidationIssue(
                    rule="holousd:hull-vertices", severity="info", where=f"{prim.GetPath()}/Collision",
                    message=f"{len(many)} of {len(counts)} collider parts are hulls of more than {MAX_HULL_VERTICES} "
                            f"vertices (up to {max(many)}): PhysX cooks at most {MAX_HULL_VERTICES} by default and "
                            "simulates simpler hulls of its choosing",
                    fix="split those parts, or run holousd's physics set-up again (its parts keep within "
                        f"{MAX_HULL_VERTICES})"))  # fmt: skip
            if reach > MAX_COLLIDER_REACH:
                issues.append(_err("collider-reach", f"{prim.GetPath()}/Collision",
                                   f"the collider reaches {100 * reach:.1f} cm outside the rendered mesh (at most "
                                   f"{100 * MAX_COLLIDER_REACH:.0f} cm): the simulated object is not the one shown",
                                   "derive the collider from the mesh (its hull, or a decomposition of it), or "
                                   "edit the mesh itself"))  # fmt: skip
        world[name] = (scene.get_pose(name).apply(mesh.points), mesh.faces)
    names = sorted(world)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            both = overlap(world[a], world[b])
            if both.volume_m3 > MAX_OVERLAP:
                issues.append(_err("overlap", f"{OBJECTS_PATH}/{a}, {OBJECTS_PATH}/{b}",
                                   f"the rendered meshes of {a} and {b} overlap by {1e6 * both.volume_m3:.1f} cm^3 "
                                   f"(up to {100 * both.depth_m:.1f} cm deep): a simulator throws them apart",
                                   "cut them apart where they meet (holousd reconstruct's physics set-up does)"))
    return issues


def _hull_vertices(points: np.ndarray) -> int:
    """How many vertices the convex hull of ``points`` has (as many as there are points when qhull finds none)."""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) <= MAX_HULL_VERTICES:
        return len(pts)
    try:
        return len(ConvexHull(pts).vertices)
    except QhullError:
        return len(pts)


def _watertight(mesh) -> bool:  # noqa: ANN001 - MeshData
    import trimesh

    return bool(trimesh.Trimesh(vertices=mesh.points, faces=mesh.faces, process=False).is_watertight)
