"""Reading and writing the per-frame files of captures: images, arrays, JSON; atomic and byte-deterministic.

Writers produce identical bytes for identical inputs: PNGs carry no time chunk, JSON keeps insertion order,
``.npz`` archives get a fixed zip timestamp (``np.savez`` stamps the current time).
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np

from holousd._atomic import atomic_path
from holousd.io._observations import LazyArray, ObservationsError

__all__ = [
    "lazy",
    "read_depth_png",
    "read_json",
    "read_mask",
    "read_normal_png",
    "read_npy",
    "read_rgb",
    "write_json",
    "write_npy",
    "write_npz",
    "write_png",
]

_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def _open_image(path: Path):  # noqa: ANN202 - PIL image
    from PIL import Image, UnidentifiedImageError

    if not path.is_file():
        raise ObservationsError(f"{path}: file is missing; restore it or remove the frame from the capture")
    try:
        image = Image.open(path)
        image.load()
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        raise ObservationsError(f"{path}: cannot be decoded as an image ({exc}); is the file corrupt?") from exc
    return image


def read_rgb(path: Path) -> np.ndarray:
    """Read a colour image as [H, W, 3] uint8 (alpha dropped, grey expanded, 16-bit scaled down)."""
    image = _open_image(path)
    if image.mode in ("I;16", "I;16B", "I", "F"):
        arr = np.asarray(image, dtype=np.float64)
        arr = np.clip(arr / (65535.0 if image.mode.startswith("I;16") else max(arr.max(), 1.0)) * 255.0, 0, 255)
        return np.repeat(np.rint(arr).astype(np.uint8)[..., None], 3, axis=2)
    return np.asarray(image.convert("RGB"), dtype=np.uint8)


def read_mask(path: Path) -> np.ndarray:
    """Read an instance mask as [H, W] int32: a single-channel 8/16/32-bit PNG, or a ``.npy`` integer array."""
    if path.suffix == ".npy":
        arr = read_npy(path)
        if arr.dtype.kind not in "iu":
            raise ObservationsError(f"{path}: mask array has dtype {arr.dtype}; instance ids must be integers")
        return arr.astype(np.int32)
    image = _open_image(path)
    if image.mode not in ("1", "L", "P", "I;16", "I;16B", "I;16L", "I"):
        raise ObservationsError(
            f"{path}: mask is a {image.mode} image; instance masks must be single-channel integer images "
            "(8- or 16-bit grey PNG, 0 = background)"
        )
    return np.asarray(image).astype(np.int32)


def read_npy(path: Path) -> np.ndarray:
    """Read a ``.npy`` array (no pickles)."""
    if not path.is_file():
        raise ObservationsError(f"{path}: file is missing; restore it or remove the frame from the capture")
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise ObservationsError(f"{path}: cannot be read as a .npy array ({exc}); is the file corrupt?") from exc


def read_depth_png(path: Path, scale: float) -> np.ndarray:
    """Read a 16-bit depth PNG as [H, W] float32 = stored value / ``scale`` (1000: millimetres -> metres)."""
    image = _open_image(path)
    if image.mode not in ("I;16", "I;16B", "I;16L", "I", "L"):
        raise ObservationsError(f"{path}: depth PNG is a {image.mode} image; expected a 16-bit single-channel PNG")
    return (np.asarray(image).astype(np.float64) / scale).astype(np.float32)


def read_normal_png(path: Path) -> np.ndarray:
    """Read an 8-bit normal PNG (RGB = (n + 1) / 2 * 255) as [H, W, 3] float32; black pixels = no normal."""
    image = _open_image(path)
    arr = np.asarray(image.convert("RGB"), dtype=np.float32)
    normal = arr / 127.5 - 1.0
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    valid = arr.any(axis=-1, keepdims=True)
    return np.where(valid, normal / np.maximum(length, 1e-6), 0.0).astype(np.float32)


def read_json(path: Path, what: str) -> dict:
    """Read a JSON object file, with errors naming the file."""
    if not path.is_file():
        raise ObservationsError(f"{path}: {what} is missing; check the folder")
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ObservationsError(f"{path}: {what} is not valid JSON ({exc}); is the file corrupt?") from exc
    if not isinstance(data, dict):
        raise ObservationsError(f"{path}: {what} must hold a JSON object at the top level")
    return data


def lazy(read: object, path: Path, *args: object) -> LazyArray:
    """A :class:`LazyArray` calling ``read(path, *args)``."""
    return LazyArray(lambda: read(path, *args), str(path))  # type: ignore[operator]


def write_png(path: Path, array: np.ndarray) -> None:
    """Write [H, W, 3] uint8, [H, W] uint8 or [H, W] uint16 as PNG, atomically and deterministically."""
    from PIL import Image

    image = Image.fromarray(np.ascontiguousarray(array))  # uint16 [H, W] -> mode "I;16"
    with atomic_path(path) as tmp:
        image.save(tmp, format="PNG", compress_level=6)


def write_npy(path: Path, array: np.ndarray) -> None:
    """Write a ``.npy`` array atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.save(fh, np.ascontiguousarray(array), allow_pickle=False)


def write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write a ``.npz`` archive (np.load-compatible) with fixed zip timestamps, atomically."""
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, mode="w", compression=zipfile.ZIP_DEFLATED) as zf:
            for key, value in arrays.items():
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.ascontiguousarray(value), allow_pickle=False)
                info = zipfile.ZipInfo(f"{key}.npy", date_time=_ZIP_DATE)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                zf.writestr(info, buf.getvalue())


def write_json(path: Path, data: dict) -> None:
    """Write JSON (2-space indent, insertion key order, trailing newline) atomically."""
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
