"""The CPU Gaussian rasteriser: agreement with the brute-force definition, gradients, input checks."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest

from holousd import InvalidDataError
from holousd.render import (
    Camera,
    RasterConfig,
    covariances_from_quats,
    look_at,
    rasterize,
    rasterize_reference,
)

if TYPE_CHECKING:
    import torch


def _random_gaussians(n: int, seed: int, dtype_name: str = "float64") -> tuple[torch.Tensor, ...]:
    import torch

    dtype = getattr(torch, dtype_name)
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=dtype) * 2 - 1) * 0.8
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    scales = torch.rand(n, 3, generator=g, dtype=dtype) * 0.15 + 0.02
    opac = torch.rand(n, generator=g, dtype=dtype) * 0.85 + 0.05
    colors = torch.rand(n, 4, generator=g, dtype=dtype)
    return means, covariances_from_quats(quats, scales), opac, colors


def _camera(width: int = 45, height: int = 37) -> Camera:
    return Camera(fx=40.0, fy=43.0, cx=width / 2 + 0.7, cy=height / 2 - 1.1, width=width, height=height,
                  cam_to_world=look_at(np.array([0.4, -3.0, 0.6]), np.zeros(3)))  # fmt: skip


@pytest.mark.parametrize("tile_size", [4, 8, 16])
def test_tiled_rasteriser_matches_brute_force(tile_size: int) -> None:
    import torch

    means, covs, opac, colors = _random_gaussians(80, seed=tile_size)
    cam = _camera()
    background = torch.tensor([0.2, 0.3, 0.4, 0.0], dtype=torch.float64)
    ref = rasterize_reference(means, covs, opac, colors, cam, background=background)
    out = rasterize(means.float(), covs.float(), opac.float(), colors.float(), cam,
                    RasterConfig(tile_size=tile_size), background=background.float())  # fmt: skip
    assert out.color.shape == (37, 45, 4) and out.alpha.shape == (37, 45) and out.depth.shape == (37, 45)
    assert float(ref.alpha.max()) > 0.9  # the case is not trivially empty
    assert torch.allclose(out.color.double(), ref.color, atol=1e-4)
    assert torch.allclose(out.alpha.double(), ref.alpha, atol=1e-4)
    assert torch.allclose(out.depth.double(), ref.depth, atol=1e-3 * float(ref.depth.max()))


def test_chunked_compositing_matches_single_pass() -> None:
    import torch

    means, covs, opac, colors = _random_gaussians(60, seed=3, dtype_name="float32")
    cam = _camera()
    whole = rasterize(means, covs, opac, colors, cam, RasterConfig(tile_size=4))
    chunked = rasterize(means, covs, opac, colors, cam, RasterConfig(tile_size=4, max_chunk_elements=64))
    assert torch.allclose(whole.color, chunked.color, atol=1e-6)


def test_gaussians_behind_the_camera_leave_the_background() -> None:
    import torch

    means, covs, opac, colors = _random_gaussians(10, seed=4, dtype_name="float32")
    cam = Camera(
        fx=20,
        fy=20,
        cx=8,
        cy=8,
        width=16,
        height=16,
        cam_to_world=look_at(np.array([0, -3.0, 0]), np.array([0, -6.0, 0])),
    )
    out = rasterize(means, covs, opac, colors, cam, background=torch.ones(4))
    assert out.visible == 0 and torch.equal(out.color, torch.ones(16, 16, 4)) and float(out.alpha.max()) == 0.0


def test_gradients_match_finite_differences() -> None:
    import torch

    means, covs, opac, colors = _random_gaussians(4, seed=11)
    g = torch.Generator().manual_seed(5)
    quats = torch.randn(4, 4, generator=g, dtype=torch.float64)
    scales = torch.rand(4, 3, generator=g, dtype=torch.float64) * 0.3 + 0.25
    cam = Camera(
        fx=11, fy=12, cx=5.5, cy=5, width=11, height=10, cam_to_world=look_at(np.array([0.3, -3.0, 0.5]), np.zeros(3))
    )

    def render(m: torch.Tensor, q: torch.Tensor, s: torch.Tensor, o: torch.Tensor, c: torch.Tensor) -> tuple:
        out = rasterize(m, covariances_from_quats(q, s), o, c, cam, RasterConfig(tile_size=4))
        return out.color, out.alpha, out.depth

    inputs = [x.clone().requires_grad_() for x in (means * 0.6, quats, scales, opac * 0.8, colors)]
    assert torch.autograd.gradcheck(render, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_bad_inputs_are_reported() -> None:
    import torch

    means, covs, opac, colors = _random_gaussians(5, seed=0, dtype_name="float32")
    cam = _camera()
    with pytest.raises(InvalidDataError, match=r"means must be \[N, 3\]"):
        rasterize(means[:, :2], covs, opac, colors, cam)
    with pytest.raises(InvalidDataError, match="opacities"):
        rasterize(means, covs, opac[:3], colors, cam)
    with pytest.raises(InvalidDataError, match="background"):
        rasterize(means, covs, opac, colors, cam, background=torch.zeros(3))
    with pytest.raises(InvalidDataError, match="rotation"):
        Camera(fx=1, fy=1, cx=0, cy=0, width=4, height=4, cam_to_world=np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(InvalidDataError, match="focal"):
        Camera(fx=-1, fy=1, cx=0, cy=0, width=4, height=4, cam_to_world=np.eye(4))
