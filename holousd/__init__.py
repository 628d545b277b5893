"""holousd: video of a room -> simulation-ready, interactive USD scene graph.

``import holousd`` registers the holousd USD schema plugin (before anything builds USD's schema registry) and
exposes the public API. It never imports torch, warp or newton: those load inside the functions that need them.
"""

from holousd.usd import _plugin

_plugin.register()

from holousd._errors import HolousdError, InvalidDataError, SceneError, SchemaVersionError  # noqa: E402
from holousd.usd import (  # noqa: E402
    BACKGROUND,
    SCHEMA_VERSION,
    CameraData,
    Collider,
    Energies,
    GaussianSplats,
    GeometryRecord,
    MeshData,
    NodeInfo,
    PhysicsProps,
    Pose,
    SceneGraph,
    SdfField,
    ValidationReport,
    export_sim,
    export_usdz,
    validate,
)

__version__ = "0.1.0"

__all__ = [
    "BACKGROUND",
    "SCHEMA_VERSION",
    "CameraData",
    "Collider",
    "Energies",
    "GaussianSplats",
    "GeometryRecord",
    "HolousdError",
    "InvalidDataError",
    "MeshData",
    "NodeInfo",
    "PhysicsProps",
    "Pose",
    "SceneError",
    "SceneGraph",
    "SchemaVersionError",
    "SdfField",
    "ValidationReport",
    "__version__",
    "export_sim",
    "export_usdz",
    "validate",
]
