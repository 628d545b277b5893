"""USD domain: schema plugin, the SceneGraph facade, layers, validation and export."""

from holousd.usd._export import export_sim, export_usdz
from holousd.usd._layers import data_layer_path, new_layer_over, save_layer
from holousd.usd._plugin import API_SCHEMAS, SCHEMA_VERSION, plugin_resources_dir, register
from holousd.usd._scene import (
    BACKGROUND,
    NodeSummary,
    SceneGraph,
    SceneSummary,
    read_mesh,
)
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
from holousd.usd._validate import ValidationIssue, ValidationReport, validate

__all__ = [
    "API_SCHEMAS",
    "BACKGROUND",
    "SCHEMA_VERSION",
    "CameraData",
    "Collider",
    "Energies",
    "GaussianSplats",
    "GeometryRecord",
    "MeshData",
    "NodeInfo",
    "NodeSummary",
    "PhysicsProps",
    "Pose",
    "SceneGraph",
    "SceneSummary",
    "SdfField",
    "ValidationIssue",
    "ValidationReport",
    "export_sim",
    "export_usdz",
    "new_layer_over",
    "plugin_resources_dir",
    "read_mesh",
    "register",
    "save_layer",
    "data_layer_path",
    "validate",
]
