"""Stage s1_fit (geometry): per-instance SDF grids and watertight meshes (layer ``10_fit.usda``).

Pipeline per capture:

1. Frames are read once (labels, colour, depth, normals; long captures are subsampled). With metric depth the
   camera poses are aligned against the depth (:func:`holousd.geometry.refine_poses`) and the aligned poses
   used, for every later step and stage, when they are clearly better than the capture's (``refine_poses``);
   then every pixel's label and depth is checked against the neighbouring frames (``consensus``).
2. Background: with metric depth the room shell is TSDF-fused from background pixels at a coarse voxel and
   meshed (a closed slab a truncation distance thick, usable as a static collider); the floor height is the
   robust lowest level of the background points. Without metric depth the floor is the lowest point of the
   objects' visual hulls and the background mesh is a floor slab under the observed area.
3. Extent of each instance: back-projected masked depth (robust percentiles), or without depth a visual hull
   carved from the masks over a scene bound around the cameras. Voxel size from the instance's size
   (``target_resolution`` samples along its largest side), never finer than a fraction of the pixel
   footprint, and coarsened until the grid fits ``max_voxels``.
4. Initialisation: TSDF fusion of the instance's masked depth over its grid (free space and "behind the room
   shell" carve; "behind the instance's surface" fills the unseen inside where that is enclosed, not where it
   opens onto space a camera saw through: the space under a table top), intersected with the observed extent
   and the half-space above the floor; hidden space two instances both hold solid goes to the one whose seen
   surface it lies closer behind (a box in a shelf's compartment, not the shelf's upper board seen from above);
   without depth, the carved visual hull (coarse to fine) turned into a signed distance.
5. Refinement by differentiable volume rendering (:mod:`holousd.render._volume`): RGB, instance-mask
   cross-entropy, depth (L1, or scale-and-shift invariant for relative depth), normals, eikonal, smoothness and
   the ObjectSDF++ overlap penalty ``relu(-s_a - s_b)``; rays are instance-balanced (half of each frame's rays
   spread evenly over the instances it shows). With metric depth, voxels no fused frame observed keep the
   value the initialisation gave them.
6. Overlaps left between instances are split at the mid-surface, grids are re-distanced, meshed (marching
   cubes, largest component, closed by positive padding, face budget from the object's size) and written in
   object coordinates (origin at the bottom centre of the mesh's bounding box, pose = translation, turned
   about z by the room's yaw when the fit worked in the room's frame).

Depth a prior estimated (``obs.metadata['depth_prior']``; a capture without depth gets ``stereo`` depth from its
colour frames, :mod:`holousd.priors._depth`) is metric but sparse (textured pixels and edges) and centimetres off:
the camera poses are not aligned against it (it was made from them), the room's yaw and tilt are not read from its
normals, the background is a floor slab at the densest level of the room's points, an instance with few depth
points gets its extent from its silhouettes' width around them and its initial shape from its masks (the visual
hull carved where the depth saw free space), and whatever the refinement grows under the floor is cut again.

The room's frame: a tracker's world frame has its x axis wherever the device pointed when it started, so the
room's walls (and the furniture standing square to them) run at any angle to it. Grids and everything cut along
object axes later (the physics set-up's flat bases and plane decomposition, the search's box primitives) fit a
piece of furniture best when its axes are the grid's. With metric depth (``align_room``), the fit estimates the
yaw of the scene's vertical surfaces from the depth normals (walls, cabinet sides: their directions repeat every
90 deg about z) and works in the frame turned by it; every object's pose then carries that yaw, so its mesh and
SDF are axis-aligned with the room in object coordinates, and the scene stays where the cameras put it.
"""

from __future__ import annotations

import os
import resource
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from holousd._errors import HolousdError
from holousd._sampling import evenly_spaced
from holousd._torch_threads import torch_threads
from holousd.geometry._grid import (
    Consensus,
    Views,
    VoxelGrid,
    box_sdf,
    carve_hull,
    fuse_tsdf,
    label_consensus,
    object_points,
    observed_fraction,
    sample_grid,
    signed_distance_from_occupancy,
)
from holousd.geometry._meshing import face_budget, mesh_from_sdf, meshed_only
from holousd.geometry._poses import PoseConfig, PoseRefinement, axis_angle, refine_poses, spread_corrections
from holousd.io._observations import Observations
from holousd.render._volume import VolumeConfig
from holousd.usd._scene import BACKGROUND, SceneGraph
from holousd.usd._types import MeshData, Pose, SdfField

if TYPE_CHECKING:
    import torch

__all__ = [
    "BEST",
    "DEFAULT",
    "FAST",
    "FIT_LAYER",
    "PRESETS",
    "FitConfig",
    "FitResult",
    "LossWeights",
    "ObjectFit",
    "fit",
    "observations_as_fitted",
    "run",
    "with_seed",
]

FIT_LAYER = "10_fit.usda"
"""File name of the layer this stage writes."""


@dataclass(kw_only=True)
class LossWeights:
    """Weights of the refinement energy terms."""

    rgb: float = 1.0
    """Colour MSE (colours in [0, 1])."""
    mask: float = 0.5
    """Instance-mask cross-entropy (background + instances)."""
    depth: float = 5.0
    """Depth L1 per metre (scale-and-shift invariant when the depth is relative)."""
    normal: float = 0.05
    """Normal L1 + (1 - cosine)."""
    eikonal: float = 0.05
    """(|grad s| - 1)^2 on voxels near the surface, but not in a thin part's middle (see ``_kinked``)."""
    smooth: float = 0.02
    """Squared discrete Laplacian (times the voxel size) on voxels near the surface."""
    overlap: float = 10.0
    """relu(-s_a - s_b) per metre at points inside two instances' boxes."""


@dataclass(kw_only=True)
class FitConfig:
    """Settings of s1_fit geometry (see the presets :data:`FAST`, :data:`DEFAULT`, :data:`BEST`)."""

    target_resolution: int = 64
    """Samples along an instance's largest side (its voxel size is its size divided by this)."""
    min_voxel: float = 0.004
    """Smallest voxel size, metres."""
    footprint_factor: float = 0.5
    """Voxels are at least this many pixel footprints (at the instance's median depth)."""
    max_voxels: int = 300_000
    """Largest grid per instance (the voxel grows until the grid fits), samples."""
    trunc_voxels: float = 3.0
    """TSDF truncation distance, voxels."""
    fusion_frames: int = 50
    """Frames used for fusion and extents (evenly subsampled), at most."""
    render_frames: int = 200
    """Frames kept in memory for the refinement, at most."""
    consensus: bool = True
    """With metric depth, check every pixel's label and depth against the neighbouring frames before anything
    uses them (:func:`holousd.geometry.label_consensus`): a segmenter's boundary errors, false fragments and lost
    objects are relabelled or marked unknown, flying depth pixels dropped."""
    extent_margin: float = 1.0
    """Margin around an instance's observed extent that its solid may fill, voxels."""
    hull_voxel: float = 0.06
    """Voxel of the scene-wide visual hull that bounds instances without depth, metres."""
    scene_reach: float = 3.0
    """Without depth: how far beyond the camera centres the scene may extend, metres."""
    hull_tolerance: float = 0.02
    """Visual hull: fraction of observing frames allowed to see background at a kept voxel."""
    iterations: int = 200
    """Volume-rendering refinement steps (0: initialisation only)."""
    rays: int = 2048
    """Rays per refinement step."""
    frames_per_step: int = 8
    """Frames the rays of one step come from."""
    balanced_fraction: float = 0.5
    """Share of each frame's rays spread evenly over the instances it shows."""
    sdf_lr: float = 0.1
    """Adam learning rate of the SDF grids, voxels per step."""
    color_lr: float = 0.05
    """Adam learning rate of the colour logits."""
    overlap_points: int = 512
    """Points per overlapping instance pair and step for the overlap penalty."""
    weights: LossWeights = field(default_factory=LossWeights)
    """Loss weights."""
    volume: VolumeConfig = field(default_factory=VolumeConfig)
    """Ray sampling and density settings."""
    faces_per_m2: float = 40_000.0
    """Face budget per square metre of an instance's largest extent squared."""
    background_voxel: float = 0.05
    """Voxel of the background (room shell) fusion, metres."""
    background_faces: int = 30_000
    """Face budget of the background mesh."""
    resolve_overlaps: bool = True
    """Split volumes claimed by two instances at their mid-surface before meshing."""
    refine_poses: str = "auto"
    """With metric depth: 'auto' aligns the camera poses against the depth and uses the aligned ones when they
    cut the frames' disagreement to under ``poses.max_ratio`` of the given poses' (poses from structure from
    motion or a weak tracker; a good tracker's are kept, see :mod:`holousd.geometry._poses`); 'on' uses them
    whenever frames overlap and the alignment kept its correspondences; 'off' keeps the capture's poses without
    looking. Without metric depth the capture's poses are used ('on' says so)."""
    poses: PoseConfig = field(default_factory=PoseConfig)
    """Settings of the pose alignment."""
    align_room: bool = True
    """With metric depth, fit in the room's frame: turned about z by the yaw of the scene's vertical surfaces
    (see the module docstring). Off, or without depth, grids and object axes are the capture's world axes."""
    min_yaw_deg: float = 0.5
    """A room yaw below this is taken as none (the capture's frame is the room's already), degrees."""
    max_tilt_deg: float = 2.0
    """With metric depth, warn when the upward-facing surfaces' mean normal lies further than this from the world
    z axis, degrees (the capture is not level; the demo's tracker poses give 1.0, its exact ones 0.3)."""
    seed: int = 0
    """Seed of ray sampling and jitter."""
    device: str = "cpu"
    """Torch device of the refinement."""
    threads: int | None = None
    """Torch CPU threads during the refinement (restored afterwards); None keeps torch's setting. 1 is far more
    robust than 2 on a machine whose cores other processes share (OpenMP spin-waits collapse under contention)."""
    progress: bool = True
    """Show a tqdm progress bar on stderr."""


FAST = FitConfig(target_resolution=48, footprint_factor=0.6, max_voxels=120_000, fusion_frames=60, iterations=40,
                 rays=1024, frames_per_step=4, faces_per_m2=20_000.0)  # fmt: skip
"""About half a minute per 18-object scene on 2 cores: TSDF initialisation plus a short refinement. Fusion takes
up to 60 frames (a second or so): with 30 of bench_02's 60, the far legs of its table, seen in 14 frames, did
not come out of the fusion, and the table fell with its five objects."""
DEFAULT = FitConfig()
"""Balanced preset: finer grids and a few hundred refinement steps."""
BEST = FitConfig(target_resolution=96, footprint_factor=0.4, max_voxels=600_000, fusion_frames=100, iterations=600,
                 rays=4096, faces_per_m2=80_000.0)  # fmt: skip
"""Slowest preset: finest grids, longest refinement."""
PRESETS = {"fast": FAST, "default": DEFAULT, "best": BEST}
"""Named presets for the CLI."""


@dataclass(kw_only=True)
class ObjectFit:
    """Per-instance outcome of the fit."""

    name: str
    """Node name."""
    instance_id: int
    """Instance id in the masks."""
    pixels: int
    """Mask pixels over the frames read."""
    voxel_size: float
    """Grid spacing, metres."""
    resolution: tuple[int, int, int]
    """Grid samples along x, y, z."""
    faces: int = 0
    """Faces of the written mesh (0: no mesh)."""
    watertight: bool = False
    """The written mesh is watertight."""
    fallback: str = ""
    """How the mesh was made when marching cubes failed ('' = it did not)."""
    observed_fraction: float = 0.0
    """Share [0, 1] of the mesh's surface area that some fitted frame saw (``holo:node:observedFraction``)."""
    bounds_world: np.ndarray | None = None
    """[2, 3] world bounding box of the mesh, metres."""


@dataclass(kw_only=True)
class FitResult:
    """What :func:`fit` did."""

    scene: SceneGraph
    """The scene with ``10_fit.usda`` as its root layer."""
    objects: list[ObjectFit] = field(default_factory=list)
    """One entry per object node."""
    floor_z: float = 0.0
    """Estimated floor height, metres."""
    background_faces: int = 0
    """Faces of the background mesh."""
    used_depth: str = "none"
    """'metric', 'relative' or 'none'."""
    yaw_deg: float = 0.0
    """Yaw of the room's frame the fit worked in, about z from the capture's world frame, degrees (0: the world
    frame; every object's pose carries it)."""
    tilt_deg: float | None = None
    """Angle of the upward-facing surfaces' mean normal from the world z axis, degrees (None: no metric depth, or
    nothing faces up); above ``max_tilt_deg`` the fit warns that the capture is not level."""
    consensus: Consensus | None = None
    """What the label / depth check across frames changed (None: not run)."""
    poses: PoseRefinement | None = None
    """What the pose alignment found over the frames read, and whether its poses were used (None: not run)."""
    wall_time_s: float = 0.0
    """Wall-clock time of the stage, seconds."""
    timings: dict[str, float] = field(default_factory=dict)
    """Seconds per phase."""
    peak_memory_mb: float = 0.0
    """Peak resident memory of the process so far, MiB."""
    final_losses: dict[str, float] = field(default_factory=dict)
    """Loss terms of the last refinement step."""


# --------------------------------------------------------------------------------------------- frame loading
@dataclass(kw_only=True)
class _Frames:
    index: np.ndarray  # [N] frame indices in the observations
    views: Views  # labels already remapped? no: raw instance ids
    rgb: np.ndarray  # [N, H, W, 3] uint8
    normals: np.ndarray | None  # [N, H, W, 3] float32 camera frame
    depth_raw: np.ndarray | None  # [N, H, W] float32 as given (metric or relative)


def _load_frames(obs: Observations, count: int, use_depth: bool, use_normals: bool, consensus: bool = False,
                 refine: str = "off", pose_config: PoseConfig | None = None,
                 ) -> tuple[_Frames, Consensus | None, PoseRefinement | None]:  # fmt: skip
    idx = evenly_spaced(len(obs), count)
    labels = np.empty((len(idx), obs.height, obs.width), np.int32)
    rgb = np.empty((len(idx), obs.height, obs.width, 3), np.uint8)
    depth = np.empty((len(idx), obs.height, obs.width), np.float32) if use_depth else None
    normals = np.empty((len(idx), obs.height, obs.width, 3), np.float32) if use_normals else None
    for j, i in enumerate(idx):
        mask = obs.mask(int(i))
        if mask is None or mask.shape != (obs.height, obs.width):
            raise HolousdError(
                f"{obs.source(int(i), 'mask')}: instance mask missing or of the wrong size for frame {i}; "
                f"give a {obs.width}x{obs.height} integer mask per frame"
            )
        labels[j] = mask
        img = obs.rgb(int(i))
        rgb[j] = img[..., :3]
        if depth is not None:
            d = obs.depth(int(i))
            depth[j] = np.where(np.isfinite(d), d, 0.0)
        if normals is not None:
            normals[j] = obs.normal(int(i))
    metric = depth if (use_depth and obs.depth_kind == "metric") else None
    views = Views(intrinsics=obs.intrinsics[idx], poses=obs.poses[idx], labels=labels, depth=metric)
    aligned = None
    if refine != "off" and metric is not None and len(idx) > 1:
        config = pose_config or PoseConfig()
        aligned = refine_poses(views, replace(config, max_ratio=np.inf) if refine == "on" else config)
        views.poses = aligned.poses
    checked = None
    if consensus and metric is not None:
        views.labels, views.depth, checked = label_consensus(views)
        depth = views.depth
    return _Frames(index=idx, views=views, rgb=rgb, normals=normals, depth_raw=depth), checked, aligned


def _pose_summary(aligned: PoseRefinement) -> str:
    """One line on what the pose alignment found and did."""
    if not aligned.pairs:
        return "camera poses kept as the capture gives them: no two frames overlap enough to align their depth"
    t, r = 1000 * aligned.translation, aligned.rotation_deg
    moves = f"median {np.median(t):.1f} mm / {np.median(r):.2f} deg, largest {t.max():.1f} mm / {r.max():.2f} deg"
    gain = f"{1000 * aligned.residual_before:.1f} -> {1000 * aligned.residual_after:.1f} mm"
    if aligned.applied:
        return (f"camera poses aligned against the depth and used ({len(t)} frames moved {moves}; the frames' depth "
                f"disagreement {gain})")  # fmt: skip
    if not np.isfinite(aligned.residual_after) or aligned.ratio >= 1.0:
        return f"camera poses kept as the capture gives them: aligning them against the depth did not converge ({gain})"
    return (f"camera poses kept as the capture gives them: aligned against the depth they would move {moves}, "
            f"but the frames' depth disagreement ({gain}) says they are as good as the depth can tell")  # fmt: skip


def _write_camera_poses(scene: SceneGraph, obs: Observations, index: np.ndarray, aligned: PoseRefinement) -> None:
    """Write every camera of the capture with its aligned pose (frames not read get the corrections of the read
    frames around them) and how far it moved and turned, in the current edit target."""
    poses = spread_corrections(index, obs.poses[index], aligned.poses, obs.poses)
    cameras = scene.get_cameras()
    if len(cameras) != len(obs):
        raise HolousdError(f"{scene.path}: {len(cameras)} cameras for a capture of {len(obs)} frames; run "
                           "s0_observe on this capture again")  # fmt: skip
    for camera, given, pose in zip(cameras, obs.poses, poses, strict=True):
        camera.cam_to_world = pose
        camera.pose_move = pose[:3, 3] - given[:3, 3]
        camera.pose_turn_deg = np.degrees(axis_angle(pose[:3, :3] @ given[:3, :3].T))
        scene.set_camera_pose(camera)


def observations_as_fitted(obs: Observations, scene: SceneGraph) -> Observations:
    """``obs`` with the camera poses of ``scene``'s cameras when s1_fit aligned them (a non-zero
    ``holo:camera:poseMove`` / ``poseTurn`` on some camera), else ``obs`` itself: what the stages after the fit
    and the evaluation render with.

    Raises:
        HolousdError: the scene's cameras were aligned but are not the capture's frames (another count, other
            frame ids): the scene was made from another capture.
    """
    cameras = scene.get_cameras()
    if not any(np.any(c.pose_move) or np.any(c.pose_turn_deg) for c in cameras):
        return obs
    if [c.frame_id for c in cameras] != [str(f) for f in obs.frame_ids]:
        raise HolousdError(f"{scene.path}: its {len(cameras)} cameras (poses aligned by s1_fit) are not the "
                           f"{len(obs)} frames of {obs.root or 'the capture'}; use the capture the scene was made "
                           "from")  # fmt: skip
    return obs.with_poses(np.stack([c.cam_to_world for c in cameras]))


# --------------------------------------------------------------------------------------------- the room's frame
def _world_normals(views: Views, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit world normals of frame ``i``'s depth, facing the camera (from the points two pixels to either side,
    none across a depth jump; images wider than 160 pixels read every ``width // 160``-th pixel), and the area
    each stands for (depth squared)."""
    assert views.depth is not None
    r = 2
    stride = max(1, views.width // 160)
    depth = views.depth[i][::stride, ::stride].astype(np.float64)
    k = views.intrinsics[i]
    h, w = depth.shape
    if h <= 2 * r or w <= 2 * r:
        return np.zeros((0, 3)), np.zeros(0)
    v, u = np.mgrid[0:h, 0:w] * stride
    cam = np.stack([(u - k[0, 2]) / k[0, 0] * depth, (v - k[1, 2]) / k[1, 1] * depth, depth], axis=-1)
    centre = depth[r:-r, r:-r]
    around = [depth[r:-r, 2 * r :], depth[r:-r, : -2 * r], depth[2 * r :, r:-r], depth[: -2 * r, r:-r]]
    ok = (centre > 0) & np.all([(d > 0) & (np.abs(d - centre) < 0.05 * centre) for d in around], axis=0)
    # facing the camera: down the image (y) crossed with along it (x) points back along the optical axis
    down = cam[2 * r :, r:-r][ok] - cam[: -2 * r, r:-r][ok]
    normal = np.cross(down, cam[r:-r, 2 * r :][ok] - cam[r:-r, : -2 * r][ok])
    length = np.linalg.norm(normal, axis=1)
    keep = length > 0
    normal = (normal[keep] / length[keep, None]) @ views.poses[i, :3, :3].T
    return normal, centre[ok][keep] ** 2


Normals = list[tuple[np.ndarray, np.ndarray]]
"""Per frame, :func:`_world_normals`' (normals, areas)."""


def _room_yaw(normals: Normals) -> tuple[float, float]:
    """Yaw of the scene's vertical surfaces about z, radians in (-pi/4, pi/4], and how strongly they agree
    (0: no direction stands out, 1: every vertical surface is square to one frame).

    The depth normals (:func:`_world_normals`, per frame) of vertical surfaces (|n_z| < 0.2) vote with their
    angle about z, four times over (walls and a box's sides repeat every 90 deg), weighted by the area a pixel
    covers.
    """
    total, weight = 0j, 0.0
    for normal, area in normals:
        vertical = np.abs(normal[:, 2]) < 0.2
        angle = np.arctan2(normal[vertical, 1], normal[vertical, 0])
        total += np.sum(area[vertical] * np.exp(4j * angle))
        weight += float(area[vertical].sum())
    if weight <= 0:
        return 0.0, 0.0
    return float(np.angle(total)) / 4.0, float(abs(total)) / weight


def _up_tilt(normals: Normals) -> float | None:
    """Angle between the world's z axis and the mean normal of the scene's upward-facing surfaces (floor, table
    tops: depth normals within 35 deg of z, area-weighted), degrees; None when too few face up. Physics pulls
    along -z: a capture whose floor tilts is not the level world the simulation assumes. A turn about z leaves
    it as it is."""
    total, weight = np.zeros(3), 0.0
    for normal, area in normals:
        up = normal[:, 2] > np.cos(np.radians(35.0))
        total += (normal[up] * area[up, None]).sum(axis=0)
        weight += float(area[up].sum())
    if weight <= 0 or np.linalg.norm(total) <= 0:
        return None
    return float(np.degrees(np.arccos(np.clip(total[2] / np.linalg.norm(total), -1.0, 1.0))))


# --------------------------------------------------------------------------------------------- background
def _floor_from_points(points: np.ndarray) -> float:
    z = points[:, 2]
    low = np.percentile(z, 2.0)
    near = z[np.abs(z - low) < 0.03]
    return float(np.median(near)) if len(near) else float(low)


def _background_metric(frames: _Frames, fusion: np.ndarray, config: FitConfig) -> tuple[float, MeshData | None]:
    views = frames.views
    pts = [views.backproject(int(i), (views.labels[i] == 0) & (views.depth[i] > 0), stride=7) for i in fusion]  # type: ignore[index]
    cloud = np.concatenate(pts) if pts else np.zeros((0, 3))
    if len(cloud) < 50:
        return 0.0, None
    floor = _floor_from_points(cloud)
    lo, hi = np.percentile(cloud, 0.5, axis=0), np.percentile(cloud, 99.5, axis=0)
    voxel = config.background_voxel
    grid = VoxelGrid.from_bounds(lo, hi, voxel, pad=2)
    while grid.size > 2_000_000:
        voxel *= 1.25
        grid = VoxelGrid.from_bounds(lo, hi, voxel, pad=2)
    fused = fuse_tsdf(grid.points(), views, 0, 2.0 * voxel, frames=fusion)
    sdf = np.where(fused.weight > 0, fused.tsdf, 2.0 * voxel).reshape(grid.shape)
    meshed = mesh_from_sdf(sdf, grid.origin, grid.voxel_size, max_faces=config.background_faces)
    return floor, (meshed.mesh if meshed is not None else None)


def _floor_slab(floor: float, lo: np.ndarray, hi: np.ndarray, thickness: float = 0.1) -> MeshData:
    import trimesh

    extents = np.array([hi[0] - lo[0], hi[1] - lo[1], thickness])
    box = trimesh.creation.box(extents=extents)
    box.apply_translation([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, floor - thickness / 2])
    return MeshData(points=np.asarray(box.vertices), faces=np.asarray(box.faces))


# --------------------------------------------------------------------------------------------- instance extents
@dataclass(kw_only=True)
class _Instance:
    name: str
    instance_id: int
    lo: np.ndarray
    hi: np.ndarray
    footprint: float
    pixels: int
    grid: VoxelGrid | None = None
    sdf: np.ndarray | None = None  # [X, Y, Z]
    frozen: np.ndarray | None = None  # [X, Y, Z] voxels no fused frame saw (behind others): the refinement keeps them
    claim: np.ndarray | None = None  # [X, Y, Z] how far its hidden solid lies behind its seen surface (nan: none)
    color: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))


def _extents_metric(frames: _Frames, fusion: np.ndarray, ids: list[int]) -> dict[int, tuple]:
    views = frames.views
    clouds: dict[int, list[np.ndarray]] = {k: [] for k in ids}
    depths: dict[int, list[np.ndarray]] = {k: [] for k in ids}
    owners: dict[int, list[np.ndarray]] = {k: [] for k in ids}
    for i in fusion:
        lab = views.labels[i]
        valid = views.depth[i] > 0  # type: ignore[index]
        for k in np.unique(lab):
            if k <= 0 or k not in clouds:
                continue
            sel = (lab == k) & valid
            count = int(sel.sum())
            if count == 0:
                continue
            stride = max(1, count // 4000)
            clouds[int(k)].append(views.backproject(int(i), sel, stride))
            depths[int(k)].append(views.depth[i][sel][::stride])  # type: ignore[index]
            owners[int(k)].append(np.full(len(clouds[int(k)][-1]), int(i)))
    out = {}
    for k in ids:
        if not clouds[k]:
            continue
        # a segmenter's false fragment or a return from behind a silhouette is in one frame only (or two), and a few
        # of them set a small object's extent (the phone demo's plate reached 1.7 m across the room, its mug 1.8 m)
        median_depth = float(np.median(np.concatenate(depths[k])))
        footprint = median_depth / float(np.mean(views.intrinsics[:, [0, 1], [0, 1]]))
        cloud = object_points(np.concatenate(clouds[k]), np.concatenate(owners[k]), max(0.02, 3.0 * footprint),
                              views, k, fusion)  # fmt: skip
        lo, hi = np.percentile(cloud, 0.2, axis=0), np.percentile(cloud, 99.8, axis=0)
        # downwards, all but stray points: the lowest 0.2% of a table's points lie 7 cm above the floor (its
        # legs' feet are seen in few frames, 95 of 72k points below 5 cm on hard/stack), and the extent cut them
        lo[2] = np.percentile(cloud[:, 2], 0.02)
        out[k] = (lo, hi, median_depth)
    return out


def _silhouette_width(views: Views, fusion: np.ndarray, k: int, centre: np.ndarray) -> float:
    """How wide the instance's silhouette is at ``centre``, metres: per frame, the diagonal of the 2nd to 98th
    percentile box of its mask's largest piece (a segmenter's false fragment elsewhere in the frame is not the
    object), at the distance of ``centre``; the 80th percentile over the frames (a frame whose mask swallowed a
    neighbour is not the object either)."""
    from scipy.ndimage import label as connected

    widths = []
    for i in fusion:
        mask = views.labels[i] == k
        if np.count_nonzero(mask) < 4:
            continue
        pieces, count = connected(mask)
        if count > 1:
            mask = pieces == 1 + int(np.argmax(np.bincount(pieces.reshape(-1))[1:]))
        rows, cols = np.nonzero(mask)
        span = np.hypot(np.percentile(rows, 98) - np.percentile(rows, 2),
                        np.percentile(cols, 98) - np.percentile(cols, 2))  # fmt: skip
        distance = float(np.linalg.norm(views.poses[i][:3, 3] - centre))
        widths.append(float(span) * distance / float(views.intrinsics[i][0, 0]))
    return float(np.percentile(widths, 80)) if widths else 0.0


def _centre_from_surroundings(views: Views, fusion: np.ndarray, k: int, ring: int = 4) -> np.ndarray | None:
    """Where an instance without depth points of its own is: per frame, its mask's centre back-projected at the
    median depth of the pixels just around the mask (what it rests on or stands in front of: a book on a
    textured table top has none of its own), the median over the frames (world)."""
    from scipy.ndimage import binary_dilation

    assert views.depth is not None
    found = []
    for i in fusion:
        mask = views.labels[i] == k
        if np.count_nonzero(mask) < 4:
            continue
        around = binary_dilation(mask, iterations=ring) & ~mask & (views.depth[i] > 0)
        if np.count_nonzero(around) < 5:
            continue
        z = float(np.median(views.depth[i][around]))
        rows, cols = np.nonzero(mask)
        kk = views.intrinsics[i]
        cam = np.array([(np.median(cols) - kk[0, 2]) / kk[0, 0] * z, (np.median(rows) - kk[1, 2]) / kk[1, 1] * z, z])
        found.append(views.poses[i][:3, :3] @ cam + views.poses[i][:3, 3])
    return np.median(np.array(found), axis=0) if len(found) >= 3 else None


def _extents_estimated(frames: _Frames, fusion: np.ndarray, ids: list[int], config: FitConfig,
                       floor: float | None, dense: int = 1000) -> tuple[dict[int, tuple], set[int]]:  # fmt: skip
    """Depth a prior estimated (stereo: depth on textured pixels and edges only, a small object's on a few dozen).
    An instance with at least ``dense`` depth points keeps their extent, as with a depth sensor. One with fewer
    reaches around the centre of its points (an instance with none: around where the depth just outside its
    masks puts it) 0.4 of its silhouette's width (:func:`_silhouette_width`) each way; the visual hull's extent
    is no bound here (a segmenter's masks carve the wrong piece: the video demo's cabinet kept the ball's). An
    instance with neither keeps the hull's extent. Everything is cut at the floor. Also returns the ids of the
    instances with fewer than ``dense`` points (initialised from their masks, :func:`_init_estimated`)."""
    views = frames.views
    assert views.depth is not None
    found = _extents_metric(frames, fusion, ids)
    out: dict[int, tuple] = {}
    sparse = set()
    hull: dict[int, tuple] | None = None
    for k in ids:
        count = sum(int(np.count_nonzero((views.labels[i] == k) & (views.depth[i] > 0))) for i in fusion)
        if count >= dense and k in found:
            lo, hi, depth = found[k]
        else:
            sparse.add(k)
            centre = (found[k][0] + found[k][1]) / 2 if k in found else _centre_from_surroundings(views, fusion, k)
            if centre is not None:
                reach = 0.4 * _silhouette_width(views, fusion, k, centre)
                lo, hi = centre - reach, centre + reach
                if k in found:
                    lo, hi = np.minimum(lo, found[k][0]), np.maximum(hi, found[k][1])
                depth = found[k][2] if k in found else None
            else:
                hull = hull if hull is not None else _extents_hull(frames, fusion, ids, config)
                if k not in hull:
                    continue
                lo, hi, depth = hull[k][0], hull[k][1], None
        lo, hi = np.array(lo, float), np.array(hi, float)
        if floor is not None:
            lo[2] = max(lo[2], floor - 0.02)
            hi[2] = max(hi[2], lo[2] + 0.02)
        out[k] = (lo, hi, depth)
    return out, sparse


def _scene_bound_without_depth(views: Views, reach: float) -> tuple[np.ndarray, np.ndarray]:
    centres = views.poses[:, :3, 3]
    forward = views.poses[:, :3, 2]
    ahead = centres + reach * forward
    lo = np.minimum(centres.min(0), ahead.min(0)) - 0.25
    hi = np.maximum(centres.max(0), ahead.max(0)) + 0.25
    lo[2] = min(lo[2], centres[:, 2].min() - reach)
    return lo, hi


def _extents_hull(frames: _Frames, fusion: np.ndarray, ids: list[int], config: FitConfig) -> dict[int, tuple]:
    views = frames.views
    lo, hi = _scene_bound_without_depth(views, config.scene_reach)
    voxel = config.hull_voxel
    grid = VoxelGrid.from_bounds(lo, hi, voxel, pad=1)
    while grid.size > 1_500_000:
        voxel *= 1.2
        grid = VoxelGrid.from_bounds(lo, hi, voxel, pad=1)
    pts = grid.points()
    # frames that see no object at all still carve; a voxel projecting on background in any frame is no object's
    seen = np.zeros(len(pts), np.int32)
    bg = np.zeros(len(pts), np.int32)
    hits = {k: np.zeros(len(pts), np.int32) for k in ids}
    for i in fusion:
        row, col, z, valid = views.project(int(i), pts)
        lab = views.labels[i][row, col]
        seen += valid
        bg += valid & (lab == 0)
        for k in np.unique(lab[valid]):
            if int(k) in hits:
                hits[int(k)] += valid & (lab == k)
    out = {}
    free = bg > config.hull_tolerance * np.maximum(seen, 1)
    from scipy.ndimage import label as connected

    for k in ids:
        kept = (hits[k] > 0) & ~free & (seen >= 3)
        if not kept.any():
            kept = (hits[k] > 0) & ~free
        if not kept.any():
            continue
        # stray voxels seen by few frames survive carving: keep the component the instance's hits support most
        comps, count = connected(kept.reshape(grid.shape))
        if count > 1:
            support = np.bincount(comps.reshape(-1), weights=hits[k], minlength=count + 1)
            support[0] = 0
            kept = comps.reshape(-1) == int(np.argmax(support))
        p = pts[kept]
        out[k] = (p.min(0) - voxel, p.max(0) + voxel, None)
    return out


def _voxel_size(extent: np.ndarray, footprint: float, config: FitConfig) -> float:
    voxel = max(float(extent.max()) / config.target_resolution, config.min_voxel, config.footprint_factor * footprint)
    while np.prod(np.ceil(extent / voxel) + 1 + 4) > config.max_voxels:
        voxel *= 1.1
    return voxel


# --------------------------------------------------------------------------------------------- initialisation
def _init_metric(inst: _Instance, views: Views, fusion: np.ndarray, floor: float | None, config: FitConfig) -> None:
    """TSDF fusion of the instance's masked depth over its whole grid; hidden voxels are solid only where
    enclosed (:meth:`FusionResult.solid_sdf` with the grid's shape: the space under a table top stays open)."""
    assert inst.grid is not None
    fine = inst.grid
    trunc = config.trunc_voxels * fine.voxel_size
    frames = [int(i) for i in fusion if (views.labels[i] == inst.instance_id).any()] or [int(i) for i in fusion]
    pts = fine.points()
    fused = fuse_tsdf(pts, views, inst.instance_id, trunc, frames)
    sdf = fused.solid_sdf(trunc, fine.shape)
    inst.frozen = ((fused.weight == 0) & (fused.inside == 0) & (fused.outside == 0)).reshape(fine.shape)
    margin = config.extent_margin * fine.voxel_size
    sdf = np.maximum(sdf, box_sdf(pts, inst.lo - margin, inst.hi + margin))
    if floor is not None:
        sdf = np.maximum(sdf, (floor - pts[:, 2]).astype(np.float32))
    inst.sdf = sdf.reshape(fine.shape).astype(np.float32)
    if fused.behind is not None:
        hidden = (fused.weight == 0) & (sdf < 0) & np.isfinite(fused.behind)
        inst.claim = np.where(hidden, fused.behind, np.nan).astype(np.float32).reshape(fine.shape)


def _init_hull(inst: _Instance, views: Views, fusion: np.ndarray, floor: float | None, config: FitConfig) -> None:
    assert inst.grid is not None
    fine = inst.grid
    trunc = config.trunc_voxels * fine.voxel_size
    coarse = VoxelGrid(origin=fine.origin, voxel_size=2 * fine.voxel_size,
                       shape=tuple(int(np.ceil((n - 1) / 2)) + 1 for n in fine.shape))  # type: ignore[arg-type]  # fmt: skip
    kept_c, _ = carve_hull(coarse.points(), views, inst.instance_id, fusion, config.hull_tolerance)
    pts = fine.points()
    occ_c = sample_grid(kept_c.reshape(coarse.shape).astype(np.float32), coarse, pts, outside=0.0)
    occ = occ_c > 0.5
    band = (occ_c > 0.02) & (occ_c < 0.98)
    if band.any():
        kept_f, _ = carve_hull(pts[band], views, inst.instance_id, fusion, config.hull_tolerance)
        occ[band] = kept_f
    if floor is not None:
        occ &= pts[:, 2] >= floor
    sdf = signed_distance_from_occupancy(occ.reshape(fine.shape), fine.voxel_size)
    inst.sdf = np.clip(sdf, -trunc, trunc)


def _init_estimated(inst: _Instance, views: Views, fusion: np.ndarray, floor: float | None,
                    config: FitConfig) -> None:  # fmt: skip
    """Depth a prior estimated (stereo: sparse, centimetres off at a few metres): the visual hull, carved further
    where the fused depth saw free space in front of the instance's surface. Nothing is frozen: with depth on a
    fifth of the pixels, most voxels no depth observed are still shaped by the masks and colours."""
    _init_hull(inst, views, fusion, floor, config)
    assert inst.grid is not None and inst.sdf is not None
    trunc = config.trunc_voxels * inst.grid.voxel_size
    frames = [int(i) for i in fusion if (views.labels[i] == inst.instance_id).any()] or [int(i) for i in fusion]
    fused = fuse_tsdf(inst.grid.points(), views, inst.instance_id, trunc, frames)
    hull = inst.sdf.reshape(-1)
    # carved only where most of the frames that looked saw free space: a wrong match (a patch across a silhouette
    # takes the depth behind it) sees through the inside of an object, where no right one votes (voxels deeper
    # than the truncation behind a surface get no vote from it)
    free = fused.free if fused.free is not None else fused.outside
    carve = (free >= 2) & (free > fused.inside)
    carved = np.where(carve, np.maximum(hull, fused.tsdf), hull)
    inst.sdf = carved.reshape(inst.grid.shape).astype(np.float32)
    inst.frozen = None


def _floor_estimated(points: np.ndarray) -> float:
    """The floor height from noisy background points (depth a prior estimated): the lowest level holding a large
    share of them (the densest 2 cm band among the lowest third), not their low percentile, which the noise
    pulls down by its own spread."""
    z = np.sort(points[:, 2])
    low = z[: max(1, len(z) // 3)]
    edges = np.arange(low[0], low[-1] + 0.02, 0.005)
    if len(edges) < 2:
        return float(np.median(low))
    counts = np.array([np.count_nonzero(np.abs(low - e) < 0.01) for e in edges])
    best = float(edges[int(np.argmax(counts))])
    near = z[np.abs(z - best) < 0.02]
    return float(np.median(near)) if len(near) else best


def _background_estimated(frames: _Frames, fusion: np.ndarray) -> tuple[float | None, MeshData | None]:
    """Depth a prior estimated: a floor slab at the robust floor height under everything the cameras saw (a room
    shell fused from sparse, noisy points is holes and lumps that objects fall through)."""
    views = frames.views
    assert views.depth is not None
    bg = [views.backproject(int(i), (views.labels[i] == 0) & (views.depth[i] > 0), stride=3) for i in fusion]
    cloud = np.concatenate(bg) if bg else np.zeros((0, 3))
    if len(cloud) < 50:
        return None, None
    floor = _floor_estimated(cloud)
    every = [views.backproject(int(i), views.depth[i] > 0, stride=7) for i in fusion]
    allpts = np.concatenate(every + [views.poses[:, :3, 3]])
    lo, hi = np.percentile(allpts, 1.0, axis=0), np.percentile(allpts, 99.0, axis=0)
    return floor, _floor_slab(floor, lo - 0.5, hi + 0.5)


def _resolve_hidden_claims(instances: list[_Instance], ratio: float = 0.5) -> None:
    """Hidden space two instances both hold solid (behind the surface each was seen by) goes to the one it lies
    closer behind: the other's claim must be at least 1 / ``ratio`` times as far, and a voxel farther. Seen from
    above, the inside of a box standing in a shelf's compartment lies 20 cm behind the shelf's upper board, and a
    few centimetres behind the box's own front; split at their mid-surface, both lost it (bench_02's mug in a
    shelf came out a crescent of its front, a third of its volume, and tipped)."""
    yields: dict[int, np.ndarray] = {}
    for a, ia in enumerate(instances):
        if ia.claim is None or ia.grid is None or ia.sdf is None or not np.isfinite(ia.claim).any():
            continue
        ga = ia.grid
        held = np.isfinite(ia.claim.reshape(-1))
        pts = ga.points()
        lose = np.zeros(len(pts), bool)
        for b, ib in enumerate(instances):
            if b == a or ib.claim is None or ib.grid is None or not np.isfinite(ib.claim).any():
                continue
            gb = ib.grid
            inbox = held & np.all((pts >= gb.origin) & (pts <= gb.upper), axis=1)
            if not inbox.any():
                continue
            index = np.clip(np.rint((pts[inbox] - gb.origin) / gb.voxel_size).astype(int), 0,
                            np.asarray(gb.shape) - 1)  # fmt: skip
            other = ib.claim[index[:, 0], index[:, 1], index[:, 2]]
            own = ia.claim.reshape(-1)[inbox]
            stronger = np.isfinite(other) & (other < ratio * own) & (own - other > ga.voxel_size)
            lose[np.nonzero(inbox)[0][stronger]] = True
        if lose.any():
            yields[a] = lose
    for a, lose in yields.items():
        inst = instances[a]
        flat = inst.sdf.reshape(-1).copy()
        flat[lose] = np.abs(flat[lose])
        inst.sdf = flat.reshape(inst.grid.shape)
    for inst in instances:  # spent: no later step reads them
        inst.claim = None


def _resolve_overlaps(instances: list[_Instance]) -> None:
    """Split space claimed by two instances at their mid-surface: s_a <- max(s_a, (s_a - s_b) / 2)."""
    updates: dict[int, np.ndarray] = {}
    for a, ia in enumerate(instances):
        if ia.sdf is None or ia.grid is None:
            continue
        ga = ia.grid
        lo_a, hi_a = ga.origin, ga.upper
        new = ia.sdf.copy()
        pts = None
        for b, ib in enumerate(instances):
            if b == a or ib.sdf is None or ib.grid is None:
                continue
            lo_b, hi_b = ib.grid.origin, ib.grid.upper
            if np.any(np.maximum(lo_a, lo_b) > np.minimum(hi_a, hi_b)):
                continue
            if pts is None:
                pts = ga.points()
            flat = ia.sdf.reshape(-1)
            near = flat < ga.voxel_size  # only where a is inside or at its surface
            inbox = near & np.all((pts >= lo_b) & (pts <= hi_b), axis=1)
            if not inbox.any():
                continue
            sb = sample_grid(ib.sdf, ib.grid, pts[inbox], outside=1.0)
            sa = flat[inbox]
            cand = np.maximum(sa, 0.5 * (sa - sb))
            view = new.reshape(-1)
            view[inbox] = np.maximum(view[inbox], cand)
        updates[a] = new
    for a, grid in updates.items():
        instances[a].sdf = grid


# --------------------------------------------------------------------------------------------- refinement
class _RaySampler:
    """Instance-balanced pixel sampling over the frames kept in memory."""

    def __init__(self, frames: _Frames, index_of: dict[int, int], rng: np.random.Generator) -> None:
        self.frames = frames
        self.rng = rng
        n, h, w = frames.views.labels.shape
        lut = np.zeros(max(max(index_of, default=0), int(frames.views.labels.max())) + 1, np.int64)
        for inst_id, k in index_of.items():
            lut[inst_id] = k + 1
        raw = frames.views.labels
        # [N, H*W] 0 = background, k + 1 = instance k, -1 = unknown (see label_consensus)
        self.labels = np.where(raw >= 0, lut[np.maximum(raw, 0)], -1).reshape(n, -1)
        self.groups: list[list[np.ndarray]] = []
        for i in range(n):
            lab = self.labels[i]
            order = np.argsort(lab, kind="stable")
            ids, starts = np.unique(lab[order], return_index=True)
            ends = np.append(starts[1:], len(order))
            self.groups.append([order[s:e] for k, s, e in zip(ids, starts, ends, strict=True) if k > 0])

    def sample(self, frames_per_step: int, rays: int, balanced: float) -> tuple[np.ndarray, np.ndarray]:
        """(frame [R] int, pixel [R] int flat index) for one step."""
        n = self.labels.shape[0]
        pick = self.rng.choice(n, size=min(frames_per_step, n), replace=False)
        per = max(1, rays // len(pick))
        f_out, p_out = [], []
        hw = self.labels.shape[1]
        for i in pick:
            groups = self.groups[i]
            n_bal = int(per * balanced) if groups else 0
            uniform = self.rng.integers(0, hw, size=per - n_bal)
            parts = [uniform]
            if n_bal:
                each = max(1, n_bal // len(groups))
                parts += [g[self.rng.integers(0, len(g), size=each)] for g in groups]
            pix = np.concatenate(parts)
            p_out.append(pix)
            f_out.append(np.full(len(pix), i))
        return np.concatenate(f_out), np.concatenate(p_out)


def _refine(instances: list[_Instance], frames: _Frames, relative: bool, config: FitConfig,
            progress: object | None) -> dict[str, float]:  # fmt: skip

    active = [inst for inst in instances if inst.sdf is not None and inst.grid is not None]
    if not active or config.iterations <= 0:
        return {}
    with torch_threads(config.threads):
        return _refine_steps(active, frames, relative, config, progress)


def _refine_steps(active: list[_Instance], frames: _Frames, relative: bool, config: FitConfig,
                  progress: object | None) -> dict[str, float]:  # fmt: skip
    import torch

    from holousd.render._volume import RayBatch, SdfGridSet, render_rays

    device = torch.device(config.device)
    gen = torch.Generator(device=device).manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    grids = SdfGridSet(
        [inst.sdf for inst in active],  # type: ignore[misc]
        np.stack([inst.grid.origin for inst in active]),  # type: ignore[union-attr]
        np.array([inst.grid.voxel_size for inst in active]),  # type: ignore[union-attr]
        colors=np.stack([inst.color for inst in active]),
        device=config.device,
    )
    index_of = {inst.instance_id: k for k, inst in enumerate(active)}
    sampler = _RaySampler(frames, index_of, rng)
    groups = [{"params": [grids.sdf[k]], "lr": config.sdf_lr * float(grids.voxel[k])} for k in range(grids.count)]
    groups.append({"params": grids.color, "lr": config.color_lr})
    opt = torch.optim.Adam(groups, betas=(0.9, 0.99))
    w = config.weights
    views = frames.views
    n, h, width = views.labels.shape
    rgb_all = frames.rgb.reshape(n, -1, 3)
    depth_all = frames.depth_raw.reshape(n, -1) if frames.depth_raw is not None else None
    normal_all = frames.normals.reshape(n, -1, 3) if frames.normals is not None else None
    pairs = []
    for a in range(grids.count):
        for b in range(a + 1, grids.count):
            lo = torch.maximum(grids.lo[a], grids.lo[b])
            hi = torch.minimum(grids.hi[a], grids.hi[b])
            if bool((hi > lo).all()):
                pairs.append((a, b, lo, hi))
    use_normals = normal_all is not None and w.normal > 0
    # what no fused frame observed keeps its initial value (the enclosure rules decided it): with no data term,
    # the soft occlusion of the mask term and the overlap penalty alone moved it at Adam's full step (the
    # demo's table top under its box sank 2 cm in 40 steps)
    kept = [(k, torch.as_tensor(inst.frozen, device=device), grids.sdf[k].detach()[0, 0].clone())
            for k, inst in enumerate(active) if inst.frozen is not None and inst.frozen.any()]  # fmt: skip
    losses: dict[str, float] = {}
    for _step in range(config.iterations):
        f_idx, p_idx = sampler.sample(config.frames_per_step, config.rays, config.balanced_fraction)
        rows, cols = p_idx // width, p_idx % width
        k = views.intrinsics[f_idx]  # [R, 3, 3]
        dirs_cam = np.stack([(cols - k[:, 0, 2]) / k[:, 0, 0], (rows - k[:, 1, 2]) / k[:, 1, 1], np.ones(len(cols))], 1)
        rot = views.poses[f_idx, :3, :3]  # [R, 3, 3]
        dirs = np.einsum("rij,rj->ri", rot, dirs_cam)  # [R, 3]
        rays = RayBatch(
            origins=torch.tensor(views.poses[f_idx, :3, 3], dtype=torch.float32, device=device),
            dirs=torch.tensor(dirs, dtype=torch.float32, device=device),
            labels=torch.tensor(sampler.labels[f_idx, p_idx], dtype=torch.long, device=device),
        )
        grids.begin(with_gradients=True)
        out = render_rays(grids, rays, config.volume, gen)
        target_rgb = torch.tensor(rgb_all[f_idx, p_idx] / 255.0, dtype=torch.float32, device=device)  # [R, 3]
        pred_rgb = out.color + (1.0 - out.opacity)[:, None] * target_rgb
        terms: dict[str, torch.Tensor] = {}
        terms["rgb"] = ((pred_rgb - target_rgb) ** 2).mean()
        terms["mask"] = torch.nn.functional.nll_loss(torch.log(out.probs), rays.labels, ignore_index=-1)
        obj = rays.labels > 0
        if depth_all is not None and w.depth > 0:
            d = torch.tensor(depth_all[f_idx, p_idx], dtype=torch.float32, device=device)
            valid = obj & (d > 0)
            if valid.any():
                pred = out.depth[valid]
                target = d[valid]
                if relative:
                    target = _align_scale_shift(target, pred.detach(), torch.tensor(f_idx, device=device)[valid])
                terms["depth"] = (pred - target).abs().mean()
        if use_normals and out.normal is not None:
            nrm = torch.tensor(normal_all[f_idx, p_idx], dtype=torch.float32, device=device)  # type: ignore[index]
            valid = obj & (nrm.norm(dim=-1) > 0.5)
            if valid.any():
                rot_t = torch.tensor(rot, dtype=torch.float32, device=device)[valid]
                pred_cam = torch.einsum("rji,rj->ri", rot_t, out.normal[valid])
                pred_cam = pred_cam / pred_cam.norm(dim=-1, keepdim=True).clamp(min=1e-6)
                terms["normal"] = (pred_cam - nrm[valid]).abs().sum(-1).mean() + (
                    1.0 - (pred_cam * nrm[valid]).sum(-1)
                ).mean()
        eik, smooth = _regularisers(grids, rng, device)
        terms["eikonal"] = eik
        terms["smooth"] = smooth
        if pairs and w.overlap > 0:
            pen = []
            for a, b, lo, hi in pairs:
                u = torch.rand(config.overlap_points, 3, generator=gen, device=device)
                p = lo + (hi - lo) * u
                pen.append(torch.relu(-(grids.sdf_only(a, p) + grids.sdf_only(b, p))).mean())
            terms["overlap"] = torch.stack(pen).mean()
        loss = sum(getattr(w, name) * value for name, value in terms.items())
        opt.zero_grad(set_to_none=True)
        loss.backward()  # type: ignore[union-attr]
        opt.step()
        with torch.no_grad():
            for k, mask, start in kept:
                grids.sdf[k][0, 0][mask] = start[mask]
        grids.end()
        losses = {name: float(value.detach()) for name, value in terms.items()}
        if progress is not None:
            progress.update(1)  # type: ignore[attr-defined]
            progress.set_postfix(loss=f"{float(loss.detach()):.4f}")  # type: ignore[attr-defined]
    for k, inst in enumerate(active):
        inst.sdf = grids.sdf[k].detach().cpu().numpy()[0, 0].astype(np.float32)
        inst.color = torch.sigmoid(grids.color[k].detach()).mean(dim=(2, 3, 4))[0].cpu().numpy()
    return losses


def _align_scale_shift(target: torch.Tensor, pred: torch.Tensor, frame: torch.Tensor) -> torch.Tensor:
    """Per frame, the least-squares a * target + b closest to ``pred`` (scale-and-shift invariant depth)."""
    import torch

    out = torch.empty_like(target)
    for f in torch.unique(frame):
        sel = frame == f
        x, y = target[sel], pred[sel]
        if x.numel() < 8:
            out[sel] = y
            continue
        a_mat = torch.stack([x, torch.ones_like(x)], 1)  # [M, 2]
        sol = torch.linalg.lstsq(a_mat, y[:, None]).solution[:, 0]
        out[sel] = sol[0] * x + sol[1]
    return out


def _kinked(g: torch.Tensor, h: float) -> torch.Tensor:
    """[X, Y, Z] voxels in the middle of a thin solid part: inside (``g`` < 0) where the field's slope along some
    axis rises by about a voxel's worth or more (a second difference over 0.9 ``h``; the middle of a slab two
    voxels thick has exactly ``h``), the valley a distance field has on a thin part's medial axis (a table's leg
    two voxels thick, a shelf's board). |grad| = 1 does not hold there: central differences straddle the kink and
    read |grad| < 1, and asking them for 1 asks the field to have no valley, that is, no leg (on the phone demo
    the eikonal term erased one or two of the table's four legs with three seeds out of four). Ridges (the
    middle of a thin gap between two surfaces, where the slope falls) stay in: leaving them out as well lowered
    the phone hard suite's fit F1 by 2 points in its shelf and against_wall scenes."""
    import torch

    out = torch.zeros_like(g, dtype=torch.bool)
    for axis in range(3):
        n = g.shape[axis]
        if n < 3:
            continue
        middle = g.narrow(axis, 1, n - 2)
        second = g.narrow(axis, 2, n - 2) - 2.0 * middle + g.narrow(axis, 0, n - 2)
        out.narrow(axis, 1, n - 2).logical_or_((second > 0.9 * h) & (middle < 0))
    return out


def _regularisers(grids: object, rng: np.random.Generator, device: torch.device,
                  samples: int = 4096) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """Eikonal and smoothness terms on random voxels near each instance's surface (the eikonal term not in a thin
    part's middle, see :func:`_kinked`)."""
    import torch

    eik, smooth = [], []
    for k in range(grids.count):  # type: ignore[attr-defined]
        g = grids.sdf[k][0, 0]  # type: ignore[attr-defined]
        h = float(grids.voxel[k])  # type: ignore[attr-defined]
        grad = grids._cache[k][0, 1:4]  # type: ignore[attr-defined]  # [3, X, Y, Z]
        with torch.no_grad():
            band = ((g.abs() < 2.5 * h) & ~_kinked(g, h)).reshape(-1).nonzero().squeeze(1)
        if band.numel() == 0:
            continue
        pick = band[torch.as_tensor(rng.integers(0, band.numel(), size=min(samples, band.numel())), device=device)]
        norm = grad.reshape(3, -1)[:, pick].norm(dim=0)
        eik.append(((norm - 1.0) ** 2).mean())
        if min(g.shape) >= 3:
            lap = (
                g[2:, 1:-1, 1:-1] + g[:-2, 1:-1, 1:-1] + g[1:-1, 2:, 1:-1] + g[1:-1, :-2, 1:-1]
                + g[1:-1, 1:-1, 2:] + g[1:-1, 1:-1, :-2] - 6 * g[1:-1, 1:-1, 1:-1]
            )  # fmt: skip
            with torch.no_grad():
                inner = (g[1:-1, 1:-1, 1:-1].abs() < 2.5 * h).reshape(-1).nonzero().squeeze(1)
            if inner.numel():
                sel = inner[torch.as_tensor(rng.integers(0, inner.numel(), size=min(samples, inner.numel())))]
                smooth.append(((lap.reshape(-1)[sel] / h) ** 2).mean() * h)
    zero = torch.zeros((), device=device)
    return (torch.stack(eik).mean() if eik else zero), (torch.stack(smooth).mean() if smooth else zero)


# --------------------------------------------------------------------------------------------- stage
def _redistance(sdf: np.ndarray, voxel: float, band: float) -> np.ndarray:
    """Keep the fitted values near the surface and Euclidean distances (from the occupancy) beyond."""
    edt = signed_distance_from_occupancy(sdf < 0, voxel)
    return np.where(np.abs(sdf) < band, sdf, edt).astype(np.float32)


def _peak_memory_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def fit(scene: SceneGraph, obs: Observations, config: FitConfig | None = None,
        out_dir: str | os.PathLike[str] | None = None) -> FitResult:  # fmt: skip
    """Fit every instance's SDF and mesh and write them as the layer ``10_fit.usda`` over ``scene``.

    Args:
        scene: The scene after s0_observe (its object nodes carry the instance ids).
        obs: The capture s0_observe read (instance masks required; depth and normals used when present).
        config: Settings (default :data:`DEFAULT`).
        out_dir: Folder of the new layer (default: the folder of the scene's root layer).

    Returns:
        The result, with ``result.scene`` showing ``10_fit.usda`` as its root layer.
    """
    config = config or DEFAULT
    start = time.perf_counter()
    timings: dict[str, float] = {}
    if not obs.has_masks:
        raise HolousdError(
            f"{obs.root or '<observations>'}: no instance masks; fitting needs one integer mask per frame "
            "(0 = background, 1..N objects): add masks/ to a native capture or instance_mask/ to a nerfstudio one"
        )
    if out_dir is None:
        if scene.path is None:
            raise HolousdError("the scene is in memory; pass out_dir or create it with a path (s0_observe does)")
        out_dir = scene.path.parent
    out_dir = Path(out_dir)
    nodes = [info for info in scene.nodes() if info.role == "object"]
    if not nodes:
        raise HolousdError(f"{scene.path}: no object nodes; run s0_observe on a capture whose masks label objects")
    ids = [info.instance_id for info in nodes]
    use_depth = obs.has_depth
    relative = use_depth and obs.depth_kind == "relative"
    metric = use_depth and obs.depth_kind == "metric"
    # depth a prior estimated from the colour frames and these poses (stereo): aligning the poses against it would
    # only fit the poses to their own depth
    estimated = metric and obs.metadata.get("depth_prior") is not None
    if estimated and config.refine_poses == "on":
        print(f"warning: {obs.root or '<observations>'}: refine_poses 'on' is not applied: the depth was estimated "
              f"from these poses ({obs.metadata['depth_prior']})", file=sys.stderr)  # fmt: skip
    if config.refine_poses not in ("auto", "on", "off"):
        raise HolousdError(f"FitConfig.refine_poses {config.refine_poses!r}: choose 'auto', 'on' or 'off'")
    frames, checked, aligned = _load_frames(obs, max(config.render_frames, config.fusion_frames), use_depth,
                                            obs.has_normals, config.consensus,
                                            "off" if estimated else config.refine_poses, config.poses)  # fmt: skip
    views = frames.views
    if aligned is not None:
        timings["poses"] = aligned.wall_s
        if config.progress:
            print(f"fit: {_pose_summary(aligned)}", file=sys.stderr)
    elif config.refine_poses == "on" and not metric:
        print(f"warning: {obs.root or '<observations>'}: refine_poses 'on' needs metric depth and the capture has "
              "none: its camera poses are used as given", file=sys.stderr)  # fmt: skip
    if checked is not None and config.progress and (checked.relabelled or checked.unknown or checked.flying):
        share = 100.0 * (checked.relabelled + checked.unknown) / max(1, checked.checked)
        print(f"fit: labels checked across frames: {checked.relabelled} pixels relabelled, {checked.unknown} "
              f"unknown ({share:.1f}% of {checked.checked}), {checked.flying} flying depth pixels dropped",
              file=sys.stderr)  # fmt: skip
    fusion = evenly_spaced(len(views), config.fusion_frames)
    # once, before any turn; not from estimated depth (stereo's normals are too noisy to tell the room's yaw or a
    # tilted world frame: the levelled demo capture read as tilted by 4 deg)
    normals = [_world_normals(views, int(i)) for i in fusion] if metric and not estimated else []
    yaw = 0.0
    if normals and config.align_room:
        found, agreement = _room_yaw(normals)
        if abs(np.degrees(found)) >= config.min_yaw_deg and agreement >= 0.2:
            yaw = found
            if config.progress:
                print(f"fit: working in the room's frame, turned {np.degrees(yaw):.1f} deg about z from the "
                      f"capture's (vertical surfaces agree {100 * agreement:.0f}%)", file=sys.stderr)  # fmt: skip
    room = Pose(orientation=(0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)))  # the room's frame in the capture's
    to_world = room.rotation_matrix()
    if yaw:
        turn = np.eye(4)
        turn[:3, :3] = to_world.T
        views.poses = np.einsum("ij,njk->nik", turn, views.poses)  # the fit's frame: the room's walls on x, y
    tilt = _up_tilt(normals) if normals else None
    if tilt is not None and tilt > config.max_tilt_deg:
        where = obs.camera_file or obs.root or "<observations>"
        print(f"warning: {where}: the capture's floor and tops face {tilt:.1f} deg away from its world z axis: "
              "physics pulls along -z, so what stands in the room slides or tips in the scene; give camera poses "
              "with gravity along -z (level the world frame)", file=sys.stderr)  # fmt: skip
    timings["load"] = time.perf_counter() - start - timings.get("poses", 0.0)

    t0 = time.perf_counter()
    floor: float | None = None
    sparse: set[int] = set()  # instances a depth prior gave few points (initialised from their masks)
    background: MeshData | None = None
    if estimated:
        floor, background = _background_estimated(frames, fusion)
        extents, sparse = _extents_estimated(frames, fusion, ids, config, floor)
    elif metric:
        floor, background = _background_metric(frames, fusion, config)
        extents = _extents_metric(frames, fusion, ids)
    else:
        extents = _extents_hull(frames, fusion, ids, config)
    timings["extents"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    instances: list[_Instance] = []
    f_mean = float(np.mean(views.intrinsics[:, [0, 1], [0, 1]]))
    for info in nodes:
        k = info.instance_id
        pixels = int(sum(int((views.labels[i] == k).sum()) for i in range(len(views))))
        if k not in extents:
            instances.append(_Instance(name=info.name, instance_id=k, lo=np.zeros(3), hi=np.zeros(3), footprint=0.0,
                                       pixels=pixels))  # fmt: skip
            continue
        lo, hi, med_depth = extents[k]
        if med_depth is None:
            cams = views.poses[:, :3, 3]
            med_depth = float(np.median(np.linalg.norm(cams - (lo + hi) / 2, axis=1)))
        footprint = med_depth / f_mean
        inst = _Instance(name=info.name, instance_id=k, lo=lo, hi=hi, footprint=footprint, pixels=pixels)
        voxel = _voxel_size(np.maximum(hi - lo, 1e-3), footprint, config)
        inst.grid = VoxelGrid.from_bounds(lo, hi, voxel, pad=2 + int(np.ceil(config.extent_margin)))
        colours = [frames.rgb[i][views.labels[i] == k] for i in fusion]
        colours = [c for c in colours if len(c)]
        if colours:
            inst.color = np.concatenate(colours).mean(0) / 255.0
        instances.append(inst)
    if not metric:
        lows = [inst.lo[2] for inst in instances if inst.grid is not None]
        floor = None  # the hull bottoms are no reliable floor: keep their own extent
        floor_estimate = float(min(lows)) if lows else 0.0
    else:
        floor_estimate = float(floor) if floor is not None else 0.0

    bar = None
    if config.progress:
        from tqdm import tqdm

        bar = tqdm(total=len(instances) + config.iterations + len(instances), desc="s1_fit", file=sys.stderr,
                   unit="step", leave=False)  # fmt: skip
    for inst in instances:
        if inst.grid is not None:
            if estimated and inst.instance_id in sparse:
                _init_estimated(inst, views, fusion, floor, config)
            elif metric:
                _init_metric(inst, views, fusion, floor, config)
            else:
                _init_hull(inst, views, fusion, floor, config)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(object=inst.name)
    if config.resolve_overlaps:
        _resolve_hidden_claims(instances)
        _resolve_overlaps(instances)
    timings["init"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    losses = _refine(instances, frames, relative, config, bar)
    timings["refine"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    if estimated and floor is not None:
        # the refinement has no frozen voxels here and the masks say nothing about the floor: cut what it grew
        # under the floor again (the demo's cabinet reached 5 cm into it and was thrown through it)
        for inst in instances:
            if inst.grid is not None and inst.sdf is not None:
                below = (floor - inst.grid.points()[:, 2]).reshape(inst.grid.shape).astype(np.float32)
                inst.sdf = np.maximum(inst.sdf, below)
    if config.resolve_overlaps and config.iterations > 0:
        _resolve_overlaps(instances)
    scene.push_layer(out_dir / FIT_LAYER, provenance="s1_fit", replace=True)
    if aligned is not None and aligned.applied:
        _write_camera_poses(scene, obs, frames.index, aligned)
    results: list[ObjectFit] = []
    placed: list[np.ndarray] = []  # the meshes' bounds in the fit's frame
    for inst in instances:
        fit_info = ObjectFit(name=inst.name, instance_id=inst.instance_id, pixels=inst.pixels,
                             voxel_size=inst.grid.voxel_size if inst.grid else 0.0,
                             resolution=inst.grid.shape if inst.grid else (0, 0, 0))  # fmt: skip
        meshed = None
        if inst.grid is not None and inst.sdf is not None:
            trunc = config.trunc_voxels * inst.grid.voxel_size
            inst.sdf = _redistance(inst.sdf, inst.grid.voxel_size, trunc)
            extent = float((inst.hi - inst.lo).max())
            meshed = mesh_from_sdf(inst.sdf, inst.grid.origin, inst.grid.voxel_size,
                                   max_faces=face_budget(extent, config.faces_per_m2))  # fmt: skip
        if meshed is None:
            meshed_mesh = _fallback_mesh(inst, frames, fusion, metric)
            fallback = "box"
        else:
            meshed_mesh, fallback = meshed.mesh, meshed.fallback
        if meshed_mesh is not None:
            lo, hi = meshed_mesh.bounds
            origin = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
            scene.set_pose(inst.name, Pose(translation=to_world @ origin, orientation=room.orientation))
            scene.set_mesh(inst.name, MeshData(points=meshed_mesh.points - origin, faces=meshed_mesh.faces))
            if inst.grid is not None and inst.sdf is not None:  # the SDF holds what the mesh holds, no floater
                kept = meshed_only(inst.sdf, inst.grid.origin, inst.grid.voxel_size, meshed_mesh)
                scene.set_sdf(inst.name, SdfField(grid=kept, origin=inst.grid.origin - origin,
                                                  voxel_size=inst.grid.voxel_size))  # fmt: skip
            fit_info.faces = len(meshed_mesh.faces)
            fit_info.watertight = _is_watertight(meshed_mesh)
            tolerance = max(0.02, 3.0 * (inst.grid.voxel_size if inst.grid is not None else 0.0))
            fit_info.observed_fraction = observed_fraction(meshed_mesh.points, meshed_mesh.faces, views,
                                                           inst.instance_id, tolerance)  # fmt: skip
            scene.set_node_info(inst.name, observed_fraction=fit_info.observed_fraction)
            fit_info.fallback = fallback
            fit_info.bounds_world = np.stack([lo, hi])  # the fit's frame here; turned to the world's below
            placed.append(fit_info.bounds_world)
            if yaw:
                world = meshed_mesh.points @ to_world.T
                fit_info.bounds_world = np.stack([world.min(axis=0), world.max(axis=0)])
        results.append(fit_info)
        if bar is not None:
            bar.update(1)
    if background is None:
        cams = views.poses[:, :3, 3]
        pts = np.concatenate([np.concatenate(placed), cams]) if placed else cams
        margin = 0.5
        background = _floor_slab(floor_estimate, pts.min(0) - margin, pts.max(0) + margin)
    seen = observed_fraction(background.points, background.faces, views, 0, max(0.05, 3.0 * config.background_voxel))
    scene.set_mesh(BACKGROUND, replace(background, points=background.points @ to_world.T) if yaw else background)
    scene.set_node_info(BACKGROUND, observed_fraction=seen)
    scene.save()
    if bar is not None:
        bar.close()
    timings["mesh"] = time.perf_counter() - t0
    return FitResult(
        scene=scene,
        objects=results,
        floor_z=floor_estimate,
        background_faces=len(background.faces),
        used_depth=obs.depth_kind or "none",
        yaw_deg=float(np.degrees(yaw)),
        tilt_deg=tilt,
        consensus=checked,
        poses=aligned,
        wall_time_s=time.perf_counter() - start,
        timings=timings,
        peak_memory_mb=_peak_memory_mb(),
        final_losses=losses,
    )


def _is_watertight(mesh: MeshData) -> bool:
    import trimesh

    return bool(trimesh.Trimesh(vertices=mesh.points, faces=mesh.faces, process=False).is_watertight)


def _fallback_mesh(inst: _Instance, frames: _Frames, fusion: np.ndarray, metric: bool) -> MeshData | None:
    """A box over the observed extent when no surface could be fitted, so that no object is lost."""
    import trimesh

    if inst.grid is None:
        return None
    size = np.maximum(inst.hi - inst.lo, 0.01)
    box = trimesh.creation.box(extents=size)
    box.apply_translation((inst.lo + inst.hi) / 2)
    return MeshData(points=np.asarray(box.vertices), faces=np.asarray(box.faces))


def run(scene: SceneGraph, obs: Observations, config: FitConfig | None = None) -> SceneGraph:
    """Stage transform s1_fit (geometry): push ``10_fit.usda`` beside the scene's root layer (see :func:`fit`)."""
    return fit(scene, obs, config).scene


def with_seed(config: FitConfig, seed: int, progress: bool | None = None) -> FitConfig:
    """A copy of ``config`` with another seed (and progress setting)."""
    return replace(config, seed=seed, progress=config.progress if progress is None else progress)
