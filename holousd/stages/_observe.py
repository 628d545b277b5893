"""Stage s0_observe: cameras, image references and one node per instance id (layer ``00_observe.usda``).

The first layer of every reconstruction: it records what was observed (one ``UsdGeom.Camera`` per frame with
its image path and frame id) and which nodes the later stages fill in (the background and one object per
instance id of the masks). It writes no geometry.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from holousd._errors import HolousdError
from holousd.io._observations import Observations
from holousd.usd._scene import BACKGROUND, SceneGraph
from holousd.usd._types import CameraData

__all__ = ["OBSERVE_LAYER", "ObserveConfig", "ObserveResult", "instance_table", "object_name", "require_masks", "run"]

OBSERVE_LAYER = "00_observe.usda"
"""File name of the layer this stage writes."""


@dataclass(kw_only=True)
class ObserveConfig:
    """Options of s0_observe."""

    overwrite: bool = True
    """Replace an existing ``00_observe.usda`` in the output folder (it is only replaced once saving succeeds)."""
    provenance: str = "s0_observe"
    """Writer name recorded on every node."""
    depth: str = "auto"
    """Where the depth every stage reads comes from: 'auto' (the capture's; a capture without any gets ``stereo``
    depth from its colour frames), 'capture' (the capture's only; without any, the masks alone), or a depth prior
    by name (``stereo``, ``learned``, a ``holousd.depth`` plug-in; :mod:`holousd.priors._depth`), used in place of
    the capture's depth when it has some."""
    depth_options: dict[str, str] = field(default_factory=dict)
    """Options of that depth prior (``{'weights': 'model.pt'}`` for ``learned``)."""


@dataclass(kw_only=True)
class ObserveResult:
    """What s0_observe found in the masks."""

    instance_ids: list[int] = field(default_factory=list)
    """Object instance ids, ascending (0, the background, excluded)."""
    names: dict[int, str] = field(default_factory=dict)
    """Instance id -> object node name."""
    pixels: dict[int, int] = field(default_factory=dict)
    """Instance id -> number of mask pixels over all frames (0 = background included)."""
    frames: dict[int, int] = field(default_factory=dict)
    """Instance id -> number of frames the instance appears in."""


def object_name(instance_id: int, names: dict[int, str] | None) -> str:
    """Node name of an instance: its declared name made a valid prim identifier, else ``object_<id>``."""
    raw = (names or {}).get(int(instance_id))
    if not raw:
        return f"object_{instance_id}"
    name = re.sub(r"[^A-Za-z0-9_]", "_", raw)
    if not name or name[0].isdigit():
        name = f"object_{name}"
    return name


def require_masks(obs: Observations) -> None:
    """Raise unless the capture has an instance mask per frame (every stage after s0 needs them)."""
    if not obs.has_masks:
        raise HolousdError(
            f"{obs.camera_file or obs.root or '<observations>'}: no instance masks; fitting needs one integer mask "
            "per frame (0 = background, 1..N objects): add masks/ to a native capture or instance_mask/ to a "
            "nerfstudio one (holousd/io/FORMAT.md)"
        )


def instance_table(obs: Observations) -> ObserveResult:
    """Scan every mask of ``obs`` once and count pixels and frames per instance id.

    Raises:
        HolousdError: the capture has no instance masks.
    """
    require_masks(obs)
    pixels: dict[int, int] = {}
    frames: dict[int, int] = {}
    for i in range(len(obs)):
        mask = obs.mask(i)
        ids, counts = np.unique(np.asarray(mask), return_counts=True)
        for k, c in zip(ids.tolist(), counts.tolist(), strict=True):
            pixels[k] = pixels.get(k, 0) + int(c)
            frames[k] = frames.get(k, 0) + 1
    ids = sorted(k for k in pixels if k > 0)
    if obs.instance_names:
        ids = sorted(set(ids) | {k for k in obs.instance_names if k > 0 and k in pixels})
    names: dict[int, str] = {}
    used: set[str] = set()
    for k in ids:
        name = object_name(k, obs.instance_names)
        if name in used or name == BACKGROUND:
            name = f"{name}_{k}"
        used.add(name)
        names[k] = name
    return ObserveResult(instance_ids=ids, names=names, pixels=pixels, frames=frames)


def _image_path(obs: Observations, i: int) -> str | None:
    source = obs.source(i, "rgb")
    if source.startswith("<") or "#" in source:
        return None
    path = Path(source)
    return str(path.absolute()) if path.exists() else None


def run(obs: Observations, out_dir: str | os.PathLike[str], config: ObserveConfig | None = None) -> SceneGraph:
    """Write ``out_dir/00_observe.usda``: cameras, image references, background and object nodes.

    Object nodes are named from ``obs.instance_names`` (made valid prim names) or ``object_<id>``; their
    pose is the identity until s1_fit places them.

    Args:
        obs: The capture (must have instance masks).
        out_dir: Output folder (created).
        config: Options; default :class:`ObserveConfig`.

    Returns:
        The scene; its root layer is the saved ``00_observe.usda``.
    """
    config = config or ObserveConfig()
    if len(obs) == 0:
        raise HolousdError(f"{obs.root or '<observations>'}: no frames; a capture needs at least one image")
    table = instance_table(obs)
    if not table.instance_ids:
        raise HolousdError(
            f"{obs.root or '<observations>'}: the masks hold only background (0); label each object with its own "
            "id 1..N in the masks"
        )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    scene = SceneGraph.create(out_dir / OBSERVE_LAYER, overwrite=config.overwrite, provenance=config.provenance)
    for i in range(len(obs)):
        scene.set_camera(
            CameraData(
                name=f"Frame_{i:05d}",
                K=obs.intrinsics[i],
                cam_to_world=obs.poses[i],
                width=obs.width,
                height=obs.height,
                image=_image_path(obs, i),
                frame_id=obs.frame_ids[i],
            )
        )
    scene.add_background(instance_id=0)
    for k in table.instance_ids:
        scene.add_object(table.names[k], instance_id=k)
    scene.save()
    return scene
