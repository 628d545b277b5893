"""Layer plumbing: new layers stacked over a scene, metadata copying and atomic saves.

Every stage transform and every user edit writes a layer of its own that sublayers the layer below and holds
only what it changes; nothing below is ever rewritten.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from pxr import Sdf, Tf, UsdUtils

from holousd._atomic import atomic_path
from holousd._errors import SceneError

__all__ = ["layer_path", "new_layer_over", "open_layer_stack", "save_layer", "usd_error_text"]

_TF_ENTRY = re.compile(r"Error in '[^']*' at line \d+ in file [^:]*: '(.*)'\s*$")
_PXR_NAMESPACE = re.compile(r"pxrInternal_v\w+?__pxrReserved__::")
_PARSE_ERROR = re.compile(r"^.*?:(\d+):(\d+): parse error.*?(?: in (<[^>]*>))?\s*$")


def usd_error_text(exc: BaseException) -> str:
    """What a USD (``Tf.ErrorException``) error says is wrong with a file, in a few plain words: the most
    specific message, without the C++ function names, source files and line numbers of USD itself."""
    messages = []
    for line in str(exc).splitlines():
        m = _TF_ENTRY.search(line.strip())
        text = m.group(1) if m else line.strip()
        if text and not text.startswith("Failed to open layer"):
            messages.append(text)
    if not messages:
        return "not a readable USD file"
    text = messages[0]
    parse = _PARSE_ERROR.match(text)
    if parse:
        where = f" in {parse.group(3)}" if parse.group(3) else ""
        return f"syntax error at line {parse.group(1)}, column {parse.group(2)}{where}"
    text = _PXR_NAMESPACE.sub("", text)
    text = re.sub(r"@[^@]+@|<[^<>]+\.usd[acz]?>", "the file", text)  # the caller names the file once, up front
    return " ".join(text.split())


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


def open_layer_stack(path: Path, seen: frozenset[Path] = frozenset()) -> list[Sdf.Layer]:
    """The layers of the stack at ``path``, opened; raises a one-line :class:`SceneError` when one is missing or
    unreadable (USD itself would only print a warning, skip the layer and open a scene with parts gone)."""
    layer = Sdf.Layer.FindOrOpen(str(path))
    if layer is None:
        raise SceneError(f"{path}: cannot be read as USD; is the file corrupt?")
    layers = [layer]
    for sub in layer.subLayerPaths:
        resolved = layer.ComputeAbsolutePath(sub)
        if "[" in resolved or str(path).endswith("]") or Path(path).suffix == ".usdz":
            continue  # inside a .usdz package: USD opens it from the archive
        target = Path(resolved)
        if target in seen:
            raise SceneError(f"{path}: sublayers {sub} in a loop; remove the repeated sublayer")
        if not target.is_file():
            raise SceneError(f"{path}: its sublayer {sub} is missing ({target}); restore it, or re-run the stage that "
                             "writes it (holousd reconstruct ... --resume)")  # fmt: skip
        try:
            layers += open_layer_stack(target, seen | {path.absolute()})
        except Tf.ErrorException as exc:
            raise SceneError(f"{target}: sublayer of {path.name} cannot be read as USD ({usd_error_text(exc)}); "
                             "restore it or re-run the stage that writes it") from exc  # fmt: skip
    return layers
