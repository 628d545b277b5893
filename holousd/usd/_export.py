"""Export: a flattened, self-contained physics scene for simulators, and a USDZ package of the full scene."""

from __future__ import annotations

import os
from pathlib import Path

from pxr import Sdf, Usd, UsdGeom, UsdUtils, UsdVol

from holousd._atomic import atomic_path
from holousd._errors import SceneError
from holousd.usd._layers import layer_path, save_layer

__all__ = ["export_sim", "export_usdz"]

_DROPPED_SCOPES = ("/World/Cameras",)


def export_sim(stage: Usd.Stage, out: str | os.PathLike[str]) -> Path:
    """Write one flattened physics scene: meshes, colliders, rigid bodies, materials, relations.

    Splats, cameras and SDF grids (everything that lives in external files or only serves appearance) are left
    out, so the result is a single self-contained file that Newton's ``ModelBuilder.add_usd``, Isaac Sim or
    any UsdPhysics reader loads. Stage metadata (upAxis, metersPerUnit, kilogramsPerUnit) is kept.

    Args:
        stage: The composed scene (all layers).
        out: Output file (.usda or .usdc), written atomically.

    Returns:
        The path written.
    """
    flat = stage.Flatten()
    sim = Usd.Stage.Open(flat)
    dropped = [p.GetPath() for p in sim.Traverse() if p.IsA(UsdVol.ParticleField) or p.IsA(UsdGeom.Camera)]
    dropped += [Sdf.Path(p) for p in _DROPPED_SCOPES if sim.GetPrimAtPath(p)]
    for path in sorted(set(dropped), key=lambda p: p.pathElementCount, reverse=True):
        sim.RemovePrim(path)
    for prim in sim.Traverse():
        if "HoloSdfAPI" in prim.GetAppliedSchemas():
            prim.RemoveAPI("HoloSdfAPI")
            for prop in prim.GetPropertiesInNamespace("holo:sdf"):
                prim.RemoveProperty(prop.GetName())
    data = dict(flat.customLayerData)
    holo = dict(data.get("holousd", {}))
    holo["exportedFrom"] = stage.GetRootLayer().identifier
    holo["exportKind"] = "sim"
    data["holousd"] = holo
    flat.customLayerData = data
    return save_layer(flat, out)


def export_usdz(stage: Usd.Stage, out: str | os.PathLike[str]) -> Path:
    """Package the full scene (all layers, per-object splat files, SDF grids) into one .usdz archive.

    Args:
        stage: The scene; its root layer must be saved to a file.
        out: Output .usdz file, written atomically.

    Returns:
        The path written.
    """
    out = Path(out)
    if out.suffix != ".usdz":
        raise SceneError(f"{out}: a USDZ package must end in .usdz")
    root = layer_path(stage.GetRootLayer())
    if root is None:
        raise SceneError("the scene is in memory: save it to a file before packaging it as USDZ")
    if stage.GetRootLayer().dirty:
        raise SceneError(f"{root}: has unsaved changes; save the scene before packaging it")
    with atomic_path(out) as tmp:
        if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(root)), str(tmp)):
            raise SceneError(f"{out}: USD could not package {root}; run 'holousd validate' on it first")
    return out
