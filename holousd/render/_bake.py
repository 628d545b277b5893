"""Colour baked onto a mesh from its Gaussian splats: what tools that do not read splats show.

A surface point takes the opacity- and distance-weighted mean of the view-independent colour (the degree-0 SH
term, ``0.5 + 0.28209 c_0``) of its nearest splats. Two forms: one colour per mesh point (converted from the
captured, sRGB-encoded values to the linear RGB of ``primvars:displayColor``), and a texture: a UV atlas of the
mesh (xatlas; the mesh itself is not changed, the UVs are per face corner) whose texels each take the colour of
the surface point they cover, kept sRGB-encoded as image files are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from holousd.render._binding import SH_C0, splats_in_world
from holousd.usd import GaussianSplats, MeshData, Pose

__all__ = ["Texture", "bake_texture", "linear_from_srgb", "sample_texture", "srgb_from_linear", "surface_srgb",
           "vertex_colors"]


def linear_from_srgb(values: np.ndarray) -> np.ndarray:
    """The sRGB transfer function undone (IEC 61966-2-1), values in [0, 1]."""
    v = np.clip(np.asarray(values, np.float64), 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def srgb_from_linear(values: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1): linear values in [0, 1] to the encoded values screens show."""
    v = np.clip(np.asarray(values, np.float64), 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1.0 / 2.4) - 0.055)


def surface_srgb(points: np.ndarray, mesh: MeshData, splats: GaussianSplats, *, neighbours: int = 8) -> np.ndarray:
    """[N, 3] sRGB-encoded colour in [0, 1] at object-frame surface ``points`` of ``mesh`` from the node's splats
    (bound splats are placed on ``mesh``). Without splats: mid grey."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(splats) == 0 or len(points) == 0:
        return np.full((len(points), 3), 0.5)
    centres, _, scales = splats_in_world(splats, Pose(), mesh if splats.bound else None)
    srgb = np.clip(0.5 + SH_C0 * splats.sh_coeffs[:, 0, :].astype(np.float64), 0.0, 1.0)
    k = min(neighbours, len(centres))
    distance, index = cKDTree(centres).query(points, k=k)
    distance, index = distance.reshape(len(points), k), index.reshape(len(points), k)
    reach = np.maximum(scales.max(axis=1)[index], 1e-6)  # each splat's own size sets how far its colour carries
    weight = np.maximum(splats.opacities[index].astype(np.float64), 1e-3) * np.exp(-0.5 * (distance / reach) ** 2)
    weight[np.arange(len(points)), 0] += 1e-12  # the nearest splat decides where every weight vanishes
    return np.einsum("pk,pkc->pc", weight, srgb[index]) / weight.sum(axis=1, keepdims=True)


def vertex_colors(mesh: MeshData, splats: GaussianSplats, *, neighbours: int = 8) -> np.ndarray:
    """[P, 3] linear RGB per mesh point from the node's splats (object coordinates; bound splats are placed on
    ``mesh``). A mesh without splats comes out mid grey."""
    return linear_from_srgb(surface_srgb(mesh.points, mesh, splats, neighbours=neighbours))


@dataclass(kw_only=True)
class Texture:
    """A mesh's colour as a texture atlas."""

    st: np.ndarray
    """[F, 3, 2] texture coordinates of each face's corners, USD's convention: (0, 0) is the image's bottom left."""
    image: np.ndarray
    """[H, W, 3] uint8 sRGB-encoded colours, row 0 at the top (as image files store them)."""


def bake_texture(mesh: MeshData, splats: GaussianSplats, *, texel_m: float | None = None, max_size: int = 1024,
                 padding: int = 2) -> Texture | None:  # fmt: skip
    """Unwrap ``mesh`` into a UV atlas and colour every texel from the splats at the surface point it covers;
    None when xatlas cannot pack the mesh into one atlas of at most ``max_size`` texels a side (its texel grown
    up to about 28 times) or changes its faces (the per-point colours then stay the mesh's only colour).

    Args:
        mesh: The node's rendered mesh (object frame); it is not changed.
        splats: The node's splats.
        texel_m: Texel size on the surface, m (None: half the median spacing of the splats, at least 1 mm, so the
            texture keeps what the splats resolve and no more).
        max_size: Longest side of the atlas, texels (the texel grows for large surfaces).
        padding: Texels between charts.
    """
    import xatlas
    from scipy import ndimage

    points = np.asarray(mesh.points, np.float64)
    faces = np.asarray(mesh.faces, np.int64)
    corners = points[faces]
    area = float(0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                                      axis=1).sum())  # fmt: skip
    if texel_m is None:
        texel_m = _splat_spacing(splats, mesh) / 2.0
    texel_m = max(float(texel_m), 1e-3, float(np.sqrt(area / (0.6 * max_size**2))))
    fits = False
    for _ in range(16):  # 1.25^15: the texel up to 28 times what was asked
        atlas = xatlas.Atlas()
        atlas.add_mesh(points.astype(np.float32), faces.astype(np.uint32))
        options = xatlas.PackOptions()
        options.texels_per_unit = 1.0 / texel_m
        options.padding = padding
        options.bilinear = True
        charts = xatlas.ChartOptions()
        charts.max_iterations = 0  # the room of the demo: 1.1 s instead of 3.6 s, as many texels used (84%)
        atlas.generate(chart_options=charts, pack_options=options)
        fits = atlas.atlas_count == 1 and max(atlas.width, atlas.height) <= max_size
        if fits:
            break
        texel_m *= 1.25
    if not fits:
        return None
    vmapping, indices, uvs = atlas[0]
    if indices.shape != faces.shape or not np.array_equal(vmapping[indices], faces):
        return None
    width, height = int(atlas.width), int(atlas.height)
    st = np.asarray(uvs, np.float64)[indices]  # [F, 3, 2], u right, v up from the bottom (xatlas: v down)
    st[..., 1] = 1.0 - st[..., 1]
    face, bary, rows, cols = _rasterize(st, width, height)
    texel_points = np.einsum("nk,nkc->nc", bary, corners[face])
    image = np.zeros((height, width, 3))
    filled = np.zeros((height, width), bool)
    image[rows, cols] = surface_srgb(texel_points, mesh, splats)
    filled[rows, cols] = True
    if filled.any():  # every empty texel takes its nearest filled one: no dark seams under bilinear filtering
        _, (near_r, near_c) = ndimage.distance_transform_edt(~filled, return_indices=True)
        image = image[near_r, near_c]
    else:
        image[:] = 0.5
    return Texture(st=st, image=np.round(255.0 * np.clip(image, 0.0, 1.0)).astype(np.uint8))


def _splat_spacing(splats: GaussianSplats, mesh: MeshData) -> float:
    from scipy.spatial import cKDTree

    if len(splats) < 2:
        return 0.01
    centres, _, _ = splats_in_world(splats, Pose(), mesh if splats.bound else None)
    distance, _ = cKDTree(centres).query(centres, k=2)
    return float(np.median(distance[:, 1]))


def _rasterize(st: np.ndarray, width: int, height: int) -> tuple[np.ndarray, ...]:
    """The texels whose centres lie in each face's UV triangle: [N] face, [N, 3] barycentric weights, [N] row and
    [N] column of the texel (a texel on a shared edge is listed for both faces; either colour is right)."""
    px = np.stack([st[..., 0] * width, (1.0 - st[..., 1]) * height], axis=-1)  # [F, 3, 2] pixel coordinates
    lo = np.floor(px.min(axis=1) - 0.5).astype(np.int64)
    hi = np.ceil(px.max(axis=1) - 0.5).astype(np.int64)
    nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    count = nx * ny
    face = np.repeat(np.arange(len(st)), count)
    k = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    cx = lo[face, 0] + k % nx[face] + 0.5
    cy = lo[face, 1] + k // nx[face] + 0.5
    a, b, c = px[face, 0], px[face, 1], px[face, 2]
    v0, v1 = b - a, c - a
    v2 = np.stack([cx, cy], axis=1) - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(np.abs(den) < 1e-12, 1e-12, den)
    w1 = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
    w2 = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    bary = np.stack([1.0 - w1 - w2, w1, w2], axis=1)
    inside = np.all(bary >= -1e-6, axis=1) & (cx >= 0) & (cx < width) & (cy >= 0) & (cy < height)
    return face[inside], bary[inside], (cy[inside] - 0.5).astype(np.int64), (cx[inside] - 0.5).astype(np.int64)


def sample_texture(image: np.ndarray, st: np.ndarray) -> np.ndarray:
    """[N, 3] colour in [0, 1] (sRGB-encoded, as stored) of ``image`` [H, W, 3] at texture coordinates ``st``
    [N, 2] (USD's convention), bilinear between texel centres, clamped at the border."""
    height, width = image.shape[:2]
    x = np.clip(st[:, 0] * width - 0.5, 0.0, width - 1.0)
    y = np.clip((1.0 - st[:, 1]) * height - 0.5, 0.0, height - 1.0)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    x1, y1 = np.minimum(x0 + 1, width - 1), np.minimum(y0 + 1, height - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    img = np.asarray(image, np.float64) / 255.0
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bottom * fy
