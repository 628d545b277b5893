"""Collision geometry for objects: convex hull, convex decomposition, or triangle mesh, and the choice between them.

Policy (ARCHITECTURE §4/§6): a convex hull when the object is convex enough (volume ratio mesh / hull), a convex
decomposition otherwise, a triangle mesh only for the static background. :func:`choose_collider` keeps the
simplest collider whose stability verdict matches the detailed (triangle-mesh) one.

Parts are returned as ``(points [N, 3] float64, faces [F, 3] int64)`` in object coordinates; the scene graph
authors each part as a ``Mesh`` prim with ``CollisionAPI`` + ``MeshCollisionAPI`` and
``physics:approximation = "convexHull"`` (the static background mesh uses ``"none"``). Newton's importer maps
``convexHull`` to its convex-hull remesher, which is idempotent on a part that already is a hull, and
``none`` to a triangle-mesh shape (checked in newton/_src/usd/_colliders.py).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from pxr import Usd

from holousd.geometry._hulls import (
    DecompositionConfig,
    _as_arrays,
    convex_decomposition,
    convex_hull,
    convexity,
    cut_above,
    cut_axis,
    cut_below,
    cut_plane,
)

from ._scene import ColliderParts

if TYPE_CHECKING:
    from ._stability import StabilityConfig

__all__ = [
    "ColliderChoice",
    "DecompositionConfig",
    "choose_collider",
    "choose_object_collider",
    "collider_verdict",
    "convex_decomposition",
    "convex_hull",
    "convexity",
    "cut_above",
    "cut_axis",
    "cut_plane",
    "cut_below",
]


@dataclass(kw_only=True)
class ColliderChoice:
    """The collider chosen for one object and why."""

    kind: str
    """``"hull"``, ``"decomposition"`` or ``"mesh"``."""
    parts: ColliderParts
    """Parts to author, object coordinates (one part for a hull or a mesh)."""
    approximation: str
    """``physics:approximation`` for each part: ``"convexHull"`` or ``"none"``."""
    convexity: float
    """Volume ratio mesh / hull of the object."""
    reference_stable: bool | None = None
    """Verdict with the detailed (triangle-mesh) collider, when it was computed."""
    tried: dict[str, bool] = field(default_factory=dict)
    """Verdict of each candidate tried, by kind."""


def choose_collider(
    points: np.ndarray,
    faces: np.ndarray,
    *,
    verdict: Callable[[str, ColliderParts, str], bool] | None = None,
    convex_threshold: float = 0.9,
    decomposition: DecompositionConfig | None = None,
) -> ColliderChoice:
    """The simplest collider whose stability verdict matches the detailed one.

    Candidates from simplest: convex hull (only when ``convexity >= convex_threshold``), then convex
    decomposition. The reference is the object's own triangle mesh. With ``verdict`` None no simulation runs
    and the convexity rule alone decides (hull or decomposition). Otherwise ``verdict(kind, parts,
    approximation)`` must return the object's stable flag with those colliders (see
    :func:`collider_verdict`); a candidate is kept when its flag equals the mesh's. If no candidate matches,
    the triangle mesh itself is returned (correct, but slow in contact).

    Args:
        points: [N, 3] object mesh vertices, object coordinates, metres.
        faces: [F, 3] triangles.
        verdict: Stability oracle, or None.
        convex_threshold: Minimum volume ratio for the hull to be a candidate.
        decomposition: CoACD settings.
    """
    pts, tri = _as_arrays(points, faces)
    ratio = convexity(pts, tri)
    candidates: list[tuple[str, Callable[[], ColliderParts]]] = []
    if ratio >= convex_threshold:
        candidates.append(("hull", lambda: [convex_hull(pts, tri)]))
    candidates.append(("decomposition", lambda: convex_decomposition(pts, tri, decomposition)))
    if verdict is None:
        kind, make = candidates[0]
        return ColliderChoice(kind=kind, parts=make(), approximation="convexHull", convexity=ratio)
    reference = verdict("mesh", [(pts, tri)], "none")
    tried: dict[str, bool] = {}
    for kind, make in candidates:
        parts = make()
        tried[kind] = verdict(kind, parts, "convexHull")
        if tried[kind] == reference:
            return ColliderChoice(
                kind=kind,
                parts=parts,
                approximation="convexHull",
                convexity=ratio,
                reference_stable=reference,
                tried=tried,
            )
    return ColliderChoice(
        kind="mesh", parts=[(pts, tri)], approximation="none", convexity=ratio, reference_stable=reference, tried=tried
    )


def collider_verdict(
    source: str | os.PathLike[str] | Usd.Stage, obj: str, config: StabilityConfig | None = None
) -> Callable[[str, ColliderParts, str], bool]:
    """A ``verdict`` oracle for :func:`choose_collider`: ``obj`` alone on its static support chain.

    Args:
        source: Stage or file path.
        obj: The object's prim path.
        config: A :class:`~holousd.physics.StabilityConfig` (default protocol settings).
    """
    from ._model import ColliderOverride
    from ._scene import open_stage, resolve_object
    from ._stability import StabilityConfig, stability_alone

    cfg = config or StabilityConfig()
    stage = open_stage(source)
    path = resolve_object(stage, obj)

    def verdict(kind: str, parts: ColliderParts, approximation: str) -> bool:
        del kind
        override = {path: ColliderOverride(parts=parts, approximation=approximation)}
        return stability_alone(stage, path, cfg, colliders=override).stable

    return verdict


def choose_object_collider(
    source: str | os.PathLike[str] | Usd.Stage,
    obj: str,
    config: StabilityConfig | None = None,
    *,
    convex_threshold: float = 0.9,
    decomposition: DecompositionConfig | None = None,
) -> ColliderChoice:
    """:func:`choose_collider` for an object of a scene, judged alone on its static support chain.

    The object's render meshes (``UsdGeom.Mesh`` prims under it without ``CollisionAPI``, e.g. ``Geom``) are
    the detailed geometry; the returned parts are in the object's coordinates, ready to author under
    ``<object>/Collision``.

    Args:
        source: Stage or file path.
        obj: Prim path, or name under /World/Objects.
        config: Protocol settings of the verdicts (``stop_when_decided`` recommended for speed).
        convex_threshold: Minimum volume ratio for the hull to be a candidate.
        decomposition: CoACD settings.
    """
    from pxr import UsdGeom

    from ._scene import open_stage, resolve_object, world_mesh

    stage = open_stage(source)
    path = resolve_object(stage, obj)
    pts_w, faces = world_mesh(stage, path)
    to_world = np.array(UsdGeom.Xformable(stage.GetPrimAtPath(path)).ComputeLocalToWorldTransform(0.0))
    to_local = np.linalg.inv(to_world)  # row-vector convention
    pts = pts_w @ to_local[:3, :3] + to_local[3, :3]
    return choose_collider(
        pts,
        faces,
        verdict=collider_verdict(stage, path, config),
        convex_threshold=convex_threshold,
        decomposition=decomposition,
    )
