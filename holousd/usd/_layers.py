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

__all__ = ["data_layer_path", "layer_path", "new_layer_over", "open_layer_stack", "save_layer", "usd_error_text"]

ARRAY_LIMIT = 64
"""Array values longer than this are stored in the layer's crate data file, not in its text (the bound of
NVIDIA's UsdAsciiPerformanceChecker: text layers with longer arrays are slow to read)."""
SAMPLE_LIMIT = 4
"""Attributes with more time samples than this are stored in the crate data file too (the same checker's bound)."""

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


def sublayer_files(layer: Sdf.Layer) -> list[Path]:
    """The files ``layer`` sublayers, resolved to absolute paths."""
    return [Path(layer.ComputeAbsolutePath(p)).resolve() for p in layer.subLayerPaths]


def data_layer_path(layer_file: str | os.PathLike[str]) -> Path:
    """The crate file holding the large arrays of the text layer ``layer_file``: ``assets/<stem>/arrays.usdc``
    beside it, sublayered first (just under the text layer, over everything below it)."""
    layer_file = Path(layer_file)
    return layer_file.parent / "assets" / layer_file.stem / "arrays.usdc"


def _attribute_paths(layer: Sdf.Layer) -> list[Sdf.Path]:
    paths: list[Sdf.Path] = []

    def visit(path: Sdf.Path) -> None:
        if path.IsPropertyPath() and layer.GetAttributeAtPath(path):
            paths.append(path)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return paths


def _heavy(layer: Sdf.Layer, spec: Sdf.AttributeSpec) -> bool:
    if spec.typeName in (Sdf.ValueTypeNames.Asset, Sdf.ValueTypeNames.AssetArray):
        return False  # asset paths resolve against the layer that holds them: they stay in the text layer
    if layer.GetNumTimeSamplesForPath(spec.path) > SAMPLE_LIMIT:
        return True
    if not spec.typeName.isArray:
        return False
    values = [spec.default] if spec.HasDefaultValue() else []
    values += [layer.QueryTimeSample(spec.path, t) for t in layer.ListTimeSamplesForPath(spec.path)]
    return any(v is not None and not isinstance(v, Sdf.ValueBlock) and len(v) > ARRAY_LIMIT for v in values)


def _split(layer: Sdf.Layer, target: Path) -> tuple[Sdf.Layer, Sdf.Layer | None]:
    """A copy of ``layer`` as (text layer, crate layer with its large arrays and long time samples, or None).

    A layer read back from disk already sublayers its data file: those attributes are folded back in first (where
    the text layer still has their prim and no newer value), so that the split is always of the whole layer.
    """
    data_file = data_layer_path(target)
    text = Sdf.Layer.CreateAnonymous(".usda")
    text.TransferContent(layer)
    source = layer_path(layer)  # where the layer was read from: its sublayer paths are relative to that folder
    own = {data_file} | ({data_layer_path(source.absolute())} if source is not None else set())
    base = (source.absolute() if source is not None else target).parent
    for sub in list(text.subLayerPaths):
        found = Path(os.path.normpath(base / sub))
        if found not in own:
            continue
        old = Sdf.Layer.FindOrOpen(str(found)) if found.is_file() else None
        if old is None:  # a data file the layer sublayers must be there to fold
            raise SceneError(f"{source or target}: its data file {found} is missing; restore it (assets/ folder) "
                             "before saving the layer")  # fmt: skip
        for path in _attribute_paths(old) if old is not None else []:
            if text.GetPrimAtPath(path.GetPrimPath()) and not text.GetAttributeAtPath(path):
                Sdf.CopySpec(old, path, text, path)
        text.subLayerPaths.remove(sub)
    data = Sdf.Layer.CreateAnonymous(".usdc")
    # Time codes per second must match, or USD rescales the crate file's time samples to the text layer's rate.
    if text.HasTimeCodesPerSecond():
        data.timeCodesPerSecond = text.timeCodesPerSecond
    if text.HasFramesPerSecond():
        data.framesPerSecond = text.framesPerSecond
    for path in _attribute_paths(text):
        spec = text.GetAttributeAtPath(path)
        if not _heavy(text, spec):
            continue
        Sdf.CreatePrimInLayer(data, path.GetPrimPath())  # an over, as are its ancestors
        Sdf.CopySpec(text, path, data, path)
        text.GetPrimAtPath(path.GetPrimPath()).RemoveProperty(spec)
    if data.pseudoRoot.nameChildren:
        text.subLayerPaths.insert(0, _relative(data_file, target.parent))
        return text, data
    return text, None


def save_layer(layer: Sdf.Layer, path: str | os.PathLike[str] | None = None, *, split: bool = True) -> Path:
    """Write ``layer`` to ``path`` (default: its own file) atomically: temp file, then rename.

    A text (``.usda``) layer keeps its large arrays and long time samples (see :data:`ARRAY_LIMIT`) in a crate
    file of its own, :func:`data_layer_path`, which it sublayers first, unless ``split`` is False (a flattened,
    self-contained file). The layer in memory stays whole.

    Returns:
        The path written.
    """
    target = Path(path) if path is not None else layer_path(layer)
    if target is None:
        raise SceneError("the scene is in memory: give a file path to save it to")
    target = target.absolute()
    out, data = layer, None
    if split and target.suffix == ".usda":
        out, data = _split(layer, target)
    data_file = data_layer_path(target)
    if data is not None:  # both files written in full before either replaces what was there
        with atomic_path(data_file) as data_tmp:
            _export(data, data_file, data_tmp)
            _export(out, target)
        loaded = Sdf.Layer.Find(str(data_file))
        if loaded is not None:
            loaded.Reload(force=True)  # a stage holding the old data file sees the new one
        return target
    _export(out, target)
    if split and target.suffix == ".usda" and data_file.is_file():
        data_file.unlink()  # this layer has no large arrays any more
    return target


def _export(layer: Sdf.Layer, target: Path, tmp: Path | None = None) -> None:
    """Write ``layer`` for ``target``: to ``tmp`` (the caller renames it), else to a temporary file renamed over
    ``target``."""
    if tmp is not None:
        if not layer.Export(str(tmp)):
            raise SceneError(f"{target}: USD failed to write the layer; check disk space and permissions")
        return
    with atomic_path(target) as temp:
        _export(layer, target, temp)


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
