"""Differentiable volume rendering of per-instance SDF grids (VolSDF densities) in torch.

Each instance k owns a dense, axis-aligned grid in world coordinates holding its signed distance s_k (metres,
negative inside) and its colour. Densities follow VolSDF: ``sigma_k = Psi_beta(-s_k) / beta`` with the Laplace
CDF ``Psi_beta``; the ray's density is the sum over instances and the share of instance k at a sample is
``sigma_k / sum_j sigma_j``, so a ray's instance probabilities (for the mask cross-entropy) come from the same
weights as its colour and depth. Values are read by trilinear interpolation (``torch.nn.functional.grid_sample``);
SDF gradients (normals, eikonal) by central differences on the grid, interpolated the same way.

Sampling per ray: a coarse pass without gradients locates the first zero crossing of the scene SDF
(min over instances); the differentiable pass samples a band around it plus stratified samples over the
interval of the ray's labelled instance box, so a pixel whose instance is missing still pulls a surface in.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

__all__ = ["RayBatch", "RenderOutput", "SdfGridSet", "VolumeConfig", "laplace_density", "render_rays"]

_FAR = 1.0
"""SDF value (metres) returned outside an instance's grid box."""


@dataclass(kw_only=True)
class VolumeConfig:
    """Sampling and density settings of :func:`render_rays`."""

    coarse_samples: int = 48
    """Samples per ray of the gradient-free pass that finds the first surface."""
    band_samples: int = 16
    """Differentiable samples in the band around the first surface."""
    box_samples: int = 16
    """Differentiable stratified samples over the labelled instance's box interval."""
    band_voxels: float = 3.0
    """Half width of the band, in voxels of the instance hit."""
    beta_voxels: float = 0.5
    """VolSDF beta (Laplace scale) of each instance, in its voxels."""
    near: float = 0.05
    """Closest sample distance (camera z), metres."""


class SdfGridSet:
    """Per-instance SDF and colour grids as torch parameters.

    Args:
        sdf: One [X, Y, Z] float32 signed-distance grid per instance, metres.
        origins: [K, 3] world position of each grid's sample (0, 0, 0).
        voxel_sizes: [K] grid spacings, metres.
        colors: Optional [K, 3] initial colours in [0, 1].
        device: Torch device.
    """

    def __init__(
        self,
        sdf: list[np.ndarray],
        origins: np.ndarray,
        voxel_sizes: np.ndarray,
        colors: np.ndarray | None = None,
        device: str = "cpu",
    ) -> None:
        import torch

        self.device = torch.device(device)
        self.count = len(sdf)
        self.sdf = [torch.tensor(g[None, None], dtype=torch.float32, device=self.device, requires_grad=True)
                    for g in sdf]  # fmt: skip
        """K tensors [1, 1, X, Y, Z] (parameters)."""
        init = np.full((self.count, 3), 0.5) if colors is None else np.clip(colors, 0.02, 0.98)
        logit = np.log(init / (1 - init))
        self.color = [
            torch.tensor(np.broadcast_to(logit[k][:, None, None, None], (3, *g.shape))[None].copy(),
                         dtype=torch.float32, device=self.device, requires_grad=True)
            for k, g in enumerate(sdf)
        ]  # fmt: skip
        """K tensors [1, 3, X, Y, Z] colour logits (parameters)."""
        self.origins = torch.tensor(np.asarray(origins), dtype=torch.float32, device=self.device)  # [K, 3]
        self.voxel = torch.tensor(np.asarray(voxel_sizes), dtype=torch.float32, device=self.device)  # [K]
        shapes = np.array([g.shape for g in sdf], dtype=np.float64)  # [K, 3]
        self.shapes = torch.tensor(shapes, dtype=torch.float32, device=self.device)
        self.lo = self.origins  # [K, 3]
        self.hi = self.origins + self.voxel[:, None] * (self.shapes - 1)  # [K, 3]
        self._cache: list[torch.Tensor] | None = None

    def parameters(self) -> list[torch.Tensor]:
        """All trainable tensors (SDF grids, then colour grids)."""
        return [*self.sdf, *self.color]

    def gradient_grid(self, k: int) -> torch.Tensor:
        """[1, 3, X, Y, Z] central-difference gradient of instance k's SDF (differentiable)."""
        import torch

        g = self.sdf[k][0, 0]
        h = float(self.voxel[k])
        grads = []
        for axis in range(3):
            if g.shape[axis] < 2:
                grads.append(torch.zeros_like(g))
            else:
                grads.append(torch.gradient(g, spacing=h, dim=axis)[0])
        return torch.stack(grads)[None]

    def begin(self, with_gradients: bool = True) -> None:
        """Build the per-iteration feature grids (SDF, gradient, colour) used by :meth:`query`."""
        import torch

        feats = []
        for k in range(self.count):
            parts = [self.sdf[k]]
            if with_gradients:
                parts.append(self.gradient_grid(k))
            parts.append(torch.sigmoid(self.color[k]))
            feats.append(torch.cat(parts, dim=1))
        self._cache = feats

    def end(self) -> None:
        """Drop the per-iteration feature grids."""
        self._cache = None

    def _normalised(self, k: int, points: torch.Tensor) -> torch.Tensor:
        idx = (points - self.origins[k]) / self.voxel[k]  # [P, 3] voxel coordinates (x, y, z)
        norm = 2.0 * idx / (self.shapes[k] - 1).clamp(min=1) - 1.0
        return norm.flip(-1)  # grid_sample wants (W, H, D) = (z, y, x) order for a [X, Y, Z] volume

    def inside(self, k: int, points: torch.Tensor) -> torch.Tensor:
        """[P] bool: points inside instance k's grid box."""
        return ((points >= self.lo[k]) & (points <= self.hi[k])).all(-1)

    def sdf_only(self, k: int, points: torch.Tensor) -> torch.Tensor:
        """[P] SDF of instance k at [P, 3] points inside its box (reads the parameter grid directly)."""
        import torch.nn.functional as F

        grid = self._normalised(k, points)[None, :, None, None, :]  # [1, P, 1, 1, 3]
        return F.grid_sample(self.sdf[k], grid, mode="bilinear", align_corners=True).reshape(-1)

    def query(self, k: int, points: torch.Tensor) -> torch.Tensor:
        """[P, C] features of instance k at [P, 3] points inside its box: SDF, (gradient x3), colour x3."""
        import torch.nn.functional as F

        assert self._cache is not None, "call begin() first"
        feats = self._cache[k]
        grid = self._normalised(k, points)[None, :, None, None, :]  # [1, P, 1, 1, 3]
        out = F.grid_sample(feats, grid, mode="bilinear", align_corners=True)  # [1, C, P, 1, 1]
        return out[0, :, :, 0, 0].T

    def box_intervals(self, origins: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Ray / box slab test: [R, K] entry and exit parameters (t_exit < t_entry: miss)."""
        import torch

        inv = 1.0 / torch.where(dirs.abs() < 1e-9, torch.full_like(dirs, 1e-9), dirs)  # [R, 3]
        t0 = (self.lo[None] - origins[:, None]) * inv[:, None]  # [R, K, 3]
        t1 = (self.hi[None] - origins[:, None]) * inv[:, None]
        t_in = torch.minimum(t0, t1).amax(-1)
        t_out = torch.maximum(t0, t1).amin(-1)
        return t_in, t_out


@dataclass(kw_only=True)
class RayBatch:
    """Rays in world coordinates; ``t`` along ``dirs`` is the camera z-depth (directions have camera z = 1)."""

    origins: torch.Tensor
    """[R, 3] camera centres, metres."""
    dirs: torch.Tensor
    """[R, 3] directions with unit camera-z component (not unit length)."""
    labels: torch.Tensor
    """[R] long instance index of the pixel: 0 background, k + 1 for grid k."""


@dataclass(kw_only=True)
class RenderOutput:
    """Per-ray results of :func:`render_rays`."""

    probs: torch.Tensor
    """[R, K + 1] probabilities background, instance 0..K-1 (sum to 1)."""
    color: torch.Tensor
    """[R, 3] colour accumulated over instances (background contributes nothing)."""
    opacity: torch.Tensor
    """[R] accumulated weight."""
    depth: torch.Tensor
    """[R] expected camera z-depth of the surface (weights normalised by the opacity), metres."""
    normal: torch.Tensor | None
    """[R, 3] accumulated world normal, or None without gradients."""
    samples: torch.Tensor
    """[R, S] sample depths used."""


def laplace_density(sdf: torch.Tensor, beta: torch.Tensor) -> torch.Tensor:
    """VolSDF density ``Psi_beta(-sdf) / beta`` (Laplace CDF with zero mean and scale ``beta``)."""
    import torch

    x = -sdf / beta
    psi = torch.where(x <= 0, 0.5 * torch.exp(x.clamp(max=0.0)), 1.0 - 0.5 * torch.exp(-x.clamp(min=0.0)))
    return psi / beta


def _evaluate(grids: SdfGridSet, points: torch.Tensor, features: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
    """SDF [P, K] of every instance at [P, 3] points (``_FAR`` outside a box) and features [P, K, C] or None."""
    import torch

    n = points.shape[0]
    sdf_cols = []
    feat_cols = []
    for k in range(grids.count):
        inside = grids.inside(k, points)
        idx = inside.nonzero().squeeze(1)
        if features:
            col_feat = torch.zeros(n, 7 if grids._cache[k].shape[1] == 7 else 4, device=points.device)  # type: ignore[index]
            if idx.numel():
                col_feat = col_feat.index_put((idx,), grids.query(k, points[idx]))
            col = torch.full((n,), _FAR, device=points.device).index_put((idx,), col_feat[idx, 0])
            feat_cols.append(col_feat)
        else:
            col = torch.full((n,), _FAR, device=points.device)
            if idx.numel():
                col = col.index_put((idx,), grids.sdf_only(k, points[idx]))
        sdf_cols.append(col)
    sdf = torch.stack(sdf_cols, dim=1)  # [P, K]
    return sdf, (torch.stack(feat_cols, dim=1) if features else None)


def render_rays(
    grids: SdfGridSet, rays: RayBatch, config: VolumeConfig, generator: torch.Generator | None = None
) -> RenderOutput:
    """Volume-render a batch of rays through the instance grids (call ``grids.begin()`` first).

    Args:
        grids: The instance grids.
        rays: Rays (``labels`` choose where the stratified samples go).
        config: Sampling settings.
        generator: Seeded generator for the stratified jitter.
    """
    import torch

    device = rays.origins.device
    r = rays.origins.shape[0]
    k_count = grids.count
    t_in, t_out = grids.box_intervals(rays.origins, rays.dirs)  # [R, K]
    hit = t_out > torch.maximum(t_in, torch.full_like(t_in, config.near))
    t_in = t_in.clamp(min=config.near)
    big = torch.full_like(t_in, 1e9)
    t_lo = torch.where(hit, t_in, big).amin(1)  # [R]
    t_hi = torch.where(hit, t_out, -big).amax(1)
    any_hit = hit.any(1)
    t_lo = torch.where(any_hit, t_lo, torch.full_like(t_lo, config.near))
    t_hi = torch.where(any_hit, t_hi, t_lo + 1e-3)
    ray_len = rays.dirs.norm(dim=-1)  # [R] metres per unit of t
    voxel_hit = torch.where(hit, grids.voxel[None].expand(r, -1), torch.zeros_like(t_in)).amax(1)  # [R]

    # --- coarse pass: first zero crossing of the scene SDF
    with torch.no_grad():
        steps = torch.linspace(0.0, 1.0, config.coarse_samples, device=device)
        tc = t_lo[:, None] + (t_hi - t_lo)[:, None] * steps[None]  # [R, Sc]
        pts = rays.origins[:, None] + tc[..., None] * rays.dirs[:, None]  # [R, Sc, 3]
        sdf_c, _ = _evaluate(grids, pts.reshape(-1, 3), features=False)
        scene_c = sdf_c.amin(1).reshape(r, -1)  # [R, Sc]
        neg = scene_c < 0
        first = torch.where(neg.any(1), neg.float().argmax(1), torch.full((r,), -1, device=device))
        prev = (first - 1).clamp(min=0)
        s0 = scene_c.gather(1, prev[:, None])[:, 0]
        s1 = scene_c.gather(1, first.clamp(min=0)[:, None])[:, 0]
        ta, tb = tc.gather(1, prev[:, None])[:, 0], tc.gather(1, first.clamp(min=0)[:, None])[:, 0]
        frac = (s0 / (s0 - s1).clamp(min=1e-9)).clamp(0, 1)
        t_hit = torch.where(first > 0, ta + frac * (tb - ta), tb)
        has_surface = first >= 0

        # stratified samples: labelled instance's box interval (or the whole interval for background rays)
        lab = rays.labels
        k_idx = (lab - 1).clamp(min=0)
        own_in = t_in.gather(1, k_idx[:, None])[:, 0]
        own_out = t_out.gather(1, k_idx[:, None])[:, 0]
        use_own = (lab > 0) & hit.gather(1, k_idx[:, None])[:, 0]
        u_lo = torch.where(use_own, own_in, t_lo)
        u_hi = torch.where(use_own, own_out, t_hi)
        nb = config.box_samples
        jitter = torch.rand(r, nb, generator=generator, device=device)
        tu = u_lo[:, None] + (u_hi - u_lo)[:, None] * (torch.arange(nb, device=device)[None] + jitter) / nb
        half = config.band_voxels * voxel_hit
        centre = torch.where(has_surface, t_hit, 0.5 * (u_lo + u_hi))
        half = torch.where(has_surface, half / ray_len.clamp(min=1e-6), 0.5 * (u_hi - u_lo))
        nband = config.band_samples
        jitter_b = torch.rand(r, nband, generator=generator, device=device)
        tb_s = centre[:, None] + half[:, None] * (2 * (torch.arange(nband, device=device)[None] + jitter_b) / nband - 1)
        t_samples = torch.cat([tu, tb_s], dim=1).clamp(min=config.near)
        t_samples, _ = torch.sort(t_samples, dim=1)  # [R, S]

    s_count = t_samples.shape[1]
    pts = rays.origins[:, None] + t_samples[..., None] * rays.dirs[:, None]  # [R, S, 3]
    sdf, feats = _evaluate(grids, pts.reshape(-1, 3), features=True)
    sdf = sdf.reshape(r, s_count, k_count)  # [R, S, K]
    assert feats is not None
    feats = feats.reshape(r, s_count, k_count, -1)  # [R, S, K, C]
    beta = (config.beta_voxels * grids.voxel).clamp(min=1e-4)  # [K]
    sigma_k = laplace_density(sdf, beta[None, None])  # [R, S, K]
    sigma = sigma_k.sum(-1)  # [R, S]
    delta = torch.diff(t_samples, dim=1, append=t_samples[:, -1:] + (t_samples[:, -1:] - t_samples[:, -2:-1]))
    delta = delta * ray_len[:, None]  # metres
    alpha = 1.0 - torch.exp(-sigma * delta)
    trans = torch.cumprod(torch.cat([torch.ones(r, 1, device=device), 1.0 - alpha + 1e-7], dim=1), dim=1)[:, :-1]
    weights = trans * alpha  # [R, S]
    share = sigma_k / sigma.clamp(min=1e-8)[..., None]  # [R, S, K]
    inst = (weights[..., None] * share).sum(1)  # [R, K]
    opacity = weights.sum(1)  # [R]
    probs = torch.cat([(1.0 - opacity).clamp(min=1e-6)[:, None], inst.clamp(min=1e-6)], dim=1)
    color_s = (share[..., None] * feats[..., -3:]).sum(2)  # [R, S, 3]
    color = (weights[..., None] * color_s).sum(1)
    depth = (weights * t_samples).sum(1) / opacity.clamp(min=1e-6)
    normal = None
    if feats.shape[-1] == 7:
        normal_s = (share[..., None] * feats[..., 1:4]).sum(2)  # [R, S, 3]
        normal = (weights[..., None] * normal_s).sum(1)
    return RenderOutput(probs=probs, color=color, opacity=opacity, depth=depth, normal=normal, samples=t_samples)
