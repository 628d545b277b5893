"""Geometry metrics: Chamfer distance, F-score and normal consistency between meshes (ARCHITECTURE.md §5).

Conventions: surface samples area-weighted (200k per mesh by default), distances in metres, Chamfer reported in
centimetres as (accuracy + completion) / 2, where accuracy is the mean distance from predicted samples to the
ground truth and completion the mean distance from ground-truth samples to the prediction. F-score at 5 cm is
the harmonic mean of precision (predicted samples within the threshold) and recall (ground-truth samples within
it), times 100. Normal consistency is the mean absolute cosine between the normals of nearest samples, x100.

"Visible" metrics restrict the ground-truth side (completion, recall) to samples some camera saw (depth test
against ground-truth depth); the predicted side is still compared with the complete ground-truth surface, so
a plausible completion of unseen parts is not penalised.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from holousd._errors import HolousdError
from holousd._sampling import evenly_spaced
from holousd.usd._types import MeshData

__all__ = [
    "GeometryMetrics",
    "SceneGeometryReport",
    "evaluate_fit",
    "geometry_metrics",
    "sample_surface",
    "visible_mask",
]


@dataclass(kw_only=True)
class GeometryMetrics:
    """Accuracy of a predicted surface against ground truth."""

    chamfer_cm: float
    """(accuracy + completion) / 2, centimetres."""
    accuracy_cm: float
    """Mean distance from predicted samples to the ground truth, centimetres."""
    completion_cm: float
    """Mean distance from (visible) ground-truth samples to the prediction, centimetres."""
    precision: float
    """Predicted samples within the threshold, percent."""
    recall: float
    """(Visible) ground-truth samples within the threshold, percent."""
    fscore: float
    """Harmonic mean of precision and recall, percent."""
    normal_consistency: float
    """Mean |cos| between nearest-sample normals (both directions averaged), x100."""
    threshold_m: float
    """F-score threshold, metres."""


def sample_surface(mesh: MeshData, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted samples of a triangle mesh: ([count, 3] points, [count, 3] unit face normals)."""
    tri = mesh.points[mesh.faces]  # [F, 3, 3]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(cross, axis=1)
    if len(tri) == 0 or area.sum() <= 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    face = rng.choice(len(tri), size=count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[face]
    points = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    normals = cross[face] / np.maximum(area[face], 1e-12)[:, None]
    return points, normals


def visible_mask(
    points: np.ndarray,
    intrinsics: np.ndarray,
    poses: np.ndarray,
    depths: Sequence[np.ndarray],
    tolerance: float = 0.02,
) -> np.ndarray:
    """[P] bool: the world point is seen by at least one camera (its z-depth matches that frame's depth).

    Args:
        points: [P, 3] world points.
        intrinsics: [N, 3, 3] pinhole intrinsics.
        poses: [N, 4, 4] camera-to-world (OpenCV camera).
        depths: N ground-truth [H, W] z-depth maps (0 = none).
        tolerance: Largest |z - depth| of a visible point, metres.
    """
    seen = np.zeros(len(points), bool)
    for k, pose, depth in zip(intrinsics, poses, depths, strict=True):
        h, w = depth.shape
        cam = (points - pose[:3, 3]) @ pose[:3, :3]
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.rint(k[0, 0] * cam[:, 0] / z + k[0, 2])
            v = np.rint(k[1, 1] * cam[:, 1] / z + k[1, 2])
        ok = (z > 1e-3) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        d = np.zeros(len(points))
        d[ok] = depth[v[ok].astype(int), u[ok].astype(int)]
        seen |= ok & (d > 0) & (np.abs(d - z) < tolerance)
    return seen


def _true_depth(gt_dir: Path, graph: dict, obs: Any, pick: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Depth of every ground-truth mesh (the room's included) ray-cast at the picked frames from the true poses
    (``gt/cameras.json``; the capture's poses where there is none), and those poses."""
    import json

    import trimesh

    from holousd.synth._raycast import RayCaster
    from holousd.usd._types import Pose

    points, faces, offset = [], [], 0
    for node in graph["nodes"]:
        if not node.get("mesh"):
            continue
        tm = trimesh.load(gt_dir / "gt" / node["mesh"], force="mesh", process=False)
        pose = node.get("pose")
        verts = np.asarray(tm.vertices, np.float64)
        if pose is not None:
            verts = Pose(translation=pose["translation"], orientation=pose["orientation_xyzw"]).apply(verts)
        points.append(verts)
        faces.append(np.asarray(tm.faces) + offset)
        offset += len(verts)
    cameras = gt_dir / "gt" / "cameras.json"
    poses = np.asarray(json.loads(cameras.read_text())["poses"], np.float64) if cameras.is_file() else obs.poses
    poses = poses[pick]
    hits = RayCaster(np.concatenate(points), np.concatenate(faces)).cast(obs.intrinsics[pick], poses, obs.width,
                                                                        obs.height)  # fmt: skip
    return list(hits.depth), poses


def geometry_metrics(
    pred: tuple[np.ndarray, np.ndarray],
    gt: tuple[np.ndarray, np.ndarray],
    *,
    gt_visible: np.ndarray | None = None,
    threshold: float = 0.05,
) -> GeometryMetrics:
    """Compare predicted and ground-truth surface samples.

    Args:
        pred: ([P, 3] points, [P, 3] normals) sampled on the prediction.
        gt: ([G, 3] points, [G, 3] normals) sampled on the complete ground truth.
        gt_visible: Optional [G] bool: only these ground-truth samples count for completion and recall.
        threshold: F-score distance, metres.
    """
    from scipy.spatial import cKDTree

    p_pts, p_nrm = pred
    g_pts, g_nrm = gt
    if len(p_pts) == 0 or len(g_pts) == 0:
        inf = float("inf")
        return GeometryMetrics(chamfer_cm=inf, accuracy_cm=inf, completion_cm=inf, precision=0.0, recall=0.0,
                               fscore=0.0, normal_consistency=0.0, threshold_m=threshold)  # fmt: skip
    d_acc, i_acc = cKDTree(g_pts).query(p_pts, workers=-1)
    sel_pts, sel_nrm = (g_pts, g_nrm) if gt_visible is None else (g_pts[gt_visible], g_nrm[gt_visible])
    if len(sel_pts) == 0:
        sel_pts, sel_nrm = g_pts, g_nrm
    d_comp, i_comp = cKDTree(p_pts).query(sel_pts, workers=-1)
    precision = float((d_acc < threshold).mean() * 100)
    recall = float((d_comp < threshold).mean() * 100)
    fscore = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    nc = 0.5 * (np.abs((p_nrm * g_nrm[i_acc]).sum(1)).mean() + np.abs((sel_nrm * p_nrm[i_comp]).sum(1)).mean())
    acc, comp = float(d_acc.mean() * 100), float(d_comp.mean() * 100)
    return GeometryMetrics(chamfer_cm=(acc + comp) / 2, accuracy_cm=acc, completion_cm=comp, precision=precision,
                           recall=recall, fscore=fscore, normal_consistency=float(nc * 100),
                           threshold_m=threshold)  # fmt: skip


@dataclass(kw_only=True)
class SceneGeometryReport:
    """Geometry of a fitted scene against a synth scene's ground truth (objects only, world coordinates)."""

    visible: GeometryMetrics
    """All objects together, ground-truth side restricted to visible samples."""
    complete: GeometryMetrics
    """All objects together against the complete ground truth."""
    object_rate: float
    """Ground-truth objects that have a predicted mesh, percent (OR%)."""
    per_object: dict[str, GeometryMetrics]
    """Ground-truth object name -> visible metrics of its own mesh (missing objects absent)."""
    per_object_complete: dict[str, GeometryMetrics] = field(default_factory=dict)
    """Ground-truth object name -> metrics of its own mesh against its complete ground-truth surface (the sides
    no camera saw included: what completion is judged on)."""
    missing: list[str]
    """Ground-truth objects without a predicted mesh."""


def evaluate_fit(
    gt_dir: str | os.PathLike[str],
    scene_file: str | os.PathLike[str],
    *,
    samples: int = 200_000,
    threshold: float = 0.05,
    seed: int = 0,
    frames: int = 50,
) -> SceneGeometryReport:
    """Evaluate the object meshes of a fitted scene against a ``holousd synth`` scene folder.

    Objects are matched by instance id; ground-truth meshes come from ``<scene>/gt/meshes`` and poses from
    ``<scene>/gt/graph.json``; visibility is tested against the capture's (ground-truth, metric) depth.

    Args:
        gt_dir: The synth scene folder (holding the capture and ``gt/``).
        scene_file: The fitted scene layer (e.g. ``10_fit.usda``).
        samples: Surface samples over all objects (each object gets a share by area).
        threshold: F-score threshold, metres.
        seed: Seed of the surface sampling.
        frames: Frames (evenly spread) used for the visibility test.
    """
    import json

    import trimesh

    from holousd.io import load
    from holousd.usd._scene import SceneGraph
    from holousd.usd._types import Pose

    gt_dir = Path(gt_dir)
    rng = np.random.default_rng(seed)
    graph = json.loads((gt_dir / "gt" / "graph.json").read_text())
    gt_meshes: dict[int, tuple[str, MeshData]] = {}
    for node in graph["nodes"]:
        if node.get("role") != "object":
            continue
        tm = trimesh.load(gt_dir / "gt" / node["mesh"], force="mesh", process=False)
        pose = Pose(translation=node["pose"]["translation"], orientation=node["pose"]["orientation_xyzw"])
        gt_meshes[int(node["instance_id"])] = (node["name"], MeshData(points=pose.apply(tm.vertices), faces=tm.faces))
    scene = SceneGraph.open(scene_file)
    pred_meshes: dict[int, MeshData] = {}
    for info in scene.nodes():
        if info.role != "object":
            continue
        try:
            mesh = scene.get_mesh(info.name)
        except HolousdError:
            continue
        if len(mesh.faces):
            pose = scene.get_pose(info.name)
            pred_meshes[info.instance_id] = MeshData(points=pose.apply(mesh.points), faces=mesh.faces)
    obs = load(gt_dir)
    pick = evenly_spaced(len(obs), frames)
    if obs.has_depth:
        depths, seen_from = [obs.depth(int(i)) for i in pick], obs.poses[pick]
    else:  # a capture without depth (the 'video' sensor): the ground truth's own depth from its true poses
        depths, seen_from = _true_depth(gt_dir, graph, obs, pick)

    def area(m: MeshData) -> float:
        tri = m.points[m.faces]
        return float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum() / 2)

    def samples_of(meshes: dict[int, MeshData]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        areas = {k: area(m) for k, m in meshes.items()}
        total = sum(areas.values()) or 1.0
        return {k: sample_surface(m, max(500, int(samples * areas[k] / total)), rng) for k, m in meshes.items()}

    gt_s = samples_of({k: m for k, (_, m) in gt_meshes.items()})
    pred_s = samples_of(pred_meshes)
    gt_vis = {k: visible_mask(p, obs.intrinsics[pick], seen_from, depths) for k, (p, _) in gt_s.items()}
    per_object, per_object_complete = {}, {}
    missing = []
    for k, (name, _) in gt_meshes.items():
        if k not in pred_s:
            missing.append(name)
            continue
        per_object[name] = geometry_metrics(pred_s[k], gt_s[k], gt_visible=gt_vis[k], threshold=threshold)
        per_object_complete[name] = geometry_metrics(pred_s[k], gt_s[k], threshold=threshold)

    def cat(d: dict[int, tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
        if not d:
            return np.zeros((0, 3)), np.zeros((0, 3))
        return np.concatenate([v[0] for v in d.values()]), np.concatenate([v[1] for v in d.values()])

    keys = list(gt_s)
    all_gt = cat({k: gt_s[k] for k in keys})
    all_vis = np.concatenate([gt_vis[k] for k in keys]) if keys else np.zeros(0, bool)
    all_pred = cat(pred_s)
    return SceneGeometryReport(
        visible=geometry_metrics(all_pred, all_gt, gt_visible=all_vis, threshold=threshold),
        complete=geometry_metrics(all_pred, all_gt, threshold=threshold),
        object_rate=100.0 * (len(gt_meshes) - len(missing)) / max(1, len(gt_meshes)),
        per_object=per_object,
        per_object_complete=per_object_complete,
        missing=missing,
    )
