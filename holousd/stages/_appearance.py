"""Appearance stage transform: fit Gaussians-on-mesh to observed frames and store them in a new layer.

Serves as the Gaussian part of s1_fit (first fit, splats initialised from the meshes) and as s3_refine
(``reinitialize=False``: start from the splats already in the scene, on the final meshes).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from holousd._errors import InvalidDataError, SceneError
from holousd.render._bake import bake_texture, vertex_colors
from holousd.render._binding import SH_C0, SplatBudget, initial_bound_splats, splat_budget, splats_in_world
from holousd.render._fit import FitConfig, FitNode, FitResult, colors_from_frames, fit_bound_splats
from holousd.render._frames import as_frames
from holousd.usd import SceneGraph

__all__ = ["AppearanceConfig", "AppearanceResult", "fit_appearance", "run"]


@dataclass(kw_only=True)
class AppearanceConfig:
    """Settings of the appearance stage."""

    layer: str = "appearance.usda"
    """Output layer; a relative path is taken beside the scene's root layer."""
    nodes: list[str] | None = None
    """Nodes to fit (None: every node with a mesh). Other nodes with splats stay as occluders."""
    reinitialize: bool = True
    """Draw new splats from the splat budget (False: refine the node's existing bound splats when present)."""
    spacing_px: float = 2.0
    """Splat spacing on screen at the closest observing camera, pixels (sets the count with the area)."""
    min_splats: int = 64
    """Lower clamp of a node's splat count."""
    max_splats: int = 50_000
    """Upper clamp of a node's splat count."""
    fit: FitConfig = field(default_factory=FitConfig)
    """Optimiser settings."""
    provenance: str = "appearance"
    """Writer name recorded on the nodes."""
    seed: int = 0
    """Seed of the splat sampling."""
    texture: bool = True
    """Also bake the splats' colour into a texture atlas per mesh (``assets/<layer>/<node>.png`` beside the
    layer), which tools that read no splats show instead of the per-point colour (which stays as their fallback;
    a mesh xatlas cannot pack into one ``texture_max_size`` atlas keeps only that)."""
    texture_max_size: int = 1024
    """Longest side of a node's texture, texels (its texels are half the splats' spacing, larger on big meshes)."""


@dataclass(kw_only=True)
class AppearanceResult:
    """What :func:`fit_appearance` did."""

    scene: SceneGraph
    """The scene, now with the appearance layer as root (saved)."""
    layer: Path
    """The layer written."""
    fit: FitResult
    """Optimisation record."""
    counts: dict[str, int]
    """Splats per fitted node."""
    budgets: dict[str, SplatBudget]
    """Splat budget per freshly initialised node (area, footprint, desired count)."""


def fit_appearance(scene: SceneGraph, frames: object, config: AppearanceConfig | None = None) -> AppearanceResult:
    """Fit every requested node's Gaussians-on-mesh to ``frames`` and store them in a new layer.

    Args:
        scene: A file-backed scene whose nodes have meshes.
        frames: Anything :func:`holousd.render.as_frames` accepts (list of (image, K, cam_to_world[, mask]),
            :class:`holousd.render.Frame` list, or an Observations-like object).
        config: Stage settings.
    """
    config = config or AppearanceConfig()
    frame_list = as_frames(frames)
    if scene.path is None:
        raise SceneError("appearance stage: the scene is in memory; save it to a file first (splats go beside it)")
    all_nodes = [n.name for n in scene.nodes()]
    wanted = config.nodes if config.nodes is not None else all_nodes
    unknown = sorted(set(wanted) - set(all_nodes))
    if unknown:
        raise InvalidDataError(f"appearance stage: unknown nodes {unknown}; the scene has {all_nodes}")
    cameras = [f.camera for f in frame_list]
    fit_nodes: list[FitNode] = []
    budgets: dict[str, SplatBudget] = {}
    for i, name in enumerate(all_nodes):
        info = scene.node_info(name)
        try:
            mesh = scene.get_mesh(name)
        except SceneError:
            mesh = None
        pose = scene.get_pose(name)
        existing = None
        try:
            existing = scene.get_gaussians(name)
        except SceneError:
            existing = None
        if name not in wanted or mesh is None:
            if name in wanted and config.nodes is not None:
                raise SceneError(f"{scene.path}: node {name!r} has no mesh; appearance needs one to bind splats to")
            if existing is not None and len(existing):
                fit_nodes.append(FitNode(name=name, mesh=mesh or _empty_mesh(), pose=pose, splats=existing,
                                         instance_id=info.instance_id, trainable=False))  # fmt: skip
            continue
        if existing is not None and existing.bound and not config.reinitialize:
            splats = existing
        else:
            budget = splat_budget(mesh, pose, cameras, spacing_px=config.spacing_px, min_splats=config.min_splats,
                                  max_splats=config.max_splats, seed=config.seed + i)  # fmt: skip
            budgets[name] = budget
            splats = initial_bound_splats(mesh, budget, seed=config.seed + i)
            centre, rot, _ = splats_in_world(splats, pose, mesh)
            rgb = colors_from_frames(centre, rot[:, :, 2], frame_list)
            splats.sh_coeffs = ((np.clip(rgb, 0.02, 0.98) - 0.5) / SH_C0)[:, None, :].astype(np.float32)
        fit_nodes.append(FitNode(name=name, mesh=mesh, pose=pose, splats=splats, instance_id=info.instance_id))
    if not any(n.trainable for n in fit_nodes):
        raise SceneError(f"{scene.path}: no node with a mesh to fit appearance to")
    result = fit_bound_splats(fit_nodes, frame_list, config.fit)
    layer = Path(config.layer)
    if not layer.is_absolute():
        layer = scene.path.parent / layer
    scene.push_layer(layer, provenance=config.provenance, replace=True)
    meshes = {n.name: n.mesh for n in fit_nodes if n.trainable}
    for name, splats in result.splats.items():
        scene.set_gaussians(name, splats)
        if name in meshes and len(meshes[name].points):  # colour on the mesh for tools that read no splats
            scene.set_surface_color(name, vertex_colors(meshes[name], splats))
            if config.texture:
                texture = bake_texture(meshes[name], splats, max_size=config.texture_max_size)
                if texture is not None:  # else no atlas fits: the per-point colours alone
                    scene.set_surface_texture(name, texture.st, texture.image)
    written = scene.save()
    return AppearanceResult(scene=scene, layer=written, fit=result,
                            counts={k: len(v) for k, v in result.splats.items()}, budgets=budgets)  # fmt: skip


def _empty_mesh():  # noqa: ANN202
    from holousd.usd import MeshData

    return MeshData(points=np.zeros((0, 3)), faces=np.zeros((0, 3), dtype=np.int64))


def run(scene: SceneGraph, frames: object, config: AppearanceConfig | None = None) -> SceneGraph:
    """Stage transform: fit appearance, push and save its layer, return the scene (see :func:`fit_appearance`)."""
    return fit_appearance(scene, frames, config).scene
