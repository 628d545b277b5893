"""Fitting Gaussians-on-mesh to observed frames: L1 + D-SSIM (+ mask) with Adam, as in 3DGS.

Optimised per splat: colour (SH degree 0 only: view-independent radiance), opacity, in-plane scales and
rotation, barycentric position (kept on its face by clamping and renormalising after each step) and normal
offset (clamped). The splat count is fixed by :func:`splat_budget` (no densification or pruning).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from holousd._errors import InvalidDataError
from holousd.render._binding import SH_C0, bound_gaussians, splats_in_world, sync_bound_splats
from holousd.render._frames import Frame
from holousd.render._rasterize import RasterConfig, covariances_from_rotations, rasterize
from holousd.usd import GaussianSplats, MeshData, Pose

if TYPE_CHECKING:
    import torch

__all__ = ["FitConfig", "FitNode", "FitResult", "colors_from_frames", "fit_bound_splats"]


@dataclass(kw_only=True)
class FitConfig:
    """Settings of the appearance fit."""

    iterations: int = 500
    """Adam steps; each step renders one observed frame (cycling through them in a shuffled order)."""
    lambda_dssim: float = 0.2
    """Weight of D-SSIM = (1 - SSIM) against L1 (3DGS: 0.2)."""
    mask_weight: float = 0.1
    """Weight of the mask term: L1 between rendered alpha (or per-object accumulated weight) and the mask."""
    lr_color: float = 0.02
    """Adam step of the SH degree-0 coefficients (colour = 0.5 + 0.282 x coefficient)."""
    lr_opacity: float = 0.05
    """Adam step of the opacity logits."""
    lr_scale: float = 0.01
    """Adam step of the log in-plane standard deviations."""
    lr_rotation: float = 0.02
    """Adam step of the in-plane rotations, radians."""
    lr_barycentric: float = 5e-4
    """Adam step of the barycentric coordinates (re-projected onto the face after each step)."""
    lr_offset: float = 1e-4
    """Adam step of the normal offsets, metres."""
    max_normal_offset: float = 0.005
    """Clamp of |normal offset|, metres."""
    max_scale: float = 0.25
    """Upper clamp of the in-plane standard deviations, metres."""
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Colour behind all splats (where nothing covers a pixel), RGB in [0, 1]."""
    raster: RasterConfig = field(default_factory=RasterConfig)
    """Rasteriser settings."""
    seed: int = 0
    """Seed of the frame order."""
    device: str = "cpu"
    """Torch device."""
    progress: bool = False
    """Show a tqdm progress bar on stderr."""


@dataclass(kw_only=True)
class FitNode:
    """One node taking part in a fit."""

    name: str
    """Node name."""
    mesh: MeshData
    """Its mesh (object coordinates)."""
    pose: Pose
    """Its world pose during the observations."""
    splats: GaussianSplats
    """Its splats: bound to ``mesh`` when trainable; any splats when frozen."""
    instance_id: int | None = None
    """Instance id in instance masks (None: no per-object mask term)."""
    trainable: bool = True
    """Optimise this node (False: render it as it is, e.g. as an occluder)."""


@dataclass(kw_only=True)
class FitResult:
    """What :func:`fit_bound_splats` returns."""

    splats: dict[str, GaussianSplats]
    """Fitted splats of the trainable nodes (SH degree 0), keyed by node name."""
    iterations: int
    """Adam steps taken."""
    seconds: float
    """Wall time of the optimisation, seconds."""
    loss_history: list[float]
    """Loss of every step."""
    train_psnr: float
    """PSNR over the last pass of steps (one per frame, at most the last len(frames) steps), dB."""


def colors_from_frames(points: np.ndarray, normals: np.ndarray, frames: list[Frame]) -> np.ndarray:
    """Median observed colour of world points over the frames that see them (facing, in the image).

    Occlusion is not tested; the median over views keeps occluded views from dominating. Points never seen
    get the mean image colour. Returns [N, 3].
    """
    samples = np.full((len(frames), len(points), 3), np.nan, dtype=np.float32)
    for i, frame in enumerate(frames):
        cam = frame.camera
        uv, z = cam.project(points)
        facing = np.einsum("nj,nj->n", normals, cam.center - points) > 0
        col = np.floor(uv[:, 0]).astype(np.int64, copy=False) if len(points) else np.zeros(0, np.int64)
        row = np.floor(uv[:, 1]).astype(np.int64, copy=False) if len(points) else np.zeros(0, np.int64)
        ok = (z > 1e-3) & facing & (col >= 0) & (col < cam.width) & (row >= 0) & (row < cam.height)
        samples[i, ok] = frame.image[row[ok], col[ok]]
    seen = ~np.isnan(samples[..., 0]).all(axis=0)
    out = np.empty((len(points), 3), dtype=np.float32)
    out[:] = np.mean([f.image.reshape(-1, 3).mean(0) for f in frames], axis=0)
    if seen.any():
        out[seen] = np.nanmedian(samples[:, seen], axis=0)
    return out


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, 1e-4, 1 - 1e-4)
    return np.log(p / (1 - p))


class _Trainable:
    """Torch parameters of one trainable node."""

    def __init__(self, node: FitNode, dtype: torch.dtype, device: str) -> None:
        import torch

        s = node.splats
        if not s.bound:
            raise InvalidDataError(f"node {node.name!r}: only splats bound to the mesh can be fitted")
        if len(s) and (s.face_index.max() >= len(node.mesh.faces) or s.face_index.min() < 0):
            raise InvalidDataError(
                f"node {node.name!r}: splat face_index outside the mesh's {len(node.mesh.faces)} faces"
            )

        def t(x: np.ndarray, grad: bool = True) -> torch.Tensor:
            return torch.tensor(np.asarray(x), dtype=dtype, device=device, requires_grad=grad)

        self.name = node.name
        self.points = torch.as_tensor(node.mesh.points, dtype=dtype, device=device)
        self.faces = torch.as_tensor(node.mesh.faces, dtype=torch.int64, device=device)
        self.face_index = torch.as_tensor(s.face_index.astype(np.int64), device=device)
        self.rot = torch.as_tensor(node.pose.rotation_matrix(), dtype=dtype, device=device)
        self.trans = torch.as_tensor(node.pose.translation, dtype=dtype, device=device)
        big = np.maximum(s.in_plane_scale.max(axis=1), 1e-12)
        self.flatness = float(np.median(s.scales[:, 2] / big)) if len(s) else 1e-3
        self.sh_dc = t(s.sh_coeffs[:, 0, :])  # [N, 3]
        self.opacity = t(_logit(s.opacities))  # [N]
        self.log_scale = t(np.log(np.maximum(s.in_plane_scale, 1e-6)))  # [N, 2]
        self.theta = t(s.in_plane_rotation)  # [N]
        self.bary = t(s.barycentric)  # [N, 3]
        self.offset = t(s.normal_offset)  # [N]
        self.source = s

    def gaussians(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """World means [N, 3], covariances [N, 3, 3], opacities [N], colours [N, 3]."""
        import torch

        centre, rot, scales = bound_gaussians(
            self.points, self.faces, self.face_index, self.bary, self.offset, self.theta, torch.exp(self.log_scale),
            pose_rotation=self.rot, pose_translation=self.trans, flatness=self.flatness,
        )  # fmt: skip
        color = (0.5 + SH_C0 * self.sh_dc).clamp_min(0.0)
        return centre, covariances_from_rotations(rot, scales), torch.sigmoid(self.opacity), color

    def groups(self, config: FitConfig) -> list[dict]:
        return [
            {"params": [self.sh_dc], "lr": config.lr_color},
            {"params": [self.opacity], "lr": config.lr_opacity},
            {"params": [self.log_scale], "lr": config.lr_scale},
            {"params": [self.theta], "lr": config.lr_rotation},
            {"params": [self.bary], "lr": config.lr_barycentric},
            {"params": [self.offset], "lr": config.lr_offset},
        ]

    def project_constraints(self, config: FitConfig) -> None:
        """Keep splats on their face, offsets and scales in range (in place, no gradient)."""
        self.bary.clamp_(min=0.0)
        self.bary.div_(self.bary.sum(1, keepdim=True).clamp_min(1e-12))
        self.offset.clamp_(-config.max_normal_offset, config.max_normal_offset)
        self.log_scale.clamp_(max=float(np.log(config.max_scale)))

    def result(self) -> GaussianSplats:
        import torch

        with torch.no_grad():

            def n(x: torch.Tensor) -> np.ndarray:
                return x.detach().cpu().numpy().astype(np.float64)

            splats = GaussianSplats(
                positions=self.source.positions, orientations=self.source.orientations, scales=self.source.scales,
                opacities=n(torch.sigmoid(self.opacity)), sh_coeffs=n(self.sh_dc)[:, None, :],
                face_index=self.source.face_index, barycentric=n(self.bary), normal_offset=n(self.offset),
                in_plane_rotation=n(self.theta), in_plane_scale=n(torch.exp(self.log_scale)),
            )  # fmt: skip
        mesh = MeshData(points=self.points.cpu().numpy(), faces=self.faces.cpu().numpy())
        return sync_bound_splats(splats, mesh, flatness=self.flatness)


def _frozen_gaussians(node: FitNode, dtype: torch.dtype, device: str) -> tuple[torch.Tensor, ...]:
    import torch

    centre, rot, scales = splats_in_world(node.splats, node.pose, node.mesh)
    as_t = lambda x: torch.as_tensor(np.asarray(x), dtype=dtype, device=device)  # noqa: E731
    color = np.clip(0.5 + SH_C0 * node.splats.sh_coeffs[:, 0, :], 0.0, None)
    return as_t(centre), covariances_from_rotations(as_t(rot), as_t(scales)), as_t(node.splats.opacities), as_t(color)


def fit_bound_splats(nodes: list[FitNode], frames: list[Frame], config: FitConfig | None = None) -> FitResult:
    """Fit the trainable nodes' bound splats to ``frames`` jointly (occlusion between nodes included).

    Loss per step: (1 - lambda) L1 + lambda (1 - SSIM) on RGB, plus ``mask_weight`` x L1 between the rendered
    alpha and a foreground mask, or between each node's accumulated weight and its instance mask.
    """
    import torch

    from holousd.render._ssim import ssim_torch

    config = config or FitConfig()
    if not frames:
        raise InvalidDataError("fit_bound_splats: no frames given")
    if not any(n.trainable for n in nodes):
        raise InvalidDataError("fit_bound_splats: no trainable node")
    if config.iterations < 1:
        raise InvalidDataError(f"FitConfig.iterations must be >= 1, got {config.iterations}")
    dtype, device = torch.float32, config.device
    trainables = [_Trainable(n, dtype, device) for n in nodes if n.trainable]
    frozen = [_frozen_gaussians(n, dtype, device) for n in nodes if not n.trainable and len(n.splats)]
    # node channel index per splat for instance-mask terms
    masked_nodes = [n for n in nodes if n.instance_id is not None]
    use_instances = bool(masked_nodes) and any(f.instance_mask for f in frames) and config.mask_weight > 0
    sizes = [len(t.source) for t in trainables] + [len(f[0]) for f in frozen]
    order_names = [t.name for t in trainables] + [n.name for n in nodes if not n.trainable and len(n.splats)]
    onehot = None
    if use_instances:
        channel = {n.name: i for i, n in enumerate(masked_nodes)}
        onehot = torch.zeros(sum(sizes), len(masked_nodes), dtype=dtype, device=device)
        start = 0
        for name, size in zip(order_names, sizes, strict=True):
            if name in channel:
                onehot[start : start + size, channel[name]] = 1.0
            start += size
    images = [torch.as_tensor(f.image, dtype=dtype, device=device) for f in frames]
    background = torch.as_tensor(config.background, dtype=dtype, device=device)
    groups = [g for t in trainables for g in t.groups(config)]
    optim = torch.optim.Adam(groups, eps=1e-15)
    rng = np.random.default_rng(config.seed)
    history: list[float] = []
    sq_errors: list[float] = []
    order = np.array([], dtype=np.int64)
    bar = None
    if config.progress:
        from tqdm import tqdm

        bar = tqdm(total=config.iterations, desc="fit appearance", unit="step", leave=False)
    started = time.perf_counter()
    for _ in range(config.iterations):
        if len(order) == 0:
            order = rng.permutation(len(frames))
        fi, order = int(order[0]), order[1:]
        frame, target = frames[fi], images[fi]
        parts = [t.gaussians() for t in trainables] + frozen
        means = torch.cat([p[0] for p in parts])
        covs = torch.cat([p[1] for p in parts])
        opac = torch.cat([p[2] for p in parts])
        color = torch.cat([p[3] for p in parts])
        if onehot is not None:
            color = torch.cat([color, onehot], dim=1)
            bg = torch.cat([background, torch.zeros(onehot.shape[1], dtype=dtype, device=device)])
        else:
            bg = background
        out = rasterize(means, covs, opac, color, frame.camera, config.raster, background=bg)
        rgb = out.color[..., :3]
        l1 = (rgb - target).abs().mean()
        loss = (1 - config.lambda_dssim) * l1 + config.lambda_dssim * (1 - ssim_torch(rgb, target))
        if frame.mask is not None and config.mask_weight > 0:
            if frame.instance_mask and onehot is not None:
                ids = torch.as_tensor([n.instance_id for n in masked_nodes], device=device)
                want = (torch.as_tensor(frame.mask, device=device)[..., None] == ids).to(dtype)
                loss = loss + config.mask_weight * (out.color[..., 3:] - want).abs().mean()
            elif not frame.instance_mask:
                want = torch.as_tensor(frame.mask, dtype=dtype, device=device)
                loss = loss + config.mask_weight * (out.alpha - want).abs().mean()
        optim.zero_grad(set_to_none=True)
        loss.backward()
        optim.step()
        with torch.no_grad():
            for t in trainables:
                t.project_constraints(config)
        history.append(float(loss.detach()))
        sq_errors.append(float(((rgb.detach() - target) ** 2).mean()))
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{history[-1]:.4f}")
    if bar is not None:
        bar.close()
    seconds = time.perf_counter() - started
    last = sq_errors[-min(len(frames), len(sq_errors)) :]
    mse = float(np.mean(last))
    return FitResult(
        splats={t.name: t.result() for t in trainables}, iterations=config.iterations, seconds=seconds,
        loss_history=history, train_psnr=float("inf") if mse == 0 else float(-10 * np.log10(mse)),
    )  # fmt: skip
