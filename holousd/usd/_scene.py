"""The SceneGraph facade: a holousd scene graph is a USD stage, read and written through this class.

Layout (ARCHITECTURE.md §1)::

    /World                      defaultPrim; upAxis Z, metersPerUnit 1, kilogramsPerUnit 1
      /World/PhysicsScene       UsdPhysics.Scene, gravity -Z 9.81
      /World/Background         HoloNodeAPI(role=background), static collider
      /World/Objects/<name>     Xform = object state (translate + orient), HoloNodeAPI, RigidBodyAPI, MassAPI, ...
         Geom                   UsdGeom.Mesh in object coordinates
         Collision              Scope of collider meshes Part_000, Part_001, ... (CollisionAPI, MeshCollisionAPI)
         Splats                 reference to a per-object .usdc holding a UsdVol.ParticleField3DGaussianSplat
      /World/Materials          physics materials (UsdShade.Material + UsdPhysics.MaterialAPI)
      /World/Looks              visual materials (UsdPreviewSurface reading each mesh's primvars:displayColor)

Heavy data (SDF grids, splats) goes to files under ``assets/<layer stem>/`` beside the layer being written, so
the scene file stays readable and every stage's assets stay on disk.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, UsdShade, UsdVol, Vt

from holousd._atomic import atomic_path
from holousd._errors import InvalidDataError, SceneError, SchemaVersionError
from holousd.usd._layers import (
    layer_path,
    new_layer_over,
    open_layer_stack,
    save_layer,
    sublayer_files,
    usd_error_text,
)
from holousd.usd._plugin import SCHEMA_VERSION
from holousd.usd._types import (
    CameraData,
    Collider,
    Energies,
    GaussianSplats,
    GeometryRecord,
    MeshData,
    NodeInfo,
    PhysicsProps,
    Pose,
    SdfField,
)

__all__ = [
    "BACKGROUND",
    "CAMERAS_PATH",
    "BACKGROUND_PATH",
    "MATERIALS_PATH",
    "OBJECTS_PATH",
    "PHYSICS_SCENE_PATH",
    "WORLD_PATH",
    "NodeSummary",
    "SceneGraph",
    "SceneSummary",
    "read_mesh",
    "schema_version_of",
]

WORLD_PATH = Sdf.Path("/World")
PHYSICS_SCENE_PATH = Sdf.Path("/World/PhysicsScene")
BACKGROUND_PATH = Sdf.Path("/World/Background")
OBJECTS_PATH = Sdf.Path("/World/Objects")
MATERIALS_PATH = Sdf.Path("/World/Materials")
LOOKS_PATH = Sdf.Path("/World/Looks")
CAMERAS_PATH = Sdf.Path("/World/Cameras")
BACKGROUND = "background"
"""Node name of the background (the root of the support tree)."""

_GRAVITY = 9.81
_FILM_UNITS_PER_PIXEL = 0.1
"""Camera film scale: one pixel is 0.1 film units (tenths of a millimetre), so apertures read like a sensor's."""
_CV_TO_USD_CAMERA = np.diag([1.0, -1.0, -1.0, 1.0])
"""OpenCV camera axes (x right, y down, z forward) -> USD camera axes (x right, y up, looking down -z)."""
_SDF_KEY = "sdf"


def schema_version_of(layer: Sdf.Layer) -> int | None:
    """Return the holousd schema version recorded in ``layer``'s customLayerData, or None if absent."""
    data = layer.customLayerData.get("holousd")
    if not isinstance(data, dict) or "schemaVersion" not in data:
        return None
    return int(data["schemaVersion"])


@dataclass(kw_only=True)
class NodeSummary:
    """One row of :meth:`SceneGraph.summary`."""

    name: str
    """Node name ('background' or the object name)."""
    path: str
    """Prim path."""
    role: str
    """'background' or 'object'."""
    instance_id: int
    """Instance id in the observations' masks."""
    supported_by: str | None
    """Name of the support parent (None for the background or when missing)."""
    beside: list[str]
    """Names of touching siblings."""
    mesh_faces: int
    """Triangle count of the Geom mesh (0 when absent)."""
    sdf_resolution: list[int] | None
    """SDF grid resolution, or None when the node has no SDF."""
    splats: int
    """Number of Gaussian splats (0 when absent)."""
    mass_kg: float | None
    """Authored mass, or None."""
    dynamic: bool = False
    """True for an enabled rigid body (simulated, whether or not it has a mass); False for a static collider."""
    collider: str | None
    """Collider approximation ('convexHull', 'convexDecomposition', 'none') or None when there is none."""
    collider_parts: int
    """Number of collider meshes."""
    fit_shift_cm: float | None = None
    """Distance moved from the pose the fit gave, cm (None: no record; ``HoloGeometryAPI``)."""
    collider_reach_cm: float | None = None
    """How far the collider reaches outside the rendered mesh, cm (None: no record)."""
    penetration_cm: float | None = None
    """Deepest overlap of the rendered mesh with another node's, cm (None: no record)."""


@dataclass(kw_only=True)
class SceneSummary:
    """What :meth:`SceneGraph.summary` reports (``holousd info``)."""

    path: str
    """Root layer of the scene."""
    layers: list[str]
    """Layer stack, strongest first."""
    up_axis: str
    """Stage up axis."""
    meters_per_unit: float
    """Stage linear unit."""
    kilograms_per_unit: float
    """Stage mass unit."""
    schema_version: int | None
    """holousd schema version recorded in the root layer."""
    nodes: list[NodeSummary] = field(default_factory=list)
    """One entry per node, background first."""

    @property
    def total_splats(self) -> int:
        """Sum of splat counts over all nodes."""
        return sum(n.splats for n in self.nodes)


def _vec3f_array(values: np.ndarray) -> Vt.Vec3fArray:
    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(values, dtype=np.float32))


def mesh_normals(points: np.ndarray, faces: np.ndarray, *, smooth: bool = True) -> np.ndarray:
    """Unit normals of a triangle mesh: per vertex, the area-weighted mean of its faces' (``smooth``), or one per
    face (a convex hull's flat faces); float32. A degenerate face or a vertex without area gets +z."""
    points, faces = np.asarray(points, np.float64), np.asarray(faces, np.int64).reshape(-1, 3)
    tri = points[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # |cross| = twice the area: area-weighted
    if smooth:
        summed = np.zeros_like(points)
        for k in range(3):
            np.add.at(summed, faces[:, k], cross)
        cross = summed
    length = np.linalg.norm(cross, axis=1, keepdims=True)
    out = np.where(length > 1e-20, cross / np.maximum(length, 1e-20), np.array([0.0, 0.0, 1.0]))
    return out.astype(np.float32)


def set_normals(geom: UsdGeom.Mesh, points: np.ndarray, faces: np.ndarray, *, smooth: bool = True) -> None:
    """Author ``normals`` on a triangle mesh (``vertex`` interpolation when ``smooth``, else ``uniform``: one per
    face): a mesh with subdivision scheme ``none`` shows its facets without them, and validators require them."""
    geom.CreateNormalsAttr().Set(Vt.Vec3fArray.FromNumpy(mesh_normals(points, faces, smooth=smooth)))
    geom.SetNormalsInterpolation(UsdGeom.Tokens.vertex if smooth else UsdGeom.Tokens.uniform)


def _set_indexed(primvar: UsdGeom.Primvar, values: np.ndarray) -> None:
    """Author ``values`` [N, C] (float32) as an indexed primvar: each distinct value once, and an index per entry."""
    values = np.ascontiguousarray(values, dtype=np.float32)
    distinct, index = np.unique(values, axis=0, return_inverse=True)
    array = Vt.Vec3fArray if values.shape[1] == 3 else Vt.Vec2fArray
    primvar.Set(array.FromNumpy(np.ascontiguousarray(distinct)))
    primvar.SetIndices(Vt.IntArray.FromNumpy(index.reshape(-1).astype(np.int32)))


def _relative_asset(target: Path, layer: Sdf.Layer) -> str:
    anchor = layer_path(layer)
    assert anchor is not None
    rel = os.path.relpath(target, anchor.parent).replace(os.sep, "/")
    return rel if rel.startswith(".") else f"./{rel}"


def _triangulate(counts: np.ndarray, indices: np.ndarray, where: str) -> np.ndarray:
    """Fan-triangulate a polygon mesh given as face vertex counts and indices -> [F, 3]."""
    if counts.size == 0:
        return np.zeros((0, 3), dtype=np.int64)
    if np.all(counts == 3):
        if indices.size != counts.size * 3:
            raise SceneError(f"{where}: faceVertexIndices has {indices.size} entries, expected {counts.size * 3}")
        return indices.reshape(-1, 3).astype(np.int64)
    if counts.min() < 3 or counts.sum() != indices.size:
        raise SceneError(f"{where}: faceVertexCounts and faceVertexIndices disagree; re-export the mesh")
    tris = []
    start = 0
    for count in counts:
        face = indices[start : start + count]
        tris.extend((face[0], face[i], face[i + 1]) for i in range(1, count - 1))
        start += count
    return np.asarray(tris, dtype=np.int64)


def read_mesh(prim: Usd.Prim, *, where: str | None = None) -> MeshData:
    """Read a UsdGeom.Mesh prim as a triangle mesh in its own coordinates (polygons fan-triangulated).

    Args:
        prim: A UsdGeom.Mesh prim (any USD scene, not only holousd's).
        where: What to name in error messages (default: the prim path).

    Raises:
        SceneError: points or faces are missing or inconsistent.
    """
    where = where or str(prim.GetPath())
    geom = UsdGeom.Mesh(prim)
    points = geom.GetPointsAttr().Get()
    counts = geom.GetFaceVertexCountsAttr().Get()
    indices = geom.GetFaceVertexIndicesAttr().Get()
    if points is None or counts is None or indices is None:
        raise SceneError(f"{where}: mesh has no points or faces authored; author points, faceVertexCounts/Indices")
    faces = _triangulate(np.asarray(counts, dtype=np.int64), np.asarray(indices, dtype=np.int64), where)
    try:
        return MeshData(points=np.asarray(points, dtype=np.float64), faces=faces)
    except InvalidDataError as exc:
        raise SceneError(f"{where}: {exc}") from exc


class SceneGraph:
    """A holousd scene graph: a thin, typed facade over a ``Usd.Stage``.

    Create one with :meth:`create` or :meth:`open`; the raw stage stays available as :attr:`stage` for anything
    the facade does not cover. All writes go to the stage's current edit target (the root layer unless a
    stage transform or :meth:`edit` pushed a new one).

    Args:
        stage: An open stage laid out as described in this module's docstring.
        provenance: Name recorded in ``holo:node:provenance`` of every node this SceneGraph writes.
    """

    def __init__(self, stage: Usd.Stage, *, provenance: str = "user") -> None:
        self._stage = stage
        self.provenance = provenance
        """Name recorded as the writer of every node this SceneGraph touches."""

    # ------------------------------------------------------------------ creation / files
    @classmethod
    def create(
        cls, path: str | os.PathLike[str] | None = None, *, overwrite: bool = False, provenance: str = "user"
    ) -> SceneGraph:
        """Create a new scene: metadata, /World, /World/PhysicsScene, /World/Objects, /World/Materials.

        Args:
            path: File the scene will be saved to (:meth:`save`); None keeps it in memory (then SDF grids and
                splats, which live in files beside the layer, cannot be written).
            overwrite: Allow ``path`` to exist already (it is only replaced when :meth:`save` succeeds).
            provenance: See :class:`SceneGraph`.
        """
        if path is None:
            layer = Sdf.Layer.CreateAnonymous("holousd.usda")
        else:
            path = Path(path).absolute()
            if path.exists() and not overwrite:
                raise SceneError(f"{path} already exists: pass overwrite=True or choose another path")
            file_format = Sdf.FileFormat.FindByExtension(path.suffix.lstrip("."))
            if file_format is None:
                raise SceneError(f"{path}: unknown scene extension; use .usda, .usdc or .usd")
            layer = Sdf.Layer.Find(str(path))
            if layer is not None:
                layer.Clear()
            else:
                layer = Sdf.Layer.New(file_format, str(path))
        stage = Usd.Stage.Open(layer)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
        layer.customLayerData = {"holousd": {"schemaVersion": SCHEMA_VERSION}}
        world = UsdGeom.Xform.Define(stage, WORLD_PATH)
        stage.SetDefaultPrim(world.GetPrim())
        scene = UsdPhysics.Scene.Define(stage, PHYSICS_SCENE_PATH)
        scene.CreateGravityDirectionAttr(Gf.Vec3f(0.0, 0.0, -1.0))
        scene.CreateGravityMagnitudeAttr(_GRAVITY)
        UsdGeom.Scope.Define(stage, OBJECTS_PATH)
        UsdGeom.Scope.Define(stage, MATERIALS_PATH)
        return cls(stage, provenance=provenance)

    @classmethod
    def open(cls, path: str | os.PathLike[str], *, provenance: str = "user") -> SceneGraph:
        """Open a scene file, checking that it is readable USD of a schema version this release knows.

        Raises:
            SceneError: the file is missing, not USD, or corrupt.
            SchemaVersionError: the scene was written by a newer holousd.
        """
        path = Path(path)
        if not path.is_file():
            raise SceneError(f"{path}: no such file; check the path (a scene is a .usda/.usdc/.usd/.usdz file)")
        if Sdf.FileFormat.FindByExtension(path.suffix.lstrip(".")) is None:
            raise SceneError(f"{path}: not a USD file (extension {path.suffix!r}); give a .usda, .usdc, .usd or .usdz")
        try:
            layers = open_layer_stack(path)  # held open, so that USD does not read them twice
            stage = Usd.Stage.Open(str(path))
            del layers
        except Tf.ErrorException as exc:
            raise SceneError(f"{path}: cannot be read as USD ({usd_error_text(exc)}); is the file corrupt or "
                             "truncated? Restore it or re-export it") from exc
        if stage is None:
            raise SceneError(f"{path}: cannot be read as USD; is the file corrupt?")
        version = schema_version_of(stage.GetRootLayer())
        if version is not None and version > SCHEMA_VERSION:
            raise SchemaVersionError(
                f"{path}: written with holousd schema version {version}, this holousd reads up to "
                f"{SCHEMA_VERSION}; upgrade holousd (pip install -U holousd)"
            )
        return cls(stage, provenance=provenance)

    @property
    def stage(self) -> Usd.Stage:
        """The underlying USD stage."""
        return self._stage

    @property
    def root_layer(self) -> Sdf.Layer:
        """The stage's root layer (the strongest stage or edit layer)."""
        return self._stage.GetRootLayer()

    @property
    def path(self) -> Path | None:
        """File of the root layer, or None when the scene is in memory."""
        return layer_path(self.root_layer)

    def save(self, path: str | os.PathLike[str] | None = None) -> Path:
        """Write the edit-target layer atomically and return its path.

        Args:
            path: Only for an in-memory scene: the file to write it to.
        """
        layer = self._stage.GetEditTarget().GetLayer()
        if path is not None and not layer.anonymous:
            if Path(path).absolute() != layer_path(layer):
                raise SceneError(
                    f"{path}: a file-backed scene saves to its own file ({layer_path(layer)}); "
                    "use flatten() to write a copy elsewhere"
                )
            path = None
        return save_layer(layer, path)

    def flatten(self, path: str | os.PathLike[str]) -> Path:
        """Write the composed scene (all layers and references merged) to one file, atomically."""
        flat = self._stage.Flatten()
        return save_layer(flat, path, split=False)

    # ------------------------------------------------------------------ layers
    def push_layer(self, path: str | os.PathLike[str], *, provenance: str | None = None, replace: bool = False) -> None:
        """Stack a new layer at ``path`` over the current root layer and make it the root and edit target.

        This is how a stage transform starts (write only what changes, then :meth:`save`). If ``path`` already
        holds a layer that sublayers the current root, it is reopened and writes append to it, unless
        ``replace`` is True: then it starts empty and replaces the file on :meth:`save`.

        Args:
            path: File of the new layer.
            provenance: Writer name recorded on the nodes written from now on (default: the file's stem).
            replace: Start from an empty layer even if ``path`` exists.
        """
        path = Path(path).absolute()
        base = self.root_layer
        base_file = layer_path(base)
        if path.exists() and not replace:
            try:
                existing = Sdf.Layer.FindOrOpen(str(path))
            except Tf.ErrorException as exc:
                raise SceneError(
                    f"{path}: exists but is not a readable layer; delete it or choose another name"
                ) from exc
            if existing is None:
                raise SceneError(f"{path}: exists but is not a readable layer; delete it or choose another name")
            below = sublayer_files(existing)
            if base_file is None or base_file.resolve() not in below:
                raise SceneError(
                    f"{path}: exists and does not sublayer {base_file or 'this in-memory scene'}; "
                    "choose another file name or delete it"
                )
            layer = existing
        else:
            layer = new_layer_over(base, path)
        self._stage = Usd.Stage.Open(layer)
        self.provenance = provenance if provenance is not None else path.stem

    @contextlib.contextmanager
    def edit(self, path: str | os.PathLike[str]) -> Iterator[SceneGraph]:
        """Context manager for a user edit saved as its own layer, never touching the layers below.

        ``with scene.edit("edit_move.usda"): scene.set_pose("mug", pose)`` writes ``edit_move.usda`` (which
        sublayers the scene) when the block ends; afterwards this SceneGraph shows the edited scene. If the
        block raises, nothing is written and the SceneGraph returns to the scene as it was.
        """
        before_stage, before_provenance = self._stage, self.provenance
        self.push_layer(path)
        try:
            yield self
        except BaseException:
            self._stage, self.provenance = before_stage, before_provenance
            raise
        self.save()

    # ------------------------------------------------------------------ nodes
    def node_path(self, name: str) -> Sdf.Path:
        """Prim path of a node given its name ('background', an object name) or its prim path."""
        if name.startswith("/"):
            return Sdf.Path(name)
        if name == BACKGROUND:
            return BACKGROUND_PATH
        if not Sdf.Path.IsValidIdentifier(name):
            raise InvalidDataError(
                f"{name!r} is not a valid object name: use letters, digits and '_' and do not start with a digit"
            )
        return OBJECTS_PATH.AppendChild(name)

    def node_name(self, path: Sdf.Path | str) -> str:
        """Inverse of :meth:`node_path`."""
        path = Sdf.Path(str(path))
        if path == BACKGROUND_PATH:
            return BACKGROUND
        if path.GetParentPath() == OBJECTS_PATH:
            return path.name
        return str(path)

    def _prim(self, name: str) -> Usd.Prim:
        path = self.node_path(name)
        prim = self._stage.GetPrimAtPath(path)
        if not prim or not prim.IsValid():
            raise SceneError(f"{self._where()}: no node {name!r} (prim {path}); add it with add_object() first")
        return prim

    def _where(self) -> str:
        return str(self.path) if self.path is not None else "<in-memory scene>"

    def _stamp(self, prim: Usd.Prim) -> None:
        if prim.HasAPI("HoloNodeAPI"):
            prim.GetAttribute("holo:node:provenance").Set(self.provenance)

    def _define_node(self, path: Sdf.Path, role: str, instance_id: int, observed_fraction: float) -> Usd.Prim:
        xform = UsdGeom.Xform.Define(self._stage, path)
        prim = xform.GetPrim()
        prim.ApplyAPI("HoloNodeAPI")
        prim.GetAttribute("holo:node:instanceId").Set(int(instance_id))
        prim.GetAttribute("holo:node:role").Set(role)
        prim.GetAttribute("holo:node:observedFraction").Set(float(observed_fraction))
        prim.GetAttribute("holo:node:provenance").Set(self.provenance)
        return prim

    def add_background(self, *, instance_id: int = 0, observed_fraction: float = 0.0) -> Sdf.Path:
        """Define /World/Background (the static room shell and root of the support tree)."""
        return self._define_node(BACKGROUND_PATH, "background", instance_id, observed_fraction).GetPath()

    def add_object(
        self, name: str, *, instance_id: int, pose: Pose | None = None, observed_fraction: float = 0.0
    ) -> Sdf.Path:
        """Define /World/Objects/<name> with its node identity and (optionally) its world pose."""
        path = self.node_path(name)
        if path.GetParentPath() != OBJECTS_PATH:
            raise InvalidDataError(f"{name!r}: objects are named by a plain identifier, not a path")
        if not self._stage.GetPrimAtPath(OBJECTS_PATH):
            UsdGeom.Scope.Define(self._stage, OBJECTS_PATH)
        self._define_node(path, "object", instance_id, observed_fraction)
        self.set_pose(name, pose if pose is not None else Pose())
        return path

    def objects(self) -> list[str]:
        """Names of the object nodes, in prim order."""
        parent = self._stage.GetPrimAtPath(OBJECTS_PATH)
        if not parent:
            return []
        return [p.GetName() for p in parent.GetChildren() if p.HasAPI("HoloNodeAPI")]

    def nodes(self) -> list[NodeInfo]:
        """Identity of every node: the background (if any) first, then the objects."""
        names = ([BACKGROUND] if self._stage.GetPrimAtPath(BACKGROUND_PATH) else []) + self.objects()
        return [self.node_info(n) for n in names]

    def node_info(self, name: str) -> NodeInfo:
        """Identity of one node (HoloNodeAPI values)."""
        prim = self._prim(name)

        def get(attr: str, default: object) -> object:
            value = prim.GetAttribute(attr).Get()
            return default if value is None else value

        return NodeInfo(
            name=self.node_name(prim.GetPath()),
            path=str(prim.GetPath()),
            role=str(get("holo:node:role", "object")),
            instance_id=int(get("holo:node:instanceId", 0)),
            observed_fraction=float(get("holo:node:observedFraction", 0.0)),
            provenance=str(get("holo:node:provenance", "")),
        )

    def set_node_info(
        self, name: str, *, instance_id: int | None = None, observed_fraction: float | None = None
    ) -> None:
        """Update a node's instance id and / or observed fraction."""
        prim = self._prim(name)
        if instance_id is not None:
            prim.GetAttribute("holo:node:instanceId").Set(int(instance_id))
        if observed_fraction is not None:
            prim.GetAttribute("holo:node:observedFraction").Set(float(observed_fraction))
        self._stamp(prim)

    # ------------------------------------------------------------------ state
    def set_pose(self, name: str, pose: Pose) -> None:
        """Set the world pose of an object Xform (translate + orient ops, double precision)."""
        prim = self._prim(name)
        xform = UsdGeom.Xformable(prim)
        world = Gf.Matrix4d().SetIdentity()
        world.SetRotateOnly(Gf.Quatd(float(pose.orientation[3]), *map(float, pose.orientation[:3])))
        world.SetTranslateOnly(Gf.Vec3d(*map(float, pose.translation)))
        parent_world = UsdGeom.Xformable(prim.GetParent()).ComputeLocalToWorldTransform(Usd.TimeCode.Default())
        local = Gf.Transform(world * parent_world.GetInverse())
        ops = xform.GetOrderedXformOps()
        kinds = [op.GetOpType() for op in ops]
        if kinds != [UsdGeom.XformOp.TypeTranslate, UsdGeom.XformOp.TypeOrient] or any(
            op.GetPrecision() != UsdGeom.XformOp.PrecisionDouble for op in ops
        ):
            xform.ClearXformOpOrder()
            ops = [
                xform.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble),
                xform.AddOrientOp(UsdGeom.XformOp.PrecisionDouble),
            ]
        else:
            xform.SetXformOpOrder(ops)
        ops[0].Set(local.GetTranslation())
        ops[1].Set(Gf.Quatd(local.GetRotation().GetQuat()))
        self._stamp(prim)

    def get_pose(self, name: str, time: float | None = None) -> Pose:
        """World pose of a node's Xform (at ``time`` when the pose is animated, e.g. by a simulation layer)."""
        prim = self._prim(name)
        code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
        matrix = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(code)
        transform = Gf.Transform(matrix)
        quat = transform.GetRotation().GetQuat()
        imag = quat.GetImaginary()
        return Pose(
            translation=np.array(transform.GetTranslation()),
            orientation=np.array([imag[0], imag[1], imag[2], quat.GetReal()]),
        )

    # ------------------------------------------------------------------ geometry
    def _write_mesh(self, path: Sdf.Path, mesh: MeshData, *, smooth: bool = True) -> UsdGeom.Mesh:
        geom = UsdGeom.Mesh.Define(self._stage, path)
        geom.CreatePointsAttr().Set(_vec3f_array(mesh.points))
        geom.CreateFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(len(mesh.faces), 3, dtype=np.int32)))
        geom.CreateFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(mesh.faces.astype(np.int32).ravel()))
        set_normals(geom, mesh.points, mesh.faces, smooth=smooth)
        geom.CreateSubdivisionSchemeAttr().Set(UsdGeom.Tokens.none)
        geom.CreateOrientationAttr().Set(UsdGeom.Tokens.rightHanded)
        bounds = mesh.bounds.astype(np.float32)
        geom.CreateExtentAttr().Set(Vt.Vec3fArray.FromNumpy(bounds))
        return geom

    def _read_mesh(self, prim: Usd.Prim) -> MeshData:
        return read_mesh(prim, where=f"{self._where()}:{prim.GetPath()}")

    def set_mesh(self, name: str, mesh: MeshData) -> None:
        """Write a node's mesh (object coordinates) as <node>/Geom."""
        prim = self._prim(name)
        self._write_mesh(prim.GetPath().AppendChild("Geom"), mesh)
        self._stamp(prim)

    def get_mesh(self, name: str) -> MeshData:
        """Read a node's Geom mesh (triangulated if it was authored with polygons)."""
        prim = self._prim(name)
        geom = prim.GetChild("Geom")
        if not geom or not geom.IsA(UsdGeom.Mesh):
            raise SceneError(f"{self._where()}: node {name!r} has no Geom mesh; write one with set_mesh()")
        return self._read_mesh(geom)

    # ------------------------------------------------------------------ assets
    def _asset_file(self, name: str, suffix: str) -> Path:
        layer = self._stage.GetEditTarget().GetLayer()
        anchor = layer_path(layer)
        if anchor is None:
            raise SceneError(
                "the scene is in memory: SDF grids and splats are stored in files beside the scene, "
                "so create it with a path (SceneGraph.create('scene.usda'))"
            )
        return anchor.parent / "assets" / anchor.stem / f"{name}{suffix}"

    def set_sdf(self, name: str, sdf: SdfField) -> Path:
        """Store a node's SDF grid in a compressed .npz beside the layer and author HoloSdfAPI.

        Returns:
            The .npz file written.
        """
        prim = self._prim(name)
        target = self._asset_file(self.node_name(prim.GetPath()), ".sdf.npz")
        with atomic_path(target) as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, **{_SDF_KEY: sdf.grid})
        prim.ApplyAPI("HoloSdfAPI")
        layer = self._stage.GetEditTarget().GetLayer()
        prim.GetAttribute("holo:sdf:file").Set(Sdf.AssetPath(_relative_asset(target, layer)))
        prim.GetAttribute("holo:sdf:origin").Set(Gf.Vec3d(*map(float, sdf.origin)))
        prim.GetAttribute("holo:sdf:voxelSize").Set(sdf.voxel_size)
        prim.GetAttribute("holo:sdf:resolution").Set(Gf.Vec3i(*sdf.resolution))
        prim.GetAttribute("holo:sdf:isoLevel").Set(sdf.iso_level)
        self._stamp(prim)
        return target

    def get_sdf(self, name: str) -> SdfField:
        """Read a node's SDF field, loading the grid from its .npz asset."""
        prim = self._prim(name)
        where = f"{self._where()}:{prim.GetPath()}"
        if not prim.HasAPI("HoloSdfAPI"):
            raise SceneError(f"{where}: node has no SDF (HoloSdfAPI); write one with set_sdf()")
        asset = prim.GetAttribute("holo:sdf:file").Get()
        resolved = asset.resolvedPath if asset is not None else ""
        if not resolved:
            raise SceneError(
                f"{where}: SDF file {asset.path if asset else '<unset>'!r} cannot be found; "
                "restore the assets/ folder beside the scene"
            )
        try:
            with np.load(resolved) as data:
                grid = data[_SDF_KEY]
        except (OSError, ValueError, KeyError) as exc:
            raise SceneError(f"{resolved}: not a holousd SDF grid ({exc}); re-run the stage that wrote it") from exc
        resolution = tuple(prim.GetAttribute("holo:sdf:resolution").Get())
        if tuple(grid.shape) != resolution:
            raise SceneError(
                f"{where}: grid in {resolved} has shape {list(grid.shape)} but holo:sdf:resolution is "
                f"{list(resolution)}; re-run the stage that wrote it"
            )
        try:
            return SdfField(
                grid=grid,
                origin=np.array(prim.GetAttribute("holo:sdf:origin").Get()),
                voxel_size=prim.GetAttribute("holo:sdf:voxelSize").Get(),
                iso_level=prim.GetAttribute("holo:sdf:isoLevel").Get(),
            )
        except InvalidDataError as exc:
            raise SceneError(f"{where}: {exc}") from exc

    def set_gaussians(self, name: str, splats: GaussianSplats) -> Path:
        """Store a node's splats as a UsdVol.ParticleField3DGaussianSplat in a per-object .usdc.

        The scene's <node>/Splats prim references that file; when the splats are bound to faces, its
        ``holo:gom:mesh`` relationship targets <node>/Geom.

        Returns:
            The .usdc file written.
        """
        prim = self._prim(name)
        target = self._asset_file(self.node_name(prim.GetPath()), ".splats.usdc")
        layer = Sdf.Layer.CreateAnonymous("splats.usdc")
        stage = Usd.Stage.Open(layer)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        layer.customLayerData = {"holousd": {"schemaVersion": SCHEMA_VERSION}}
        field_prim = UsdVol.ParticleField3DGaussianSplat.Define(stage, "/Splats")
        stage.SetDefaultPrim(field_prim.GetPrim())
        field_prim.CreatePositionsAttr().Set(_vec3f_array(splats.positions))
        field_prim.CreateOrientationsAttr().Set(Vt.QuatfArray.FromNumpy(splats.orientations))
        field_prim.CreateScalesAttr().Set(_vec3f_array(splats.scales))
        field_prim.CreateOpacitiesAttr().Set(Vt.FloatArray.FromNumpy(splats.opacities))
        field_prim.CreateRadianceSphericalHarmonicsDegreeAttr().Set(splats.sh_degree)
        field_prim.CreateRadianceSphericalHarmonicsCoefficientsAttr().Set(_vec3f_array(splats.sh_coeffs.reshape(-1, 3)))
        if len(splats):
            lo, hi = splats.positions.min(axis=0), splats.positions.max(axis=0)
            pad = 3.0 * splats.scales.max()
            field_prim.CreateExtentAttr().Set(Vt.Vec3fArray.FromNumpy(np.stack([lo - pad, hi + pad])))
        if splats.bound:
            fp = field_prim.GetPrim()
            fp.ApplyAPI("HoloGaussianOnMeshAPI")
            fp.GetAttribute("holo:gom:faceIndex").Set(Vt.IntArray.FromNumpy(splats.face_index))
            fp.GetAttribute("holo:gom:barycentric").Set(_vec3f_array(splats.barycentric))
            fp.GetAttribute("holo:gom:normalOffset").Set(Vt.FloatArray.FromNumpy(splats.normal_offset))
            fp.GetAttribute("holo:gom:inPlaneRotation").Set(Vt.FloatArray.FromNumpy(splats.in_plane_rotation))
            fp.GetAttribute("holo:gom:inPlaneScale").Set(Vt.Vec2fArray.FromNumpy(splats.in_plane_scale))
        save_layer(layer, target)

        splat_prim = self._stage.DefinePrim(prim.GetPath().AppendChild("Splats"))
        edit_layer = self._stage.GetEditTarget().GetLayer()
        splat_prim.GetReferences().SetReferences([Sdf.Reference(_relative_asset(target, edit_layer))])
        rel = splat_prim.CreateRelationship("holo:gom:mesh", custom=False)
        if splats.bound:
            rel.SetTargets([prim.GetPath().AppendChild("Geom")])
        else:
            rel.ClearTargets(True)
        self._stamp(prim)
        return target

    def set_surface_color(self, name: str, colors: np.ndarray) -> None:
        """Colour a node's mesh for tools that do not read Gaussian splats (Blender, usdview, game engines).

        Authors ``primvars:displayColor`` on <node>/Geom, one linear RGB colour per point, and a visual
        material /World/Looks/<Node> (a UsdPreviewSurface whose diffuse colour reads that primvar, falling back
        to the mean colour) bound to the Geom for all purposes; the physics material keeps its 'physics' binding.

        Args:
            name: Node name.
            colors: [P, 3] linear RGB in [0, 1] for the P points of the node's Geom mesh.
        """
        prim = self._prim(name)
        geom = prim.GetChild("Geom")
        if not geom or not geom.IsA(UsdGeom.Mesh):
            raise SceneError(f"{self._where()}: node {name!r} has no Geom mesh to colour; write one with set_mesh()")
        points = geom.GetAttribute("points").Get()
        colors = np.asarray(colors, dtype=np.float32)
        if colors.shape != (len(points or []), 3) or not np.all(np.isfinite(colors)):
            raise InvalidDataError(f"{self._where()}: {name!r}: colours must be [{len(points or [])}, 3] finite "
                                   f"values, one per mesh point; got shape {colors.shape}")  # fmt: skip
        colors = np.clip(colors, 0.0, 1.0)
        primvar = UsdGeom.PrimvarsAPI(geom).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray,
                                                          UsdGeom.Tokens.vertex)  # fmt: skip
        _set_indexed(primvar, colors)
        node = self.node_name(prim.GetPath())
        look = LOOKS_PATH.AppendChild("Background" if prim.GetPath() == BACKGROUND_PATH else f"Object_{node}")
        UsdGeom.Scope.Define(self._stage, LOOKS_PATH)
        material = UsdShade.Material.Define(self._stage, look)
        surface = UsdShade.Shader.Define(self._stage, look.AppendChild("Surface"))
        surface.CreateIdAttr("UsdPreviewSurface")
        reader = UsdShade.Shader.Define(self._stage, look.AppendChild("DisplayColor"))
        reader.CreateIdAttr("UsdPrimvarReader_float3")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("displayColor")  # string: UsdPreviewSurface 2.5
        mean = Gf.Vec3f(*map(float, colors.mean(axis=0))) if len(colors) else Gf.Vec3f(0.5, 0.5, 0.5)
        reader.CreateInput("fallback", Sdf.ValueTypeNames.Float3).Set(mean)
        result = reader.CreateOutput("result", Sdf.ValueTypeNames.Float3)
        surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(result)
        surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8)
        surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
        material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
        UsdShade.MaterialBindingAPI.Apply(geom).Bind(material)
        self._stamp(prim)

    def set_surface_texture(self, name: str, st: np.ndarray, image: np.ndarray) -> Path:
        """Texture a node's mesh: the image goes to ``assets/<layer>/<name>.png`` beside the layer, the mesh gets
        ``primvars:st`` (one coordinate per face corner, faceVarying), and the node's visual material (written by
        :meth:`set_surface_color`, which must come first) takes its diffuse colour from the texture through a
        ``UsdUVTexture`` (sRGB); ``displayColor`` stays on the mesh for tools that read no textures.

        Args:
            name: Node name.
            st: [F, 3, 2] texture coordinates of each triangle's corners, (0, 0) at the image's bottom left.
            image: [H, W, 3] uint8 sRGB-encoded texels, row 0 at the top.

        Returns:
            The image file written.
        """
        from PIL import Image

        prim = self._prim(name)
        geom = prim.GetChild("Geom")
        counts = geom.GetAttribute("faceVertexCounts").Get() if geom else None
        st = np.asarray(st, dtype=np.float32)
        if counts is None or st.shape != (len(counts), 3, 2) or not np.all(np.isfinite(st)):
            raise InvalidDataError(f"{self._where()}: {name!r}: st must be [{len(counts or [])}, 3, 2] finite "
                                   f"coordinates, one per triangle corner; got shape {st.shape}")  # fmt: skip
        image = np.asarray(image)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3 or min(image.shape[:2]) == 0:
            raise InvalidDataError(f"{self._where()}: {name!r}: the texture must be an [H, W, 3] uint8 image")
        material = UsdShade.MaterialBindingAPI(geom).GetDirectBinding().GetMaterial()
        surface = UsdShade.Shader(self._stage.GetPrimAtPath(material.GetPath().AppendChild("Surface"))) \
            if material else None  # fmt: skip
        if not surface:
            raise SceneError(f"{self._where()}: {name!r} has no visual material; call set_surface_color() first")
        target = self._asset_file(name, ".png")
        with atomic_path(target) as tmp:
            Image.fromarray(image).save(tmp, format="PNG")
        primvar = UsdGeom.PrimvarsAPI(geom).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                          UsdGeom.Tokens.faceVarying)  # fmt: skip
        _set_indexed(primvar, st.reshape(-1, 2))
        look = material.GetPath()
        reader = UsdShade.Shader.Define(self._stage, look.AppendChild("TexCoords"))
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        coords = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
        texture = UsdShade.Shader.Define(self._stage, look.AppendChild("Texture"))
        texture.CreateIdAttr("UsdUVTexture")
        layer = self._stage.GetEditTarget().GetLayer()
        texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(_relative_asset(target, layer)))
        texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(coords)
        texture.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
        for wrap in ("wrapS", "wrapT"):
            texture.CreateInput(wrap, Sdf.ValueTypeNames.Token).Set("clamp")
        mean = image.reshape(-1, 3).mean(axis=0) / 255.0
        texture.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*map(float, mean), 1.0))
        rgb = texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
        self._stamp(prim)
        return target

    def get_surface_texture(self, name: str) -> tuple[np.ndarray, np.ndarray] | None:
        """([F, 3, 2] st per triangle corner, [H, W, 3] uint8 image) of a textured node, or None."""
        from PIL import Image

        geom = self._prim(name).GetChild("Geom")
        primvar = UsdGeom.PrimvarsAPI(geom).GetPrimvar("st") if geom else None
        material = UsdShade.MaterialBindingAPI(geom).GetDirectBinding().GetMaterial() if geom else None
        surface = UsdShade.Shader(self._stage.GetPrimAtPath(material.GetPath().AppendChild("Surface"))) \
            if material else None  # fmt: skip
        diffuse = surface.GetInput("diffuseColor") if surface else None
        sources = diffuse.GetConnectedSources()[0] if diffuse else []
        texture = sources[0].source.GetPrim() if len(sources) == 1 else None
        if not primvar or not primvar.HasValue() or not texture or not texture.HasAttribute("inputs:file"):
            return None  # not coloured by a texture (a later layer may have reconnected the colour)
        asset = texture.GetAttribute("inputs:file").Get()
        where = f"{self._where()}:{texture.GetPath()}"
        st = np.asarray(primvar.ComputeFlattened(), dtype=np.float64)
        counts = geom.GetAttribute("faceVertexCounts").Get()
        if st.shape != (3 * len(counts or []), 2):
            raise SceneError(f"{where}: primvars:st has {len(st)} coordinates for {len(counts or [])} triangles "
                             "(3 each); re-run the appearance stage")  # fmt: skip
        if asset is None or not asset.resolvedPath:
            raise SceneError(f"{where}: its texture file {asset.path if asset else ''!r} is missing; restore the "
                             "assets/ folder or re-run the appearance stage")  # fmt: skip
        with Image.open(asset.resolvedPath) as img:
            image = np.asarray(img.convert("RGB"))
        return st.reshape(-1, 3, 2), image

    def get_surface_color(self, name: str) -> np.ndarray | None:
        """[P, 3] linear RGB per point of the node's Geom (``primvars:displayColor``), or None when not coloured."""
        geom = self._prim(name).GetChild("Geom")
        primvar = UsdGeom.PrimvarsAPI(geom).GetPrimvar("displayColor") if geom else None
        value = primvar.ComputeFlattened() if primvar and primvar.HasValue() else None
        return None if value is None else np.asarray(value, dtype=np.float64).reshape(-1, 3)

    def get_gaussians(self, name: str) -> GaussianSplats:
        """Read a node's splats (and their face binding, if any)."""
        prim = self._prim(name)
        where = f"{self._where()}:{prim.GetPath()}/Splats"
        splat_prim = prim.GetChild("Splats")
        if not splat_prim or not splat_prim.IsA(UsdVol.ParticleField3DGaussianSplat):
            raise SceneError(
                f"{where}: no Gaussian splats (missing prim or unresolved .usdc reference); "
                "write them with set_gaussians() or restore the assets/ folder"
            )
        gs = UsdVol.ParticleField3DGaussianSplat(splat_prim)

        def arr(attr: Usd.Attribute, dtype: type) -> np.ndarray:
            value = attr.Get()
            return np.asarray(value if value is not None else [], dtype=dtype)

        positions = arr(gs.GetPositionsAttr(), np.float32).reshape(-1, 3)
        n = len(positions)
        coeffs = arr(gs.GetRadianceSphericalHarmonicsCoefficientsAttr(), np.float32).reshape(-1, 3)
        degree = gs.GetRadianceSphericalHarmonicsDegreeAttr().Get()
        k = (int(degree) + 1) ** 2 if degree is not None else 1
        if coeffs.shape[0] != n * k:
            raise SceneError(
                f"{where}: {coeffs.shape[0]} SH coefficients for {n} splats of degree {degree} "
                f"(expected {n * k}); rewrite the splats"
            )
        binding: dict[str, np.ndarray] = {}
        if splat_prim.HasAPI("HoloGaussianOnMeshAPI"):
            binding = {
                "face_index": arr(splat_prim.GetAttribute("holo:gom:faceIndex"), np.int32),
                "barycentric": arr(splat_prim.GetAttribute("holo:gom:barycentric"), np.float32),
                "normal_offset": arr(splat_prim.GetAttribute("holo:gom:normalOffset"), np.float32),
                "in_plane_rotation": arr(splat_prim.GetAttribute("holo:gom:inPlaneRotation"), np.float32),
                "in_plane_scale": arr(splat_prim.GetAttribute("holo:gom:inPlaneScale"), np.float32),
            }
        try:
            return GaussianSplats(
                positions=positions,
                orientations=arr(gs.GetOrientationsAttr(), np.float32),
                scales=arr(gs.GetScalesAttr(), np.float32),
                opacities=arr(gs.GetOpacitiesAttr(), np.float32),
                sh_coeffs=coeffs.reshape(n, k, 3),
                **binding,
            )
        except InvalidDataError as exc:
            raise SceneError(f"{where}: inconsistent splat arrays: {exc}; rewrite the splats") from exc

    # ------------------------------------------------------------------ physics
    def _material_path(self, prim: Usd.Prim) -> Sdf.Path:
        if prim.GetPath() == BACKGROUND_PATH:
            return MATERIALS_PATH.AppendChild("Background")
        return MATERIALS_PATH.AppendChild(f"Object_{prim.GetName()}")

    def set_physics(self, name: str, props: PhysicsProps) -> None:
        """Author a node's rigid body, mass, material (bound with purpose 'physics') and damping.

        ``props.mass = None`` makes the node a static collider (no RigidBodyAPI): the background always is one.
        """
        prim = self._prim(name)
        if props.mass is not None:
            if prim.GetPath() == BACKGROUND_PATH:
                raise InvalidDataError("the background is static: give it PhysicsProps(mass=None, ...)")
            UsdPhysics.RigidBodyAPI.Apply(prim).CreateRigidBodyEnabledAttr().Set(True)
            mass_api = UsdPhysics.MassAPI.Apply(prim)
            mass_api.CreateMassAttr().Set(props.mass)
            mass_api.CreateCenterOfMassAttr().Set(Gf.Vec3f(*map(float, props.center_of_mass)))
            if props.diagonal_inertia is not None:
                mass_api.CreateDiagonalInertiaAttr().Set(Gf.Vec3f(*map(float, props.diagonal_inertia)))
                x, y, z, w = (float(v) for v in (props.principal_axes if props.principal_axes is not None
                                                 else (0.0, 0.0, 0.0, 1.0)))  # fmt: skip
                mass_api.CreatePrincipalAxesAttr().Set(Gf.Quatf(w, x, y, z))
            prim.ApplyAPI("HoloPhysicsAPI")
            prim.GetAttribute("holo:physics:linearDamping").Set(props.linear_damping)
            prim.GetAttribute("holo:physics:angularDamping").Set(props.angular_damping)
        elif prim.HasAPI(UsdPhysics.RigidBodyAPI):
            UsdPhysics.RigidBodyAPI(prim).CreateRigidBodyEnabledAttr().Set(False)
        material = UsdShade.Material.Define(self._stage, self._material_path(prim))
        mat_api = UsdPhysics.MaterialAPI.Apply(material.GetPrim())
        mat_api.CreateStaticFrictionAttr().Set(props.static_friction)
        mat_api.CreateDynamicFrictionAttr().Set(props.dynamic_friction)
        mat_api.CreateRestitutionAttr().Set(props.restitution)
        mat_api.CreateDensityAttr().Set(props.density)
        UsdShade.MaterialBindingAPI.Apply(prim).Bind(material, UsdShade.Tokens.weakerThanDescendants, "physics")
        self._bind_colliders(prim)
        self._stamp(prim)

    def set_geometry_record(self, name: str, record: GeometryRecord) -> None:
        """Author how an object's final mesh relates to its fit and its collider (``HoloGeometryAPI``)."""
        prim = self._prim(name)
        prim.ApplyAPI("HoloGeometryAPI")
        prim.GetAttribute("holo:geometry:fitShift").Set(Gf.Vec3f(*map(float, record.fit_shift)))
        prim.GetAttribute("holo:geometry:colliderReach").Set(float(record.collider_reach))
        prim.GetAttribute("holo:geometry:penetrationDepth").Set(float(record.penetration))
        prim.GetAttribute("holo:geometry:volume").Set(float(record.volume))
        prim.GetAttribute("holo:geometry:edits").Set(Vt.StringArray(list(record.edits)))
        self._stamp(prim)

    def get_geometry_record(self, name: str) -> GeometryRecord | None:
        """The record :meth:`set_geometry_record` wrote, or None when the node has none."""
        prim = self._prim(name)
        reach = prim.GetAttribute("holo:geometry:colliderReach")
        if not reach or not reach.HasAuthoredValue():
            return None

        def get(attr: str, default: object) -> object:
            value = prim.GetAttribute(attr).Get()
            return default if value is None else value

        return GeometryRecord(fit_shift=np.array(get("holo:geometry:fitShift", (0.0, 0.0, 0.0)), float),
                              collider_reach=float(reach.Get()),
                              penetration=float(get("holo:geometry:penetrationDepth", 0.0)),
                              volume=float(get("holo:geometry:volume", 0.0)),
                              edits=[str(e) for e in get("holo:geometry:edits", [])])  # fmt: skip

    def _bind_colliders(self, prim: Usd.Prim) -> None:
        """Bind the node's physics material directly on each collider prim too.

        UsdPhysics resolves bindings through inheritance, but some importers (Newton 1.8) only read a binding
        authored on the collider prim itself; binding both ways serves every reader.
        """
        material = UsdShade.Material.Get(self._stage, self._material_path(prim))
        if not material:
            return
        for child in Usd.PrimRange(prim):
            if child.HasAPI(UsdPhysics.CollisionAPI):
                UsdShade.MaterialBindingAPI.Apply(child).Bind(
                    material, UsdShade.Tokens.weakerThanDescendants, "physics"
                )

    def get_physics(self, name: str) -> PhysicsProps:
        """Read a node's physical parameters (mass, centre of mass, inertia, material, damping).

        ``mass`` is None for a static collider (no enabled rigid body).
        """
        prim = self._prim(name)
        where = f"{self._where()}:{prim.GetPath()}"
        dynamic = prim.HasAPI(UsdPhysics.RigidBodyAPI) and bool(
            UsdPhysics.RigidBodyAPI(prim).GetRigidBodyEnabledAttr().Get()
        )
        mass_api = UsdPhysics.MassAPI(prim)
        mass = com = inertia = axes = None
        if dynamic:
            mass = mass_api.GetMassAttr().Get() if prim.HasAPI(UsdPhysics.MassAPI) else None
            if not mass:
                raise SceneError(f"{where}: rigid body without a mass (UsdPhysics.MassAPI); set it with set_physics()")
            com = mass_api.GetCenterOfMassAttr().Get()
            inertia = mass_api.GetDiagonalInertiaAttr().Get()
            axes = mass_api.GetPrincipalAxesAttr().Get()
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial("physics")
        if not material or not material.GetPrim().HasAPI(UsdPhysics.MaterialAPI):
            raise SceneError(f"{where}: no physics material bound; write it with set_physics()")
        mat = UsdPhysics.MaterialAPI(material.GetPrim())
        has_damping = prim.HasAPI("HoloPhysicsAPI")
        try:
            return PhysicsProps(
                mass=float(mass) if mass else None,
                center_of_mass=np.array(com) if com is not None else np.zeros(3),
                diagonal_inertia=np.array(inertia) if inertia is not None and any(inertia) else None,
                principal_axes=(np.array([*axes.GetImaginary(), axes.GetReal()])
                                if axes is not None and inertia is not None and any(inertia) else None),
                density=float(mat.GetDensityAttr().Get() or 0.0),
                static_friction=float(mat.GetStaticFrictionAttr().Get() or 0.0),
                dynamic_friction=float(mat.GetDynamicFrictionAttr().Get() or 0.0),
                restitution=float(mat.GetRestitutionAttr().Get() or 0.0),
                linear_damping=float(prim.GetAttribute("holo:physics:linearDamping").Get() or 0.0)
                if has_damping
                else 0.0,
                angular_damping=float(prim.GetAttribute("holo:physics:angularDamping").Get() or 0.0)
                if has_damping
                else 0.0,
            )
        except InvalidDataError as exc:
            raise SceneError(f"{where}: {exc}") from exc

    def set_collider(self, name: str, collider: Collider) -> None:
        """Write a node's collider meshes under <node>/Collision (purpose 'guide', so viewers hide them).

        ``convexHull`` and ``none`` author one mesh with that approximation. ``convexDecomposition`` with
        several parts authors each part as a convex hull (the decomposition is explicit, so every simulator
        sees the same parts); with one part it authors approximation ``convexDecomposition`` and leaves the
        decomposition to the simulator. Parts left over from a weaker layer are deactivated.
        """
        prim = self._prim(name)
        scope_path = prim.GetPath().AppendChild("Collision")
        UsdGeom.Scope.Define(self._stage, scope_path)
        if len(collider.parts) > 1:
            approximation = UsdPhysics.Tokens.convexHull
        else:
            approximation = collider.approximation
        names = [f"Part_{i:03d}" for i in range(len(collider.parts))]
        existing = self._stage.GetPrimAtPath(scope_path).GetChildren()
        for child in existing:
            if child.GetName() not in names:
                child.SetActive(False)
        for part_name, part in zip(names, collider.parts, strict=True):
            geom = self._write_mesh(scope_path.AppendChild(part_name), part, smooth=False)  # a hull: flat faces
            geom.GetPrim().SetActive(True)
            geom.CreatePurposeAttr().Set(UsdGeom.Tokens.guide)
            UsdPhysics.CollisionAPI.Apply(geom.GetPrim()).CreateCollisionEnabledAttr().Set(True)
            UsdPhysics.MeshCollisionAPI.Apply(geom.GetPrim()).CreateApproximationAttr().Set(approximation)
        self._bind_colliders(prim)
        self._stamp(prim)

    def get_collider(self, name: str) -> Collider:
        """Read a node's collider meshes (any prims with CollisionAPI under the node)."""
        prim = self._prim(name)
        parts: list[MeshData] = []
        approximations: list[str] = []
        for child in Usd.PrimRange(prim):
            if child.HasAPI(UsdPhysics.CollisionAPI) and child.IsA(UsdGeom.Mesh):
                parts.append(self._read_mesh(child))
                approx = UsdPhysics.MeshCollisionAPI(child).GetApproximationAttr().Get()
                approximations.append(str(approx) if approx else "none")
        if not parts:
            raise SceneError(f"{self._where()}:{prim.GetPath()}: no collider; write one with set_collider()")
        if len(parts) > 1:
            kind = "convexDecomposition"
        elif approximations[0] in ("convexHull", "convexDecomposition", "none"):
            kind = approximations[0]
        else:  # other UsdPhysics approximations (boundingCube, meshSimplification, ...) act as hulls or meshes
            kind = "convexHull"
        return Collider(approximation=kind, parts=parts)

    # ------------------------------------------------------------------ relations and energies
    def set_support(self, name: str, parent: str) -> None:
        """Set the one node that ``name`` rests on (``'background'`` for the floor)."""
        prim = self._prim(name)
        parent_prim = self._prim(parent)
        if parent_prim.GetPath() == prim.GetPath():
            raise InvalidDataError(f"{name!r} cannot support itself")
        prim.ApplyAPI("HoloRelationsAPI")
        prim.GetRelationship("holo:supportedBy").SetTargets([parent_prim.GetPath()])
        if not prim.GetRelationship("holo:beside").HasAuthoredTargets():
            prim.GetRelationship("holo:beside").SetTargets([])
        self._stamp(prim)

    def get_support(self, name: str) -> str | None:
        """Name of the node that ``name`` rests on, or None."""
        rel = self._prim(name).GetRelationship("holo:supportedBy")
        targets = rel.GetTargets() if rel else []
        return self.node_name(targets[0]) if targets else None

    def set_beside(self, name: str, others: Sequence[str]) -> None:
        """Set the siblings ``name`` touches side by side."""
        prim = self._prim(name)
        paths = [self._prim(o).GetPath() for o in others]
        prim.ApplyAPI("HoloRelationsAPI")
        prim.GetRelationship("holo:beside").SetTargets(paths)
        self._stamp(prim)

    def get_beside(self, name: str) -> list[str]:
        """Names of the siblings ``name`` touches."""
        rel = self._prim(name).GetRelationship("holo:beside")
        return [self.node_name(t) for t in (rel.GetTargets() if rel else [])]

    def set_energies(self, name: str, energies: Energies) -> None:
        """Record the energies the physics search measured for a node."""
        prim = self._prim(name)
        prim.ApplyAPI("HoloEnergyAPI")
        prim.GetAttribute("holo:energy:stable").Set(float(energies.stable))
        prim.GetAttribute("holo:energy:touch").Set(float(energies.touch))
        prim.GetAttribute("holo:energy:penetration").Set(float(energies.penetration))
        prim.GetAttribute("holo:energy:candidate").Set(int(energies.candidate))
        prim.GetAttribute("holo:energy:observation").Set(float(energies.observation))
        prim.GetAttribute("holo:energy:total").Set(float(energies.total))
        prim.GetAttribute("holo:energy:candidates").Set(Vt.StringArray(list(energies.candidates)))
        prim.GetAttribute("holo:energy:totals").Set(Vt.FloatArray([float(v) for v in energies.totals]))
        prim.GetAttribute("holo:energy:solver").Set(str(energies.solver))
        prim.GetAttribute("holo:energy:standsOnceSetUp").Set(bool(energies.stands_once_set_up))
        self._stamp(prim)

    def get_energies(self, name: str) -> Energies | None:
        """The recorded energies of a node, or None if none were recorded."""
        prim = self._prim(name)
        if not prim.HasAPI("HoloEnergyAPI"):
            return None
        return Energies(
            stable=float(prim.GetAttribute("holo:energy:stable").Get()),
            touch=float(prim.GetAttribute("holo:energy:touch").Get()),
            penetration=float(prim.GetAttribute("holo:energy:penetration").Get()),
            candidate=int(prim.GetAttribute("holo:energy:candidate").Get()),
            observation=float(prim.GetAttribute("holo:energy:observation").Get()),
            total=float(prim.GetAttribute("holo:energy:total").Get()),
            candidates=list(prim.GetAttribute("holo:energy:candidates").Get() or []),
            totals=[float(v) for v in (prim.GetAttribute("holo:energy:totals").Get() or [])],
            solver=str(prim.GetAttribute("holo:energy:solver").Get()),
            stands_once_set_up=bool(prim.GetAttribute("holo:energy:standsOnceSetUp").Get()),
        )

    # ------------------------------------------------------------------ cameras
    def set_camera(self, camera: CameraData) -> Sdf.Path:
        """Write an observation camera as a UsdGeom.Camera under /World/Cameras (+ HoloCameraAPI).

        The OpenCV pinhole (K, cam_to_world) maps exactly onto USD's camera: focalLength = 0.1 fx,
        horizontalAperture = 0.1 width, verticalAperture = 0.1 fx height / fy, and the principal point goes to
        the aperture offsets. Image paths are stored relative to the layer being written when possible.
        """
        if not Sdf.Path.IsValidIdentifier(camera.name):
            raise InvalidDataError(f"camera name {camera.name!r} is not a valid prim name (letters, digits, '_')")
        if not self._stage.GetPrimAtPath(CAMERAS_PATH):
            UsdGeom.Scope.Define(self._stage, CAMERAS_PATH)
        cam = UsdGeom.Camera.Define(self._stage, CAMERAS_PATH.AppendChild(camera.name))
        fx, fy, cx, cy = camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]
        h_ap = _FILM_UNITS_PER_PIXEL * camera.width
        v_ap = _FILM_UNITS_PER_PIXEL * fx * camera.height / fy
        cam.CreateProjectionAttr().Set(UsdGeom.Tokens.perspective)
        cam.CreateFocalLengthAttr().Set(float(_FILM_UNITS_PER_PIXEL * fx))
        cam.CreateHorizontalApertureAttr().Set(float(h_ap))
        cam.CreateVerticalApertureAttr().Set(float(v_ap))
        cam.CreateHorizontalApertureOffsetAttr().Set(float((camera.width / 2.0 - cx) * h_ap / camera.width))
        cam.CreateVerticalApertureOffsetAttr().Set(float((cy - camera.height / 2.0) * v_ap / camera.height))
        cam.CreateClippingRangeAttr().Set(Gf.Vec2f(0.01, 1000.0))
        prim = cam.GetPrim()
        self._set_camera_pose(prim, camera)
        image = ""
        if camera.image:
            image_path = Path(camera.image)
            anchor = layer_path(self._stage.GetEditTarget().GetLayer())
            image = (
                _relative_asset(image_path, self._stage.GetEditTarget().GetLayer())
                if (anchor is not None and image_path.is_absolute())
                else camera.image
            )
        prim.GetAttribute("holo:camera:image").Set(Sdf.AssetPath(image))
        prim.GetAttribute("holo:camera:frameId").Set(camera.frame_id)
        prim.GetAttribute("holo:camera:resolution").Set(Gf.Vec2i(camera.width, camera.height))
        return prim.GetPath()

    def set_camera_pose(self, camera: CameraData) -> None:
        """Write only the pose of the existing observation camera ``camera.name`` (and how far it was moved and
        turned from the capture's pose, ``pose_move`` / ``pose_turn_deg``) in the current edit target: what
        s1_fit writes when it refined the capture's poses."""
        prim = self._stage.GetPrimAtPath(CAMERAS_PATH.AppendChild(camera.name))
        if not prim or not prim.IsA(UsdGeom.Camera):
            raise SceneError(f"{self._where()}: no observation camera {camera.name!r}; write it with set_camera()")
        self._set_camera_pose(prim, camera, record=True)

    @staticmethod
    def _set_camera_pose(prim: Usd.Prim, camera: CameraData, record: bool = False) -> None:
        cam = UsdGeom.Camera(prim)
        usd_matrix = camera.cam_to_world @ _CV_TO_USD_CAMERA
        cam.ClearXformOpOrder()
        cam.AddTransformOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Matrix4d(usd_matrix.T.tolist()))
        prim.ApplyAPI("HoloCameraAPI")
        if record or np.any(camera.pose_move) or np.any(camera.pose_turn_deg):
            prim.GetAttribute("holo:camera:poseMove").Set(Gf.Vec3d(*camera.pose_move.tolist()))
            prim.GetAttribute("holo:camera:poseTurn").Set(Gf.Vec3d(*camera.pose_turn_deg.tolist()))

    def get_cameras(self) -> list[CameraData]:
        """All observation cameras under /World/Cameras, in prim order (image paths resolved when possible)."""
        parent = self._stage.GetPrimAtPath(CAMERAS_PATH)
        cameras = []
        for prim in parent.GetChildren() if parent else []:
            if not prim.IsA(UsdGeom.Camera):
                continue
            where = f"{self._where()}:{prim.GetPath()}"
            cam = UsdGeom.Camera(prim)
            resolution = prim.GetAttribute("holo:camera:resolution").Get()
            if resolution is None or min(resolution) <= 0:
                raise SceneError(f"{where}: camera has no holo:camera:resolution; write it with set_camera()")
            width, height = int(resolution[0]), int(resolution[1])
            focal = cam.GetFocalLengthAttr().Get()
            h_ap, v_ap = cam.GetHorizontalApertureAttr().Get(), cam.GetVerticalApertureAttr().Get()
            h_off, v_off = cam.GetHorizontalApertureOffsetAttr().Get(), cam.GetVerticalApertureOffsetAttr().Get()
            fx, fy = focal * width / h_ap, focal * height / v_ap
            K = np.array(
                [[fx, 0.0, width / 2.0 - h_off * width / h_ap], [0.0, fy, height / 2.0 + v_off * height / v_ap],
                 [0.0, 0.0, 1.0]]
            )  # fmt: skip
            usd_matrix = np.array(cam.ComputeLocalToWorldTransform(Usd.TimeCode.Default())).T
            image_attr = prim.GetAttribute("holo:camera:image")
            asset = image_attr.Get()
            image = None
            if asset is not None and asset.path:  # anchor to the layer that authored it, even if the file is gone
                image = asset.resolvedPath or image_attr.GetPropertyStack()[0].layer.ComputeAbsolutePath(asset.path)
            try:
                cameras.append(
                    CameraData(
                        name=prim.GetName(),
                        K=K,
                        cam_to_world=usd_matrix @ _CV_TO_USD_CAMERA,
                        width=width,
                        height=height,
                        image=image,
                        frame_id=str(prim.GetAttribute("holo:camera:frameId").Get() or ""),
                        pose_move=np.array(prim.GetAttribute("holo:camera:poseMove").Get() or (0.0, 0.0, 0.0)),
                        pose_turn_deg=np.array(prim.GetAttribute("holo:camera:poseTurn").Get() or (0.0, 0.0, 0.0)),
                    )
                )
            except InvalidDataError as exc:
                raise SceneError(f"{where}: {exc}") from exc
        return cameras

    # ------------------------------------------------------------------ summary
    def summary(self) -> SceneSummary:
        """Summarise nodes, relations, physics and splat counts (what ``holousd info`` prints)."""
        stage = self._stage
        root = stage.GetRootLayer()
        result = SceneSummary(
            path=str(self.path) if self.path else root.identifier,
            layers=[layer.identifier for layer in stage.GetLayerStack(includeSessionLayers=False)],
            up_axis=str(UsdGeom.GetStageUpAxis(stage)),
            meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)),
            kilograms_per_unit=float(UsdPhysics.GetStageKilogramsPerUnit(stage)),
            schema_version=schema_version_of(root),
        )
        for info in self.nodes():
            prim = self._prim(info.name)
            geom = prim.GetChild("Geom")
            counts = UsdGeom.Mesh(geom).GetFaceVertexCountsAttr().Get() if geom and geom.IsA(UsdGeom.Mesh) else None
            faces = int(sum(c - 2 for c in counts)) if counts else 0
            splat_prim = prim.GetChild("Splats")
            positions = (
                UsdVol.ParticleField3DGaussianSplat(splat_prim).GetPositionsAttr().Get()
                if splat_prim and splat_prim.IsA(UsdVol.ParticleField3DGaussianSplat)
                else None
            )
            mass = UsdPhysics.MassAPI(prim).GetMassAttr().Get() if prim.HasAPI(UsdPhysics.MassAPI) else None
            try:
                collider = self.get_collider(info.name)
                collider_kind, collider_parts = collider.approximation, len(collider.parts)
            except SceneError:
                collider_kind, collider_parts = None, 0
            resolution = prim.GetAttribute("holo:sdf:resolution").Get() if prim.HasAPI("HoloSdfAPI") else None
            record = self.get_geometry_record(info.name) if prim.HasAPI("HoloGeometryAPI") else None
            result.nodes.append(
                NodeSummary(
                    name=info.name,
                    path=info.path,
                    role=info.role,
                    instance_id=info.instance_id,
                    supported_by=self.get_support(info.name) if info.role == "object" else None,
                    beside=self.get_beside(info.name),
                    mesh_faces=faces,
                    sdf_resolution=list(resolution) if resolution is not None else None,
                    splats=len(positions) if positions is not None else 0,
                    mass_kg=float(mass) if mass else None,
                    dynamic=_is_dynamic(prim),
                    fit_shift_cm=100.0 * float(np.linalg.norm(record.fit_shift)) if record else None,
                    collider_reach_cm=100.0 * record.collider_reach if record else None,
                    penetration_cm=100.0 * record.penetration if record else None,
                    collider=collider_kind,
                    collider_parts=collider_parts,
                )
            )
        return result


def _is_dynamic(prim: Usd.Prim) -> bool:
    """An enabled rigid body: a simulator moves it (a missing mass does not make it static)."""
    if not prim.HasAPI(UsdPhysics.RigidBodyAPI):
        return False
    enabled = UsdPhysics.RigidBodyAPI(prim).GetRigidBodyEnabledAttr().Get()
    return enabled is None or bool(enabled)
