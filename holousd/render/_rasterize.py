"""Differentiable 3D Gaussian splatting rasteriser on the CPU (torch), after Kerbl et al. 2023 (3DGS).

Pipeline (every step is a torch op, so gradients flow to means, covariances, opacities and colours):

1. World -> camera (OpenCV axes); Gaussians behind the near plane are culled.
2. EWA splatting: the 3D covariance Sigma = R S S^T R^T is mapped to the image by the Jacobian J of the
   perspective projection at the Gaussian's centre, Sigma_2d = J W Sigma W^T J^T + 0.3 I (the 0.3 px^2 low-pass
   dilation of 3DGS).
3. Support: a Gaussian contributes to a pixel where its Mahalanobis distance is <= ``sigma_cutoff`` (3) and
   its alpha >= 1/255; the axis-aligned box of that ellipse is its footprint.
4. Tiling: the image is cut into square tiles; every (tile, Gaussian) pair whose footprint touches the tile is
   packed into one list, sorted by (tile, depth of the centre).
5. Compositing: for all pairs at once, alpha is evaluated at the tile's pixels ([pairs, tile_px]); front-to-back
   transmittance T_i = prod_{j<i} (1 - alpha_j) is a per-tile exclusive cumulative sum of log(1 - alpha)
   (float64), and colour, alpha and depth are summed per tile with weights alpha_i T_i.

:func:`rasterize_reference` is the brute-force definition (every Gaussian on every pixel) used by the tests.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from holousd._errors import InvalidDataError
from holousd.render._camera import Camera

if TYPE_CHECKING:
    import torch

__all__ = [
    "RasterConfig",
    "RenderResult",
    "covariances_from_quats",
    "covariances_from_rotations",
    "rasterize",
    "rasterize_reference",
]


@dataclass(kw_only=True)
class RasterConfig:
    """Settings of the Gaussian rasteriser."""

    tile_size: int = 8
    """Tile edge, pixels (8 is fastest on CPU for footprints of a few pixels; 16 as in 3DGS also works)."""
    near: float = 0.01
    """Near plane, metres: Gaussians whose centre is closer (camera z) are culled."""
    dilation: float = 0.3
    """Low-pass filter added to the diagonal of every 2D covariance, pixels^2 (3DGS: 0.3)."""
    sigma_cutoff: float = 3.0
    """Support of a Gaussian in Mahalanobis distance (standard deviations)."""
    min_alpha: float = 1.0 / 255.0
    """Contributions with a smaller alpha are dropped (3DGS: 1/255)."""
    max_alpha: float = 0.99
    """Alpha is clamped to this value so that 1 - alpha stays positive (3DGS: 0.99)."""
    max_chunk_elements: int = 16_000_000
    """Upper bound on pairs x tile pixels evaluated at once (memory of the forward pass), elements."""


@dataclass(kw_only=True)
class RenderResult:
    """Output of :func:`rasterize` (tensors on the input's device and dtype)."""

    color: torch.Tensor
    """[H, W, C] composited colour (over ``background`` where given)."""
    alpha: torch.Tensor
    """[H, W] accumulated opacity in [0, 1]."""
    depth: torch.Tensor
    """[H, W] expected depth of the visible splats (camera z, metres); 0 where alpha is 0."""
    pairs: int
    """Number of (tile, Gaussian) pairs composited."""
    visible: int
    """Number of Gaussians with a non-empty footprint."""


def covariances_from_rotations(rotations: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """Return [N, 3, 3] covariances R diag(s^2) R^T from [N, 3, 3] rotations and [N, 3] standard deviations."""
    scaled = rotations * scales[:, None, :]  # [N, 3, 3] columns scaled
    return scaled @ scaled.transpose(1, 2)


def quats_to_rotations(quats: torch.Tensor) -> torch.Tensor:
    """Return [N, 3, 3] rotation matrices of [N, 4] quaternions (x, y, z, w), normalised first."""
    import torch

    q = quats / quats.norm(dim=1, keepdim=True).clamp_min(1e-12)
    x, y, z, w = q.unbind(1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        dim=1,
    ).reshape(-1, 3, 3)  # fmt: skip


def covariances_from_quats(quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """Return [N, 3, 3] covariances from [N, 4] quaternions (x, y, z, w) and [N, 3] standard deviations."""
    return covariances_from_rotations(quats_to_rotations(quats), scales)


@dataclass
class _Projected:
    """Per-Gaussian screen-space quantities (only Gaussians in front of the near plane)."""

    index: torch.Tensor  # [M] index into the input arrays
    mean2d: torch.Tensor  # [M, 2] pixel coordinates of the centre
    conic: torch.Tensor  # [M, 3] inverse 2D covariance (a, b, c) of [[a, b], [b, c]]
    cov2d: torch.Tensor  # [M, 3] 2D covariance (xx, xy, yy)
    depth: torch.Tensor  # [M] camera z, metres


def _check_inputs(means, covariances, opacities, colors) -> None:  # noqa: ANN001
    n = means.shape[0]
    if means.ndim != 2 or means.shape[1] != 3:
        raise InvalidDataError(f"rasterize: means must be [N, 3], got {list(means.shape)}")
    if covariances.shape != (n, 3, 3):
        raise InvalidDataError(f"rasterize: covariances must be [{n}, 3, 3], got {list(covariances.shape)}")
    if opacities.shape != (n,):
        raise InvalidDataError(f"rasterize: opacities must be [{n}], got {list(opacities.shape)}")
    if colors.ndim != 2 or colors.shape[0] != n:
        raise InvalidDataError(f"rasterize: colors must be [{n}, C], got {list(colors.shape)}")


def _project(means, covariances, camera: Camera, config: RasterConfig) -> _Projected:  # noqa: ANN001
    """World -> camera -> EWA 2D covariance and conic, culling Gaussians behind the near plane."""
    import torch

    w2c = torch.as_tensor(camera.world_to_cam, dtype=means.dtype, device=means.device)
    rot, trans = w2c[:3, :3], w2c[:3, 3]
    cam = means @ rot.T + trans  # [N, 3]
    keep = torch.nonzero(cam[:, 2] > config.near).squeeze(1)
    cam = cam[keep]
    cov_cam = rot @ covariances[keep] @ rot.T  # [M, 3, 3]
    x, y, z = cam.unbind(1)
    # clamp the point used for the Jacobian to 15% outside the image, as 3DGS does, so that the linearisation of
    # far-off-screen Gaussians stays bounded
    lo_x, hi_x = (-0.15 * camera.width - camera.cx) / camera.fx, (1.15 * camera.width - camera.cx) / camera.fx
    lo_y, hi_y = (-0.15 * camera.height - camera.cy) / camera.fy, (1.15 * camera.height - camera.cy) / camera.fy
    tx = (x / z).clamp(lo_x, hi_x) * z
    ty = (y / z).clamp(lo_y, hi_y) * z
    zeros = torch.zeros_like(z)
    jac = torch.stack(
        [camera.fx / z, zeros, -camera.fx * tx / (z * z), zeros, camera.fy / z, -camera.fy * ty / (z * z)], dim=1
    ).reshape(-1, 2, 3)  # [M, 2, 3]
    cov2 = jac @ cov_cam @ jac.transpose(1, 2)  # [M, 2, 2]
    a = cov2[:, 0, 0] + config.dilation
    b = cov2[:, 0, 1]
    c = cov2[:, 1, 1] + config.dilation
    det = (a * c - b * b).clamp_min(1e-12)
    conic = torch.stack([c / det, -b / det, a / det], dim=1)  # [M, 3]
    mean2d = torch.stack([camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy], dim=1)  # [M, 2]
    return _Projected(index=keep, mean2d=mean2d, conic=conic, cov2d=torch.stack([a, b, c], dim=1), depth=z)


def _power_threshold(opacities, config: RasterConfig):  # noqa: ANN001, ANN202
    """[N] smallest exponent (-0.5 Mahalanobis^2) at which a Gaussian still contributes.

    A pixel counts when it lies within ``sigma_cutoff`` standard deviations and its alpha is >= ``min_alpha``:
    power >= max(-0.5 cutoff^2, log(min_alpha / opacity)).
    """
    import torch

    return torch.clamp(torch.log(config.min_alpha / opacities.clamp_min(1e-30)), min=-0.5 * config.sigma_cutoff**2)


def _alpha(power, opacity, threshold, config: RasterConfig):  # noqa: ANN001, ANN202
    """Alpha from the Gaussian exponent ``power`` (= -0.5 d^T conic d) with cut-offs, differentiable."""
    import torch

    masked = torch.where(power >= threshold, power, torch.full_like(power, -torch.inf))
    return (opacity * torch.exp(masked)).clamp(max=config.max_alpha)


def _validate(camera: Camera, config: RasterConfig, background, channels: int) -> None:  # noqa: ANN001
    if not isinstance(camera, Camera):
        raise InvalidDataError(f"rasterize: camera must be a holousd.render.Camera, got {type(camera).__name__}")
    if config.tile_size < 1:
        raise InvalidDataError(f"RasterConfig.tile_size must be >= 1, got {config.tile_size}")
    if background is not None and tuple(background.shape) != (channels,):
        raise InvalidDataError(f"rasterize: background must be [{channels}], got {list(background.shape)}")


def rasterize(
    means: torch.Tensor,
    covariances: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    camera: Camera,
    config: RasterConfig | None = None,
    *,
    background: torch.Tensor | None = None,
) -> RenderResult:
    """Render Gaussians into ``camera`` with tiled, depth-sorted front-to-back alpha compositing.

    Args:
        means: [N, 3] centres in world coordinates, metres.
        covariances: [N, 3, 3] world covariances, metres^2 (see :func:`covariances_from_quats`).
        opacities: [N] opacities in [0, 1].
        colors: [N, C] per-Gaussian features composited like colour (RGB, or RGB plus extra channels).
        camera: The camera (OpenCV convention).
        config: Rasteriser settings (defaults: :class:`RasterConfig`).
        background: [C] colour behind the splats (default: none, i.e. black with alpha < 1).

    Returns:
        A :class:`RenderResult`; everything is differentiable with respect to all four inputs.
    """
    import torch

    config = config or RasterConfig()
    _check_inputs(means, covariances, opacities, colors)
    _validate(camera, config, background, colors.shape[1])
    dtype, device = means.dtype, means.device
    ts = config.tile_size
    width, height = camera.width, camera.height
    tiles_x, tiles_y = -(-width // ts), -(-height // ts)
    n_tiles, tile_px = tiles_x * tiles_y, ts * ts
    channels = colors.shape[1]

    proj = _project(means, covariances, camera, config)
    opac = opacities[proj.index]  # [M]
    threshold = _power_threshold(opac.detach(), config)  # [M]
    r2 = -2.0 * threshold  # [M] squared Mahalanobis radius of the support
    with torch.no_grad():
        u, v = proj.mean2d.detach().unbind(1)
        ext_x = torch.sqrt(r2.clamp_min(0) * proj.cov2d[:, 0].detach()) + 1e-3  # [M] half-width of the footprint
        ext_y = torch.sqrt(r2.clamp_min(0) * proj.cov2d[:, 2].detach()) + 1e-3
        x_lo = torch.ceil(u - ext_x - 0.5).clamp(0, width - 1)  # first / last pixel whose centre is inside
        x_hi = torch.floor(u + ext_x - 0.5)
        y_lo = torch.ceil(v - ext_y - 0.5).clamp(0, height - 1)
        y_hi = torch.floor(v + ext_y - 0.5)
        on_screen = (
            (opac.detach() > config.min_alpha) & (u + ext_x - 0.5 >= 0) & (u - ext_x - 0.5 <= width - 1)
            & (v + ext_y - 0.5 >= 0) & (v - ext_y - 0.5 <= height - 1) & (x_hi >= x_lo) & (y_hi >= y_lo)
        )  # fmt: skip
        x_hi, y_hi = x_hi.clamp(0, width - 1), y_hi.clamp(0, height - 1)
        tx0 = torch.div(x_lo, ts, rounding_mode="floor").long()
        tx1 = torch.div(x_hi, ts, rounding_mode="floor").long()
        ty0 = torch.div(y_lo, ts, rounding_mode="floor").long()
        ty1 = torch.div(y_hi, ts, rounding_mode="floor").long()
        ntx = torch.where(on_screen, tx1 - tx0 + 1, torch.zeros_like(tx0))
        nty = torch.where(on_screen, ty1 - ty0 + 1, torch.zeros_like(ty0))
        counts = ntx * nty  # [M] tiles touched by each Gaussian
        n_pairs = int(counts.sum())
        # depth rank of each Gaussian (front first), so that one sort orders the pairs by (tile, depth)
        rank = torch.empty_like(counts)
        rank[torch.argsort(proj.depth.detach())] = torch.arange(len(rank), device=device)
        gid = torch.repeat_interleave(torch.arange(len(counts), device=device), counts)  # [P]
        first = torch.cumsum(counts, 0) - counts
        local = torch.arange(n_pairs, device=device) - first[gid]
        tile = (ty0[gid] + local // ntx[gid]) * tiles_x + tx0[gid] + local % ntx[gid]  # [P]
        order = torch.argsort(tile * max(len(rank), 1) + rank[gid])
        gid, tile = gid[order], tile[order]
        tile_counts = torch.bincount(tile, minlength=n_tiles)  # [T]
        tile_first = torch.cumsum(tile_counts, 0) - tile_counts  # [T]

    feats = torch.cat([colors[proj.index], proj.depth[:, None], torch.ones_like(proj.depth)[:, None]], dim=1)
    out = torch.zeros(n_tiles * tile_px, channels + 2, dtype=dtype, device=device)  # colour, depth, alpha
    # chunk over whole tiles so that pairs x tile pixels stays bounded
    per_chunk = max(config.max_chunk_elements // tile_px, 1)
    start = 0
    while start < n_pairs:
        stop = min(start + per_chunk, n_pairs)
        if stop < n_pairs:  # end the chunk at a tile boundary (a single huge tile is taken whole)
            t_end = int(tile[stop])
            boundary = int(tile_first[t_end])
            stop = boundary if boundary > start else int(tile_first[t_end] + tile_counts[t_end])
        out = out + _composite_chunk(
            gid[start:stop], tile[start:stop], proj, opac, threshold, feats, tiles_x, ts, n_tiles, config
        )
        start = stop

    image = out.reshape(tiles_y, tiles_x, ts, ts, channels + 2).permute(0, 2, 1, 3, 4)
    image = image.reshape(tiles_y * ts, tiles_x * ts, channels + 2)[:height, :width]
    color, depth_sum, alpha = image[..., :channels], image[..., channels], image[..., channels + 1]
    depth = torch.where(alpha > 1e-8, depth_sum / alpha.clamp_min(1e-8), torch.zeros_like(alpha))
    if background is not None:
        color = color + (1.0 - alpha)[..., None] * background.to(dtype)
    return RenderResult(color=color, alpha=alpha, depth=depth, pairs=n_pairs, visible=int(on_screen.sum()))


def _composite_chunk(gid, tile, proj: _Projected, opac, threshold, feats, tiles_x, ts, n_tiles, config):  # noqa: ANN001, ANN202
    """Composite the pairs of whole tiles; returns [T * ts * ts, C + 2] summed weight x features.

    The pairs arrive sorted by (tile, depth). A dense pass (one matrix product, no gradient) finds the tile
    pixels each pair covers; the covered (pixel, pair) entries, taken pixel-major, form one contiguous,
    depth-ordered run per pixel, over which the transmittance is an exclusive cumulative sum of log(1 - alpha).
    """
    import torch

    dtype, device = proj.mean2d.dtype, proj.mean2d.device
    offs = torch.arange(ts, dtype=dtype, device=device) + 0.5 - 0.5 * ts  # pixel centres about the tile centre
    oy, ox = torch.meshgrid(offs, offs, indexing="ij")
    ox, oy = ox.reshape(-1), oy.reshape(-1)  # [K]
    tx = (tile % tiles_x).to(dtype)
    ty = torch.div(tile, tiles_x, rounding_mode="floor").to(dtype)
    mean = torch.index_select(proj.mean2d, 0, gid)  # [P, 2]
    a = (tx + 0.5) * ts - mean[:, 0]  # [P] tile centre minus Gaussian centre, pixels
    b = (ty + 0.5) * ts - mean[:, 1]
    thr = threshold[gid]  # [P]
    with torch.no_grad():
        ca, cb, cc = proj.conic.detach()[gid].unbind(1)
        ad, bd = a.detach(), b.detach()
        coeffs = torch.stack([-0.5 * ca * ad * ad - 0.5 * cc * bd * bd - cb * ad * bd, -ca * ad - cb * bd,
                              -cc * bd - cb * ad, -0.5 * ca, -0.5 * cc, -cb], dim=0)  # [6, P]  # fmt: skip
        basis = torch.stack([torch.ones_like(ox), ox, oy, ox * ox, oy * oy, ox * oy], dim=1)  # [K, 6]
        covered = basis @ coeffs >= (thr - 1e-3)[None, :]  # [K, P] with a margin; exact test below
        k_idx, p_idx = torch.nonzero(covered, as_tuple=True)  # pixel-major: runs of one (pixel, tile)
        pixel = tile[p_idx] * (ts * ts) + k_idx  # [E] output row
        new_run = torch.ones_like(pixel, dtype=torch.bool)
        new_run[1:] = pixel[1:] != pixel[:-1]
        run_first = torch.cummax(torch.where(new_run, torch.arange(len(pixel), device=device), 0), 0).values
        starts = torch.nonzero(new_run).squeeze(1)
        ends = torch.cat([starts[1:] - 1, torch.full((1,), len(pixel) - 1, device=device)])
        run_last = ends[torch.cumsum(new_run.long(), 0) - 1]  # [E] last entry of each entry's run
    # index_select rather than x[idx]: its backward is index_add, much faster on the CPU than index_put
    sel = torch.index_select
    gp = sel(gid, 0, p_idx)  # [E] Gaussian of each entry
    dx = sel(a, 0, p_idx) + sel(ox, 0, k_idx)  # [E]
    dy = sel(b, 0, p_idx) + sel(oy, 0, k_idx)
    cs = sel(proj.conic, 0, gp)  # [E, 3]
    power = -0.5 * (cs[:, 0] * dx * dx + cs[:, 2] * dy * dy) - cs[:, 1] * dx * dy
    alpha = _alpha(power, sel(opac, 0, gp), sel(thr, 0, p_idx), config)  # [E]
    log_t = torch.log1p(-alpha).to(torch.float64)
    transmittance = torch.exp(_SegmentedExclusiveCumsum.apply(log_t, run_first, run_last)).to(dtype)
    weight = alpha * transmittance  # [E]
    out = torch.zeros(n_tiles * ts * ts, feats.shape[1], dtype=dtype, device=device)
    return out.index_add(0, pixel, weight[:, None] * sel(feats, 0, gp))


def _segmented_exclusive_cumsum_function():  # noqa: ANN202
    import torch

    class SegmentedExclusiveCumsum(torch.autograd.Function):
        """Exclusive cumulative sum within contiguous runs: out_i = sum of x_j, run_first(i) <= j < i.

        Written as a global float64 cumsum minus its value at the run start, with a backward that never
        scatters: grad_j = sum of g_i over later entries of the same run (a global reverse cumsum minus its
        value past the run end).
        """

        @staticmethod
        def forward(ctx, x, run_first, run_last):  # noqa: ANN001, ANN205
            exclusive = torch.cumsum(x, 0) - x
            ctx.save_for_backward(run_last)
            return exclusive - exclusive[run_first]

        @staticmethod
        def backward(ctx, grad):  # noqa: ANN001, ANN205
            (run_last,) = ctx.saved_tensors
            after = torch.flip(torch.cumsum(torch.flip(grad, [0]), 0), [0]) - grad  # sum over i > j
            return after - after[run_last], None, None

    return SegmentedExclusiveCumsum


class _Lazy:
    """Builds the autograd Function on first use (torch is imported lazily)."""

    _fn = None

    @classmethod
    def apply(cls, *args):  # noqa: ANN002, ANN206
        if cls._fn is None:
            cls._fn = _segmented_exclusive_cumsum_function()
        return cls._fn.apply(*args)


_SegmentedExclusiveCumsum = _Lazy


def rasterize_reference(
    means: torch.Tensor,
    covariances: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    camera: Camera,
    config: RasterConfig | None = None,
    *,
    background: torch.Tensor | None = None,
) -> RenderResult:
    """Brute-force rasteriser: every Gaussian on every pixel, sorted by depth, products in float64.

    Slow (memory N x H x W); the definition that :func:`rasterize` is tested against.
    """
    import torch

    config = config or RasterConfig()
    _check_inputs(means, covariances, opacities, colors)
    _validate(camera, config, background, colors.shape[1])
    proj = _project(means, covariances, camera, config)
    order = torch.argsort(proj.depth)
    mean2d, conic, depth = proj.mean2d[order], proj.conic[order], proj.depth[order]
    opac, col = opacities[proj.index][order], colors[proj.index][order]
    ys, xs = torch.meshgrid(
        torch.arange(camera.height, dtype=means.dtype) + 0.5,
        torch.arange(camera.width, dtype=means.dtype) + 0.5,
        indexing="ij",
    )
    dx = xs[None] - mean2d[:, 0, None, None]  # [M, H, W]
    dy = ys[None] - mean2d[:, 1, None, None]
    power = (
        -0.5 * (conic[:, 0, None, None] * dx * dx + conic[:, 2, None, None] * dy * dy)
        - conic[:, 1, None, None] * dx * dy
    )
    threshold = _power_threshold(opac, config)[:, None, None]
    alpha = _alpha(power, opac[:, None, None], threshold, config).to(torch.float64)  # [M, H, W]
    trans = torch.cumprod(torch.cat([torch.ones_like(alpha[:1]), 1.0 - alpha[:-1]], dim=0), dim=0)
    weight = (alpha * trans).to(means.dtype)  # [M, H, W]
    color = torch.einsum("mhw,mc->hwc", weight, col)
    acc = weight.sum(0)
    depth_img = torch.einsum("mhw,m->hw", weight, depth)
    depth_img = torch.where(acc > 1e-8, depth_img / acc.clamp_min(1e-8), torch.zeros_like(acc))
    if background is not None:
        color = color + (1.0 - acc)[..., None] * background.to(means.dtype)
    visible = int((alpha.reshape(len(alpha), -1) > 0).any(1).sum()) if len(alpha) else 0
    return RenderResult(color=color, alpha=acc, depth=depth_img, pairs=0, visible=visible)
