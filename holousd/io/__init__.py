"""Observations I/O: the :class:`Observations` type every stage reads, and readers / writers for captures.

Formats (FORMAT.md): ``native`` (``observations.json`` + per-frame files), ``nerfstudio`` (``transforms.json``
+ ``instance_mask/``), ``monosdf`` (MonoSDF / ObjectSDF++: ``cameras.npz``, ``*_rgb.png``, ``*_depth.npy``,
``*_normal.npy``, ``segs/``) and ``video`` (a video file + ``cameras.json`` + per-frame side files).
"""

from holousd.io._formats import FORMATS, detect_format, load, write
from holousd.io._monosdf import decompose_projection
from holousd.io._observations import DEPTH_KINDS, CaptureCheck, Frame, LazyArray, Observations, ObservationsError

__all__ = [
    "DEPTH_KINDS",
    "CaptureCheck",
    "FORMATS",
    "Frame",
    "LazyArray",
    "Observations",
    "ObservationsError",
    "decompose_projection",
    "detect_format",
    "load",
    "write",
]
