"""Layer plumbing: new layers stacked over a scene, metadata copying and atomic saves.

Every stage transform and every user edit writes a layer of its own that sublayers the layer below and holds
only what it changes; nothing below is ever rewritten.
"""

from __future__ import annotations

import os
from pathlib import Path

from pxr import Sdf, UsdUtils

from holousd._atomic import atomic_path
from holousd._errors import SceneError

__all__ = ["layer_path", "new_layer_over", "save_layer"]


def layer_path(layer: Sdf.Layer) -> Path | None:
    """Return the file of ``layer``, or None for an in-memory (anonymous) layer."""
    if layer.anonymous:
        return None
    return Path(layer.realPath or layer.identifier)


def _relative(target: Path, start_dir: Path) -> str:
    rel = os.path.relpath(target, start_dir).replace(os.sep, "/")
    return rel if rel.startswith(".") else f"./{rel}"


def new_layer_over(base: Sdf.Layer, path: str | os.PathLike[str]) -> Sdf.Layer:
    """Create (in memory, not yet on disk) a layer at ``path`` that sublayers ``base``.

    Root-layer metadata that USD reads only from the root (upAxis, metersPerUnit, kilogramsPerUnit,
    defaultPrim, customLayerData) is copied from ``base``, so the new layer opens as a complete scene.

    Args:
        base: The layer to stack on; it must be saved to a file.
        path: File the new layer will be saved to (``.usda``, ``.usdc`` or ``.usd``).

    Returns:
        The new layer; call :func:`save_layer` to write it.
    """
    path = Path(path).absolute()
    base_file = layer_path(base)
    if base_file is None:
        raise SceneError(f"cannot stack {path} on an in-memory scene: save the scene to a file first")
    if path.resolve() == base_file.resolve():
        raise SceneError(f"{path}: a layer cannot sublayer itself; choose a different file name")
    file_format = Sdf.FileFormat.FindByExtension(path.suffix.lstrip("."))
    if file_format is None:
        raise SceneError(f"{path}: unknown layer extension; use .usda, .usdc or .usd")
    existing = Sdf.Layer.Find(str(path))
    if existing is not None:
        existing.Clear()
        layer = existing
    else:
        layer = Sdf.Layer.New(file_format, str(path))
        if layer is None:
            raise SceneError(f"{path}: USD could not create a layer there; check the folder is writable")
    UsdUtils.CopyLayerMetadata(base, layer, skipSublayers=True)
    layer.subLayerPaths.append(_relative(base_file, path.parent))
    return layer


def save_layer(layer: Sdf.Layer, path: str | os.PathLike[str] | None = None) -> Path:
    """Write ``layer`` to ``path`` (default: its own file) atomically: temp file, then rename.

    Returns:
        The path written.
    """
    target = Path(path) if path is not None else layer_path(layer)
    if target is None:
        raise SceneError("the scene is in memory: give a file path to save it to")
    with atomic_path(target) as tmp:
        if not layer.Export(str(tmp)):
            raise SceneError(f"{target}: USD failed to write the layer; check disk space and permissions")
    return target
