"""Format detection and the two entry points: :func:`load` and :func:`write`."""

from __future__ import annotations

import os
from pathlib import Path

from holousd.io._monosdf import CAMERAS, read_monosdf, write_monosdf
from holousd.io._native import (
    MANIFEST,
    VIDEO_MANIFEST,
    VIDEO_SUFFIXES,
    find_video,
    read_native,
    read_video,
    write_native,
    write_video,
)
from holousd.io._nerfstudio import TRANSFORMS, read_nerfstudio, write_nerfstudio
from holousd.io._observations import Observations, ObservationsError

__all__ = ["FORMATS", "detect_format", "load", "write"]

FORMATS = ("native", "nerfstudio", "monosdf", "video")
"""Capture formats holousd reads and writes (see FORMAT.md)."""

_READERS = {"native": read_native, "nerfstudio": read_nerfstudio, "monosdf": read_monosdf, "video": read_video}
_WRITERS = {"native": write_native, "nerfstudio": write_nerfstudio, "monosdf": write_monosdf, "video": write_video}


def detect_format(path: str | os.PathLike[str]) -> str:
    """Name the format of a capture folder (or video file) from the files it holds.

    ``observations.json`` -> native; ``transforms.json`` -> nerfstudio; ``cameras.npz`` + ``*_rgb.png`` ->
    monosdf; a video file with ``cameras.json`` -> video.

    Raises:
        ObservationsError: ``path`` does not exist or holds none of these.
    """
    path = Path(path)
    if path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES:
        return "video"
    if not path.is_dir():
        raise ObservationsError(f"{path}: no such folder; give the folder of a capture (or a video file)")
    if (path / MANIFEST).is_file():
        return "native"
    if (path / TRANSFORMS).is_file():
        return "nerfstudio"
    if (path / CAMERAS).is_file() or any(path.glob("*_rgb.png")):
        return "monosdf"
    if (path / VIDEO_MANIFEST).is_file() and find_video(path) is not None:
        return "video"
    raise ObservationsError(
        f"{path}: not a capture holousd recognises (no {MANIFEST}, {TRANSFORMS}, {CAMERAS} + *_rgb.png, or a "
        f"video with {VIDEO_MANIFEST}); see holousd/io/FORMAT.md"
    )


def load(path: str | os.PathLike[str], *, format: str | None = None) -> Observations:  # noqa: A002
    """Open a capture lazily (frames are read on access).

    Args:
        path: Capture folder, or a video file with ``cameras.json`` beside it.
        format: One of :data:`FORMATS`; default: detected with :func:`detect_format`.

    Returns:
        The observations; call ``validate()`` to check every frame.
    """
    fmt = format or detect_format(path)
    if fmt not in _READERS:
        raise ObservationsError(f"unknown capture format {fmt!r}; choose one of {', '.join(FORMATS)}")
    return _READERS[fmt](Path(path))


def write(
    obs: Observations,
    path: str | os.PathLike[str],
    *,
    format: str = "native",
    progress: bool = False,  # noqa: A002
) -> Path:
    """Write ``obs`` to the folder ``path`` in ``format`` (files are written atomically, one by one).

    Returns:
        The main file written (manifest, ``transforms.json`` or ``cameras.npz``).
    """
    if format not in _WRITERS:
        raise ObservationsError(f"unknown capture format {format!r}; choose one of {', '.join(FORMATS)}")
    if len(obs) == 0:
        raise ObservationsError(f"{path}: nothing to write, the observations have no frames")
    return _WRITERS[format](obs, Path(path), progress=progress)
