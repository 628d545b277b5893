"""A differentiable SSIM for the appearance fit's loss (the render domain's; holousd.eval re-exports it)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from holousd._errors import InvalidDataError

if TYPE_CHECKING:
    import torch

__all__ = ["ssim_torch"]


def ssim_torch(image: torch.Tensor, reference: torch.Tensor, *, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Differentiable mean SSIM of two [H, W, C] images in [0, 1] (Gaussian window, as in 3DGS's loss).

    Borders are handled by 'valid' filtering (no padding), like scikit-image; returns a scalar tensor.
    """
    import torch
    import torch.nn.functional as F

    if image.shape != reference.shape or image.ndim != 3:
        raise InvalidDataError(
            f"ssim_torch: two [H, W, C] images needed, got {list(image.shape)}, {list(reference.shape)}"
        )
    c1, c2 = 0.01**2, 0.03**2
    coords = torch.arange(window, dtype=image.dtype, device=image.device) - (window - 1) / 2
    g = torch.exp(-(coords**2) / (2 * sigma**2))
    g = g / g.sum()
    channels = image.shape[2]
    x = image.permute(2, 0, 1)[None]  # [1, C, H, W]
    y = reference.permute(2, 0, 1)[None]
    kx = g.reshape(1, 1, 1, window).repeat(channels, 1, 1, 1)
    ky = g.reshape(1, 1, window, 1).repeat(channels, 1, 1, 1)

    def blur(t: torch.Tensor) -> torch.Tensor:
        return F.conv2d(F.conv2d(t, kx, groups=channels), ky, groups=channels)

    mu_x, mu_y = blur(x), blur(y)
    sxx = blur(x * x) - mu_x**2
    syy = blur(y * y) - mu_y**2
    sxy = blur(x * y) - mu_x * mu_y
    num = (2 * mu_x * mu_y + c1) * (2 * sxy + c2)
    den = (mu_x**2 + mu_y**2 + c1) * (sxx + syy + c2)
    return (num / den).mean()
