"""Small value types that the SceneGraph reads and writes.

Conventions: metres, kilograms, seconds; object coordinates unless a name says ``world``; quaternions are
scalar-last ``(x, y, z, w)`` like Warp, Newton and SciPy (USD's Gf.Quat constructors take ``w`` first: the
SceneGraph converts).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from holousd._errors import InvalidDataError

__all__ = [
    "CameraData",
    "Collider",
    "Energies",
    "GaussianSplats",
    "MeshData",
    "NodeInfo",
    "PhysicsProps",
    "Pose",
    "SdfField",
]

COLLIDER_APPROXIMATIONS = ("convexHull", "convexDecomposition", "none")
"""UsdPhysics.MeshCollisionAPI approximations holousd authors."""


def _array(value: object, dtype: type, shape: tuple[int | None, ...], what: str) -> np.ndarray:
    """Return ``value`` as a C-contiguous array of ``dtype`` checked against ``shape`` (None = any) and finiteness."""
    arr = np.ascontiguousarray(np.asarray(value, dtype=dtype))
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape, strict=True)):
        want = "x".join("N" if s is None else str(s) for s in shape)
        raise InvalidDataError(f"{what}: expected shape [{want}], got {list(arr.shape)}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise InvalidDataError(f"{what}: contains NaN or infinite values")
    return arr


@dataclass(kw_only=True)
class Pose:
    """Rigid world pose of an object Xform (the node state T_i)."""

    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """[3] position of the object origin in world coordinates, metres."""
    orientation: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    """[4] unit quaternion (x, y, z, w) rotating object into world coordinates."""

    def __post_init__(self) -> None:
        self.translation = _array(self.translation, np.float64, (3,), "Pose.translation")
        q = _array(self.orientation, np.float64, (4,), "Pose.orientation")
        norm = float(np.linalg.norm(q))
        if norm < 1e-8:
            raise InvalidDataError("Pose.orientation: zero quaternion; use (0, 0, 0, 1) for no rotation")
        self.orientation = q / norm

    def rotation_matrix(self) -> np.ndarray:
        """Return the [3, 3] rotation matrix of ``orientation``."""
        x, y, z, w = self.orientation
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )

    def matrix(self) -> np.ndarray:
        """Return the [4, 4] homogeneous object-to-world matrix (column vectors: p_world = M @ p_obj)."""
        m = np.eye(4)
        m[:3, :3] = self.rotation_matrix()
        m[:3, 3] = self.translation
        return m

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map [N, 3] object-coordinate points to world coordinates."""
        return np.asarray(points) @ self.rotation_matrix().T + self.translation


@dataclass(kw_only=True)
class MeshData:
    """A triangle mesh in object coordinates."""

    points: np.ndarray
    """[N, 3] vertex positions, metres."""
    faces: np.ndarray
    """[F, 3] vertex indices of each triangle, counter-clockwise seen from outside."""

    def __post_init__(self) -> None:
        self.points = _array(self.points, np.float64, (None, 3), "MeshData.points")
        self.faces = _array(self.faces, np.int64, (None, 3), "MeshData.faces")
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= len(self.points)):
            raise InvalidDataError(
                f"MeshData.faces: indices must lie in [0, {len(self.points) - 1}], "
                f"got [{self.faces.min()}, {self.faces.max()}]"
            )

    @property
    def bounds(self) -> np.ndarray:
        """[2, 3] axis-aligned bounding box (min, max), metres."""
        if len(self.points) == 0:
            return np.zeros((2, 3))
        return np.stack([self.points.min(axis=0), self.points.max(axis=0)])


@dataclass(kw_only=True)
class SdfField:
    """A signed distance field sampled on a regular grid in object coordinates (negative inside)."""

    grid: np.ndarray
    """[X, Y, Z] float32 signed distances, metres; sample (i, j, k) sits at origin + voxel_size * (i, j, k)."""
    origin: np.ndarray
    """[3] position of sample (0, 0, 0) in object coordinates, metres."""
    voxel_size: float
    """Grid spacing, metres."""
    iso_level: float = 0.0
    """SDF value of the surface, metres."""

    def __post_init__(self) -> None:
        self.grid = _array(self.grid, np.float32, (None, None, None), "SdfField.grid")
        self.origin = _array(self.origin, np.float64, (3,), "SdfField.origin")
        if not (np.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise InvalidDataError(f"SdfField.voxel_size must be a positive number of metres, got {self.voxel_size}")
        self.voxel_size = float(self.voxel_size)
        self.iso_level = float(self.iso_level)

    @property
    def resolution(self) -> tuple[int, int, int]:
        """Number of samples along x, y, z."""
        x, y, z = self.grid.shape
        return (int(x), int(y), int(z))


_BINDING_FIELDS = ("face_index", "barycentric", "normal_offset", "in_plane_rotation", "in_plane_scale")


@dataclass(kw_only=True)
class GaussianSplats:
    """3D Gaussian splats in object coordinates, optionally bound to the faces of the node's mesh.

    Appearance is the UsdVol.ParticleField3DGaussianSplat convention: linear opacities in [0, 1], scales are
    standard deviations in metres, radiance as real spherical-harmonics coefficients (degree 0 = base colour).
    The binding fields are either all given (splats on a mesh, HoloGaussianOnMeshAPI) or all None.
    """

    positions: np.ndarray
    """[N, 3] centres, metres."""
    orientations: np.ndarray
    """[N, 4] unit quaternions (x, y, z, w)."""
    scales: np.ndarray
    """[N, 3] standard deviations along the local axes, metres."""
    opacities: np.ndarray
    """[N] opacity in [0, 1]."""
    sh_coeffs: np.ndarray
    """[N, K, 3] spherical-harmonics radiance coefficients, K = (degree + 1) ** 2."""
    face_index: np.ndarray | None = None
    """[N] triangle of the mesh each splat is bound to."""
    barycentric: np.ndarray | None = None
    """[N, 3] barycentric coordinates on that triangle (rows sum to 1)."""
    normal_offset: np.ndarray | None = None
    """[N] offset along the face normal, metres."""
    in_plane_rotation: np.ndarray | None = None
    """[N] rotation about the face normal from the face's first edge, radians."""
    in_plane_scale: np.ndarray | None = None
    """[N, 2] standard deviations along the two in-plane axes, metres."""

    def __post_init__(self) -> None:
        self.positions = _array(self.positions, np.float32, (None, 3), "GaussianSplats.positions")
        n = len(self.positions)
        self.orientations = _array(self.orientations, np.float32, (n, 4), "GaussianSplats.orientations")
        self.scales = _array(self.scales, np.float32, (n, 3), "GaussianSplats.scales")
        self.opacities = _array(self.opacities, np.float32, (n,), "GaussianSplats.opacities")
        self.sh_coeffs = _array(self.sh_coeffs, np.float32, (n, None, 3), "GaussianSplats.sh_coeffs")
        k = self.sh_coeffs.shape[1]
        if round(np.sqrt(k)) ** 2 != k or k == 0:
            raise InvalidDataError(f"GaussianSplats.sh_coeffs: K must be (degree + 1) ** 2, got K = {k}")
        given = [name for name in _BINDING_FIELDS if getattr(self, name) is not None]
        if given and len(given) != len(_BINDING_FIELDS):
            missing = sorted(set(_BINDING_FIELDS) - set(given))
            raise InvalidDataError(f"GaussianSplats: binding fields are all or nothing; missing {missing}")
        if given:
            self.face_index = _array(self.face_index, np.int32, (n,), "GaussianSplats.face_index")
            self.barycentric = _array(self.barycentric, np.float32, (n, 3), "GaussianSplats.barycentric")
            self.normal_offset = _array(self.normal_offset, np.float32, (n,), "GaussianSplats.normal_offset")
            self.in_plane_rotation = _array(
                self.in_plane_rotation, np.float32, (n,), "GaussianSplats.in_plane_rotation"
            )
            self.in_plane_scale = _array(self.in_plane_scale, np.float32, (n, 2), "GaussianSplats.in_plane_scale")

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def sh_degree(self) -> int:
        """Spherical-harmonics degree of ``sh_coeffs``."""
        return round(np.sqrt(self.sh_coeffs.shape[1])) - 1

    @property
    def bound(self) -> bool:
        """True when the splats carry a face binding."""
        return self.face_index is not None


@dataclass(kw_only=True)
class PhysicsProps:
    """Rigid-body and material properties of a node (UsdPhysics MassAPI + MaterialAPI + HoloPhysicsAPI)."""

    mass: float | None
    """Total mass, kilograms; None for a static collider (the background), which gets no rigid body."""
    center_of_mass: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """[3] centre of mass in object coordinates, metres."""
    diagonal_inertia: np.ndarray | None = None
    """[3] principal moments of inertia about the centre of mass, kg m^2; None: the simulator derives the
    inertia from the colliders."""
    principal_axes: np.ndarray | None = None
    """[4] quaternion (x, y, z, w) from the object axes to the principal axes of ``diagonal_inertia``; None:
    the object axes."""
    density: float = 1000.0
    """Material density, kg / m^3 (mass wins where both are given, as in UsdPhysics)."""
    static_friction: float = 0.5
    """Static Coulomb friction coefficient."""
    dynamic_friction: float = 0.5
    """Dynamic Coulomb friction coefficient."""
    restitution: float = 0.0
    """Coefficient of restitution in [0, 1]."""
    linear_damping: float = 0.0
    """Linear velocity damping, 1/s."""
    angular_damping: float = 0.0
    """Angular velocity damping, 1/s."""

    def __post_init__(self) -> None:
        self.center_of_mass = _array(self.center_of_mass, np.float64, (3,), "PhysicsProps.center_of_mass")
        if self.diagonal_inertia is not None:
            self.diagonal_inertia = _array(self.diagonal_inertia, np.float64, (3,), "PhysicsProps.diagonal_inertia")
        if self.principal_axes is not None:
            self.principal_axes = _array(self.principal_axes, np.float64, (4,), "PhysicsProps.principal_axes")
            norm = float(np.linalg.norm(self.principal_axes))
            if not norm > 0:
                raise InvalidDataError("PhysicsProps.principal_axes must be a unit quaternion (x, y, z, w)")
            self.principal_axes = self.principal_axes / norm
        for name in ("density", "static_friction", "dynamic_friction", "restitution",
                     "linear_damping", "angular_damping"):  # fmt: skip
            value = float(getattr(self, name))
            if not np.isfinite(value) or value < 0:
                raise InvalidDataError(f"PhysicsProps.{name} must be a finite non-negative number, got {value}")
            setattr(self, name, value)
        if self.mass is not None:
            self.mass = float(self.mass)
            if not (np.isfinite(self.mass) and self.mass > 0):
                raise InvalidDataError(f"PhysicsProps.mass must be a positive number of kilograms, got {self.mass}")


@dataclass(kw_only=True)
class Collider:
    """The collision geometry of a node: one or more meshes in object coordinates."""

    approximation: str
    """'convexHull' (one hull), 'convexDecomposition' (several convex parts) or 'none' (the triangle mesh)."""
    parts: list[MeshData]
    """The collider meshes (one for convexHull and none)."""

    def __post_init__(self) -> None:
        if self.approximation not in COLLIDER_APPROXIMATIONS:
            raise InvalidDataError(
                f"Collider.approximation must be one of {COLLIDER_APPROXIMATIONS}, got {self.approximation!r}"
            )
        if not self.parts:
            raise InvalidDataError("Collider.parts: at least one mesh is required")
        if self.approximation != "convexDecomposition" and len(self.parts) != 1:
            raise InvalidDataError(f"Collider: approximation {self.approximation!r} takes exactly one mesh")


@dataclass(kw_only=True)
class Energies:
    """Energies the physics search measured for a node (HoloEnergyAPI)."""

    stable: float
    """E_stable: 0 when the object stands in the search's check, else 1 + its centre of mass's distance outside
    its support polygon in cm (``solver`` says how it was measured)."""
    touch: float
    """E_touch: distance to the support parent's surface, metres."""
    penetration: float
    """E_pene: intersection volume with other nodes, m^3."""
    candidate: int = -1
    """Index of the chosen completion candidate in ``candidates`` (-1 = none)."""
    observation: float = 0.0
    """E_obs of the chosen candidate ((1 - mask IoU) + depth residual / 5 cm + seen-through fraction)."""
    total: float = 0.0
    """Weighted total of the chosen candidate (lower is better); -1 when E_obs rejected every candidate and the
    fitted shape was kept."""
    candidates: list[str] = field(default_factory=list)
    """Candidates tried, ``'proposer#seed'``, in proposal order."""
    totals: list[float] = field(default_factory=list)
    """Weighted total of each candidate (inf: rejected by E_obs)."""
    solver: str = ""
    """How E_stable was measured."""
    stands_once_set_up: bool = False
    """The chosen candidate does not stand on the parent's shape as chosen (``stable`` > 0) but does on the
    parent's top as the physics set-up leaves it (see ``SearchConfig.settle_beyond``)."""

    @property
    def stands(self) -> bool:
        """The search's verdict: the chosen candidate stands (E_stable 0, or it stands once the parent is set up)."""
        return self.stable == 0.0 or self.stands_once_set_up

    @property
    def chosen(self) -> str | None:
        """The chosen candidate's label (``'proposer#seed'``), None when the search chose none."""
        return self.candidates[self.candidate] if 0 <= self.candidate < len(self.candidates) else None

    def runner_up(self) -> tuple[str, float] | None:
        """The lowest-total candidate other than the chosen one that E_obs did not reject, as (label, total);
        None when there is none."""
        live = [(t, c) for i, (t, c) in enumerate(zip(self.totals, self.candidates, strict=False))
                if i != self.candidate and math.isfinite(t)]  # fmt: skip
        return (min(live)[1], min(live)[0]) if live else None


@dataclass(kw_only=True, frozen=True)
class NodeInfo:
    """Identity of a scene-graph node (HoloNodeAPI)."""

    name: str
    """Node name: 'background' or the object's prim name under /World/Objects."""
    path: str
    """Prim path."""
    role: str
    """'background' or 'object'."""
    instance_id: int
    """Instance id in the observations' masks."""
    observed_fraction: float
    """Fraction of the surface the observations saw, [0, 1]."""
    provenance: str
    """Stage or tool that last wrote the node."""


@dataclass(kw_only=True)
class CameraData:
    """A pinhole observation camera in the OpenCV convention (x right, y down, z forward; world Z up, metres)."""

    name: str
    """Prim name under /World/Cameras (a valid identifier, e.g. 'Frame_00012')."""
    K: np.ndarray
    """[3, 3] intrinsics: fx, fy, cx, cy in pixels (pixel centres at integer + 0.5 coordinates)."""
    cam_to_world: np.ndarray
    """[4, 4] rigid camera-to-world transform (OpenCV camera axes)."""
    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""
    image: str | None = None
    """Path of the frame's RGB image (absolute, or relative to the scene layer), if any."""
    frame_id: str = ""
    """Identifier of the frame in its capture."""
    pose_move: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """[3] how far s1_fit moved the camera's centre from the capture's pose, world frame, metres (zero: as
    given; ``holo:camera:poseMove``)."""
    pose_turn_deg: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """[3] how far s1_fit turned the camera about its centre from the capture's pose, world axis times angle,
    degrees (``holo:camera:poseTurn``)."""

    def __post_init__(self) -> None:
        self.K = _array(self.K, np.float64, (3, 3), "CameraData.K")
        self.pose_move = _array(self.pose_move, np.float64, (3,), "CameraData.pose_move")
        self.pose_turn_deg = _array(self.pose_turn_deg, np.float64, (3,), "CameraData.pose_turn_deg")
        self.cam_to_world = _array(self.cam_to_world, np.float64, (4, 4), "CameraData.cam_to_world")
        rot = self.cam_to_world[:3, :3]
        if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-4) or np.linalg.det(rot) < 0:
            raise InvalidDataError(f"CameraData {self.name!r}: cam_to_world rotation is not a proper rotation")
        if self.width <= 0 or self.height <= 0:
            raise InvalidDataError(
                f"CameraData {self.name!r}: image size must be positive, got {self.width}x{self.height}"
            )
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
            raise InvalidDataError(f"CameraData {self.name!r}: focal lengths must be positive")


@dataclass(kw_only=True)
class GeometryRecord:
    """How an object's final geometry relates to what was observed and to its collider (``HoloGeometryAPI``)."""

    fit_shift: np.ndarray
    """[3] move of the object from the pose the fit gave it, metres (world axes)."""
    collider_reach: float
    """How far the collider reaches outside the rendered mesh, metres."""
    penetration: float
    """Deepest overlap of the rendered mesh with another node's, metres."""
    volume: float
    """Volume of the rendered mesh (what the mass is computed from), m^3."""
    edits: list[str]
    """What was done to the mesh, in order (e.g. ``clip:wall``, ``cut:base``, ``cut:neighbour:box_1``)."""
