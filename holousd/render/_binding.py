"""Gaussians on a mesh: splats bound to triangle faces, posed by the object's state.

Splat k lives on face f = face_index[k] with vertices (v0, v1, v2) in object coordinates. Its face frame is
t = (v1 - v0) / |v1 - v0| (the first edge), n = the unit face normal, b = n x t. The splat's axes are t and b
rotated by ``in_plane_rotation`` about n, then n; its centre is sum_i w_i v_i + normal_offset * n and its
standard deviations are (in_plane_scale, flatness * max(in_plane_scale)): flat along the normal. Object
coordinates are mapped to the world by the node's pose, so a moved or simulated object carries its splats with
no refit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from holousd._errors import InvalidDataError
from holousd.render._camera import Camera
from holousd.usd import GaussianSplats, MeshData, Pose

if TYPE_CHECKING:
    import torch

__all__ = [
    "FLATNESS",
    "SH_C0",
    "SplatBudget",
    "bound_gaussians",
    "initial_bound_splats",
    "rotations_to_quats",
    "splat_budget",
    "splats_in_world",
    "sync_bound_splats",
]

SH_C0 = 0.28209479177387814
"""Real spherical harmonic Y_0^0: colour = 0.5 + SH_C0 * coefficient (the 3DGS convention)."""
FLATNESS = 1e-3
"""Default ratio of the normal-axis standard deviation to the larger in-plane one."""


def _face_frames_np(mesh: MeshData) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    tri = mesh.points[mesh.faces]  # [F, 3, 3]
    e1 = tri[:, 1] - tri[:, 0]
    cross = np.cross(e1, tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    if np.any(area2 < 1e-14):
        raise InvalidDataError(f"mesh has {int(np.sum(area2 < 1e-14))} degenerate (zero-area) faces; clean it first")
    n = cross / area2[:, None]
    t = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    return tri, t, np.cross(n, t), n


def bound_gaussians(
    points: torch.Tensor,
    faces: torch.Tensor,
    face_index: torch.Tensor,
    barycentric: torch.Tensor,
    normal_offset: torch.Tensor,
    in_plane_rotation: torch.Tensor,
    in_plane_scale: torch.Tensor,
    *,
    pose_rotation: torch.Tensor | None = None,
    pose_translation: torch.Tensor | None = None,
    flatness: float = FLATNESS,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Differentiable world centres, rotations and scales of splats bound to a mesh (torch).

    Args:
        points: [V, 3] mesh vertices, object coordinates, metres.
        faces: [F, 3] triangle vertex indices (int64).
        face_index: [N] face of each splat (int64).
        barycentric: [N, 3] barycentric coordinates.
        normal_offset: [N] offset along the face normal, metres.
        in_plane_rotation: [N] rotation about the normal from the first edge, radians.
        in_plane_scale: [N, 2] in-plane standard deviations, metres.
        pose_rotation: [3, 3] object-to-world rotation (None: identity).
        pose_translation: [3] object origin in the world, metres (None: zero).
        flatness: Normal-axis standard deviation as a fraction of the larger in-plane one.

    Returns:
        ([N, 3] centres, [N, 3, 3] rotations whose columns are the splat axes, [N, 3] standard deviations).
    """
    import torch

    tri = points[faces[face_index]]  # [N, 3, 3]
    e1 = tri[:, 1] - tri[:, 0]
    cross = torch.linalg.cross(e1, tri[:, 2] - tri[:, 0])
    n = cross / cross.norm(dim=1, keepdim=True).clamp_min(1e-20)  # [N, 3]
    t = e1 / e1.norm(dim=1, keepdim=True).clamp_min(1e-20)
    b = torch.linalg.cross(n, t)
    cos, sin = torch.cos(in_plane_rotation)[:, None], torch.sin(in_plane_rotation)[:, None]
    a1 = cos * t + sin * b
    a2 = -sin * t + cos * b
    rot = torch.stack([a1, a2, n], dim=2)  # [N, 3, 3] columns = axes
    centre = (barycentric[:, :, None] * tri).sum(1) + normal_offset[:, None] * n  # [N, 3]
    if pose_rotation is not None:
        rot = pose_rotation @ rot
        centre = centre @ pose_rotation.T
    if pose_translation is not None:
        centre = centre + pose_translation
    thin = flatness * in_plane_scale.max(dim=1).values
    scales = torch.cat([in_plane_scale, thin[:, None]], dim=1)  # [N, 3]
    return centre, rot, scales


def rotations_to_quats(rot: np.ndarray) -> np.ndarray:
    """Convert [N, 3, 3] rotation matrices to [N, 4] unit quaternions (x, y, z, w), w >= 0."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(rot, dtype=np.float64)).as_quat()  # scalar-last
    q[q[:, 3] < 0] *= -1
    return q


def sync_bound_splats(splats: GaussianSplats, mesh: MeshData, *, flatness: float | None = None) -> GaussianSplats:
    """Recompute a bound splat set's object-space positions, orientations and scales from its binding.

    This keeps the plain UsdVol attributes (read by any 3DGS viewer) consistent with the binding.

    Args:
        splats: Splats with binding fields.
        mesh: The mesh they are bound to (object coordinates).
        flatness: Normal-axis ratio; None keeps each splat's stored ratio scales[:, 2] / max(in-plane).
    """
    import torch

    if not splats.bound:
        raise InvalidDataError("sync_bound_splats: the splats carry no face binding (face_index is None)")
    _check_binding(splats, mesh)
    ratio = flatness
    if ratio is None:
        big = np.maximum(splats.in_plane_scale.max(axis=1), 1e-12)
        ratio = float(np.median(splats.scales[:, 2] / big)) if len(splats) else FLATNESS
    with torch.no_grad():
        centre, rot, scales = bound_gaussians(
            torch.tensor(mesh.points), torch.tensor(mesh.faces),
            torch.tensor(splats.face_index.astype(np.int64)), torch.tensor(splats.barycentric, dtype=torch.float64),
            torch.tensor(splats.normal_offset, dtype=torch.float64),
            torch.tensor(splats.in_plane_rotation, dtype=torch.float64),
            torch.tensor(splats.in_plane_scale, dtype=torch.float64), flatness=ratio,
        )  # fmt: skip
    return GaussianSplats(
        positions=centre.numpy(), orientations=rotations_to_quats(rot.numpy()), scales=scales.numpy(),
        opacities=splats.opacities, sh_coeffs=splats.sh_coeffs, face_index=splats.face_index,
        barycentric=splats.barycentric, normal_offset=splats.normal_offset,
        in_plane_rotation=splats.in_plane_rotation, in_plane_scale=splats.in_plane_scale,
    )  # fmt: skip


def _check_binding(splats: GaussianSplats, mesh: MeshData) -> None:
    if len(splats) and (splats.face_index.min() < 0 or splats.face_index.max() >= len(mesh.faces)):
        raise InvalidDataError(
            f"splat face_index spans [{splats.face_index.min()}, {splats.face_index.max()}] but the mesh has "
            f"{len(mesh.faces)} faces; the splats were bound to another mesh: "
            "re-run the appearance stage (holousd.stages.appearance.run)"
        )


def splats_in_world(
    splats: GaussianSplats, pose: Pose, mesh: MeshData | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World centres, rotations and scales of a node's splats at ``pose``.

    Bound splats are re-derived from ``mesh`` (so they follow mesh and pose edits); unbound splats, or bound
    ones when ``mesh`` is None, are moved rigidly from their stored object-space positions and orientations.

    Returns:
        ([N, 3] centres, [N, 3, 3] rotations, [N, 3] standard deviations), float64 numpy.
    """
    import torch

    rot_pose = pose.rotation_matrix()
    if splats.bound and mesh is not None:
        _check_binding(splats, mesh)
        big = np.maximum(splats.in_plane_scale.max(axis=1), 1e-12)
        ratio = float(np.median(splats.scales[:, 2] / big)) if len(splats) else FLATNESS
        with torch.no_grad():
            centre, rot, scales = bound_gaussians(
                torch.tensor(mesh.points), torch.tensor(mesh.faces),
                torch.tensor(splats.face_index.astype(np.int64)),
                torch.tensor(splats.barycentric, dtype=torch.float64),
                torch.tensor(splats.normal_offset, dtype=torch.float64),
                torch.tensor(splats.in_plane_rotation, dtype=torch.float64),
                torch.tensor(splats.in_plane_scale, dtype=torch.float64),
                pose_rotation=torch.as_tensor(rot_pose), pose_translation=torch.as_tensor(pose.translation),
                flatness=ratio,
            )  # fmt: skip
        return centre.numpy(), rot.numpy(), scales.numpy()
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_quat(splats.orientations.astype(np.float64)).as_matrix() if len(splats) else np.zeros((0, 3, 3))
    return pose.apply(splats.positions.astype(np.float64)), rot_pose @ rot, splats.scales.astype(np.float64)


@dataclass(kw_only=True)
class SplatBudget:
    """How many splats a node gets, from its observed surface area and pixel footprint."""

    count: int
    """Splats chosen (after clamping)."""
    desired: float
    """Unclamped count: observed area / (spacing x footprint)^2 summed over the surface."""
    observed_area: float
    """Surface area seen by at least one camera (in front, inside the image, facing it), m^2."""
    total_area: float
    """Total surface area of the mesh, m^2."""
    footprint_median: float
    """Median over the observed surface of the finest pixel footprint depth / focal, metres per pixel."""
    candidates: np.ndarray
    """[M, 4] surface samples (face index, then barycentric w0..w2) the splats are drawn from."""
    density: np.ndarray
    """[M] desired splat density at each candidate, splats / m^2 (0 where unobserved)."""


def splat_budget(
    mesh: MeshData,
    pose: Pose,
    cameras: list[Camera],
    *,
    spacing_px: float = 2.0,
    min_splats: int = 64,
    max_splats: int = 50_000,
    footprint_range: tuple[float, float] = (1e-4, 0.2),
    candidates: int = 100_000,
    seed: int = 0,
) -> SplatBudget:
    """Number of splats for a node: sum over its observed surface of area / (spacing_px x footprint)^2.

    The footprint of a surface point is depth / focal (metres per pixel) in the closest camera that sees it
    (in front of the camera, inside the image, front-facing; occlusion is not tested), clamped to
    ``footprint_range``. The surface is sampled with ``candidates`` uniform points.

    Args:
        mesh: Node mesh, object coordinates.
        pose: Node pose.
        cameras: Observing cameras.
        spacing_px: Splat spacing on screen, pixels (2 = one splat per 2 x 2 pixels at the closest view).
        min_splats: Lower clamp of the count (also used when nothing is observed).
        max_splats: Upper clamp of the count.
        footprint_range: Clamp of the footprint, metres per pixel.
        candidates: Surface samples used to integrate the density.
        seed: Seed of the surface sampling.
    """
    if spacing_px <= 0 or min_splats < 1 or max_splats < min_splats:
        raise InvalidDataError(
            f"splat_budget: need spacing_px > 0 and 1 <= min_splats <= max_splats, got {spacing_px}, "
            f"{min_splats}, {max_splats}"
        )
    rng = np.random.default_rng(seed)
    tri, _, _, normal = _face_frames_np(mesh)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    face = rng.choice(len(area), size=candidates, p=area / area.sum())
    u, v = rng.random(candidates), rng.random(candidates)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    bary = np.stack([1 - u - v, u, v], axis=1)  # [M, 3]
    world = pose.apply(np.einsum("mk,mkj->mj", bary, tri[face]))  # [M, 3]
    world_n = normal[face] @ pose.rotation_matrix().T
    footprint = np.full(candidates, np.inf)
    for cam in cameras:
        uv, z = cam.project(world)
        facing = np.einsum("mj,mj->m", world_n, cam.center - world) > 0
        inside = (
            (z > 1e-3) & facing & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        )
        fp = np.where(inside, z / np.sqrt(cam.fx * cam.fy), np.inf)
        footprint = np.minimum(footprint, fp)
    seen = np.isfinite(footprint)
    footprint = np.where(seen, np.clip(footprint, *footprint_range), np.inf)
    density = np.where(seen, 1.0 / (spacing_px * footprint) ** 2, 0.0)  # splats / m^2
    total = float(area.sum())
    desired = float(total * density.mean())
    count = int(np.clip(round(desired), min_splats, max_splats))
    return SplatBudget(
        count=count, desired=desired, observed_area=float(total * seen.mean()), total_area=total,
        footprint_median=float(np.median(footprint[seen])) if seen.any() else float("nan"),
        candidates=np.c_[face, bary], density=density,
    )  # fmt: skip


def initial_bound_splats(
    mesh: MeshData,
    budget: SplatBudget,
    *,
    color: np.ndarray | tuple[float, float, float] = (0.5, 0.5, 0.5),
    opacity: float = 0.9,
    scale_factor: float = 0.6,
    flatness: float = FLATNESS,
    seed: int = 0,
) -> GaussianSplats:
    """Draw ``budget.count`` splats from the budget's candidates with probability proportional to density.

    In-plane standard deviations are ``scale_factor`` times the local spacing (1 / sqrt(density) after
    scaling to the chosen count); rotations are random; colours are ``color`` (one RGB, or [N, 3]).
    When nothing was observed, splats are spread uniformly.
    """
    rng = np.random.default_rng(seed)
    weights = budget.density.copy()
    if weights.sum() <= 0:
        weights = np.ones_like(weights)
    pick = rng.choice(len(weights), size=budget.count, replace=budget.count > int((weights > 0).sum()),
                      p=weights / weights.sum())  # fmt: skip
    cand = budget.candidates[pick]
    face, bary = cand[:, 0].astype(np.int64), cand[:, 1:]
    local_density = weights[pick] * (budget.count / max(float(weights.mean() * budget.total_area), 1e-12))
    sigma = scale_factor / np.sqrt(np.maximum(local_density, 1e-12))  # [N]
    rgb = np.broadcast_to(np.asarray(color, dtype=np.float64), (budget.count, 3))
    splats = GaussianSplats(
        positions=np.zeros((budget.count, 3)), orientations=np.tile([0.0, 0.0, 0.0, 1.0], (budget.count, 1)),
        scales=np.c_[sigma, sigma, flatness * sigma], opacities=np.full(budget.count, opacity),
        sh_coeffs=((rgb - 0.5) / SH_C0)[:, None, :], face_index=face, barycentric=bary,
        normal_offset=np.zeros(budget.count), in_plane_rotation=rng.uniform(-np.pi, np.pi, budget.count),
        in_plane_scale=np.c_[sigma, sigma],
    )  # fmt: skip
    return sync_bound_splats(splats, mesh, flatness=flatness)
