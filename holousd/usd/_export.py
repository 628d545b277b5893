"""Export: a flattened, self-contained physics scene for simulators, a USDZ package of the full scene, and the
coloured meshes as glTF binaries for game engines and viewers."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdUtils, UsdVol

from holousd._atomic import atomic_path
from holousd._errors import SceneError
from holousd.usd._layers import layer_path, save_layer

__all__ = ["export_glb", "export_sim", "export_usdz", "write_node_files"]

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
    flat, sim = _flattened(stage, "sim")
    dropped = [p.GetPath() for p in sim.Traverse() if p.IsA(UsdVol.ParticleField) or p.IsA(UsdGeom.Camera)]
    dropped += [Sdf.Path(p) for p in _DROPPED_SCOPES if sim.GetPrimAtPath(p)]
    for path in sorted(set(dropped), key=lambda p: p.pathElementCount, reverse=True):
        sim.RemovePrim(path)
    _untextured(sim)
    return save_layer(flat, out, split=False)


def _untextured(stage: Usd.Stage) -> None:
    """Drop the baked textures (image files beside the scene: a sim file must stand alone): each visual
    material's diffuse colour reads the mesh's ``displayColor`` again, and the meshes lose their ``st``."""
    from pxr import UsdShade

    prims = list(stage.Traverse())
    for prim in prims:
        if prim.IsA(UsdGeom.Mesh):
            UsdGeom.PrimvarsAPI(prim).RemovePrimvar("st")
    for material in [p for p in prims if p.IsA(UsdShade.Material)]:
        surface, colour = material.GetChild("Surface"), material.GetChild("DisplayColor")
        if not material.GetChild("Texture"):
            continue
        if surface and colour:
            diffuse = UsdShade.Shader(surface).GetInput("diffuseColor")
            diffuse.ConnectToSource(UsdShade.Shader(colour).GetOutput("result"))
        for shader in ("Texture", "TexCoords"):
            stage.RemovePrim(material.GetPath().AppendChild(shader))


def _flattened(stage: Usd.Stage, kind: str) -> tuple[Sdf.Layer, Usd.Stage]:
    """The composed scene in one layer (and a stage on it to edit it) without HoloSdfAPI and its properties (the
    grids live in .npz files beside the layers), stamped with where it came from and the kind of export."""
    flat = stage.Flatten()
    opened = Usd.Stage.Open(flat)
    for prim in opened.Traverse():
        if "HoloSdfAPI" in prim.GetAppliedSchemas():
            prim.RemoveAPI("HoloSdfAPI")
            for prop in prim.GetPropertiesInNamespace("holo:sdf"):
                prim.RemoveProperty(prop.GetName())
    data = dict(flat.customLayerData)
    holo = dict(data.get("holousd", {}))
    holo["exportedFrom"] = stage.GetRootLayer().identifier
    holo["exportKind"] = kind
    data["holousd"] = holo
    flat.customLayerData = data
    return flat, opened


def export_usdz(stage: Usd.Stage, out: str | os.PathLike[str]) -> Path:
    """Package the scene as one self-contained .usdz archive: the composed scene flattened into one crate file
    (meshes, colliders, physics, relations, cameras, and the Gaussian splats inline).

    Left out, because a package may hold only USD, image and audio files: the SDF grids (.npz files, the fit's
    working state; the scene folder keeps them) and the cameras' links to the captured images (capture data,
    often thousands of frames).

    Args:
        stage: The scene; its root layer must be saved to a file.
        out: Output .usdz file, written atomically.

    Returns:
        The path written.
    """
    import tempfile

    out = Path(out)
    if out.suffix != ".usdz":
        raise SceneError(f"{out}: a USDZ package must end in .usdz")
    root = layer_path(stage.GetRootLayer())
    if root is None:
        raise SceneError("the scene is in memory: save it to a file before packaging it as USDZ")
    if stage.GetRootLayer().dirty:
        raise SceneError(f"{root}: has unsaved changes; save the scene before packaging it")
    flat, packed = _flattened(stage, "usdz")
    for prim in packed.Traverse():
        if prim.HasAttribute("holo:camera:image"):
            prim.RemoveProperty("holo:camera:image")
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".holousd-usdz-", dir=out.parent) as folder:
        inner = Path(folder) / f"{root.stem}.usdc"
        if not flat.Export(str(inner)):
            raise SceneError(f"{out}: USD could not write the flattened scene; check disk space")
        with atomic_path(out) as tmp:
            if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(inner)), str(tmp)):
                raise SceneError(f"{out}: USD could not package {root}; run 'holousd validate' on it first")
    return out


_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""USD's Z-up world to glTF's Y-up (+Y up, +Z towards the viewer): x stays, z becomes y, y becomes -z."""


def export_glb(scene, out: str | os.PathLike[str]) -> list[Path]:  # noqa: ANN001 - holousd.SceneGraph
    """Write every node's rendered mesh as ``out/<node>.glb`` and all of them as ``out/scene.glb`` (one named
    mesh per node): world frame (the node's pose, edit layers included) turned to glTF's Y-up, metres, with the
    texture baked by the appearance stage as the base colour texture (the mesh's points split where its UV atlas
    has seams), else the per-point colour as COLOR_0 (grey where none was baked). Each file is written whole to
    a temporary name, then renamed.

    Returns:
        The files written, the scene's last.
    """
    import trimesh

    meshes: list[tuple[str, trimesh.Trimesh]] = []
    for node in scene.nodes():
        try:
            mesh = scene.get_mesh(node.name)
        except SceneError:
            continue
        if len(mesh.faces) == 0:
            continue
        world = scene.get_pose(node.name).apply(np.asarray(mesh.points, np.float64)) @ _Y_UP.T
        texture = scene.get_surface_texture(node.name)
        if texture is not None:
            meshes.append((node.name, _textured(world, np.asarray(mesh.faces), *texture)))
            continue
        colors = scene.get_surface_color(node.name)
        rgba = np.full((len(world), 4), 255, np.uint8)
        rgba[:, :3] = np.round(255 * (np.clip(colors, 0, 1) if colors is not None else 0.5)).astype(np.uint8)
        meshes.append((node.name, trimesh.Trimesh(world, mesh.faces, vertex_colors=rgba, process=False)))
    if not meshes:
        raise SceneError(f"{scene.stage.GetRootLayer().identifier}: no node has a mesh to export; run the fit stage "
                         "(holousd reconstruct) first")  # fmt: skip
    whole = trimesh.Scene()
    for name, mesh in meshes:
        whole.add_geometry(mesh, node_name=name, geom_name=name)
    return write_node_files(out, [(name, mesh.export(file_type="glb")) for name, mesh in meshes],
                            whole.export(file_type="glb"), ".glb")  # fmt: skip


def _textured(points: np.ndarray, faces: np.ndarray, st: np.ndarray, image: np.ndarray):  # noqa: ANN202
    """A trimesh with one vertex per distinct (point, texture coordinate) pair and ``image`` as its base colour."""
    import trimesh
    from PIL import Image

    corner_keys = np.concatenate([faces.reshape(-1, 1).astype(np.float64), st.reshape(-1, 2)], axis=1)
    keys, index = np.unique(corner_keys, axis=0, return_inverse=True)
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(image), metallicFactor=0.0,
                                                   roughnessFactor=0.8)  # fmt: skip
    visual = trimesh.visual.TextureVisuals(uv=keys[:, 1:], material=material)
    return trimesh.Trimesh(points[keys[:, 0].astype(np.int64)], index.reshape(-1, 3), visual=visual, process=False)


def write_node_files(out: str | os.PathLike[str], nodes: list[tuple[str, bytes]], whole: bytes,
                     suffix: str) -> list[Path]:  # fmt: skip
    """Write ``out/<node><suffix>`` for each ``(node, content)`` and ``out/scene<suffix>`` with ``whole``, each
    whole to a temporary name, then renamed (the layout of the per-node exchange exports). Nothing is written when
    a node is named 'scene'.

    Returns:
        The files written, the scene's last.
    """
    if "scene" in {name for name, _ in nodes}:
        raise SceneError(f"a node is named 'scene', which would collide with scene{suffix}; rename it")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, content in [*nodes, ("scene", whole)]:
        target = out / f"{name}{suffix}"
        with atomic_path(target) as tmp:
            Path(tmp).write_bytes(content)
        written.append(target)
    return written
