"""Image metrics: PSNR, SSIM (scikit-image for reporting, a differentiable torch SSIM for losses), LPIPS.

Images are float arrays in [0, 1], shaped [H, W, 3] (or [H, W] for one channel).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from holousd._errors import InvalidDataError
from holousd.render._ssim import ssim_torch

__all__ = ["ImageMetrics", "image_metrics", "lpips", "psnr", "ssim", "ssim_torch"]


def _pair(image: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(image, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    if a.shape != b.shape or a.ndim not in (2, 3):
        raise InvalidDataError(
            f"image metrics need two images of the same shape [H, W] or [H, W, C], got {list(a.shape)} "
            f"and {list(b.shape)}"
        )
    return a, b


def psnr(image: np.ndarray, reference: np.ndarray, *, mask: np.ndarray | None = None, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB (inf for identical images).

    Args:
        image: [H, W, C] or [H, W] rendered image.
        reference: Ground truth of the same shape.
        mask: Optional [H, W] boolean: only these pixels count.
        data_range: Value range of the images (1.0 for [0, 1] floats).
    """
    a, b = _pair(image, reference)
    err = (a - b) ** 2
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != a.shape[:2]:
            raise InvalidDataError(f"psnr: mask must be [{a.shape[0]}, {a.shape[1]}], got {list(mask.shape)}")
        err = err[mask]
    mse = float(err.mean()) if err.size else 0.0
    return float("inf") if mse == 0 else float(10.0 * np.log10(data_range**2 / mse))


def ssim(image: np.ndarray, reference: np.ndarray, *, data_range: float = 1.0) -> float:
    """Structural similarity (scikit-image's ``structural_similarity``, Gaussian window sigma 1.5 as in the paper)."""
    from skimage.metrics import structural_similarity

    a, b = _pair(image, reference)
    return float(
        structural_similarity(
            a, b, data_range=data_range, channel_axis=-1 if a.ndim == 3 else None,
            gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
        )
    )  # fmt: skip


def lpips(image: np.ndarray, reference: np.ndarray, *, weights: str | os.PathLike[str] | None = None) -> float | None:
    """LPIPS distance, or None when no local model is given (never downloads anything).

    Args:
        image: [H, W, 3] image in [0, 1].
        reference: Ground truth of the same shape.
        weights: A TorchScript LPIPS model saved with ``torch.jit.save`` that maps two [1, 3, H, W] images in
            [-1, 1] to a distance (e.g. a scripted ``lpips.LPIPS(net='alex')``). None or a missing file: None.
    """
    if weights is None or not Path(weights).is_file():
        return None
    import torch

    a, b = _pair(image, reference)
    model = torch.jit.load(str(weights), map_location="cpu").eval()

    def prep(x: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(x, dtype=torch.float32).permute(2, 0, 1)[None] * 2.0 - 1.0

    with torch.no_grad():
        return float(model(prep(a), prep(b)).reshape(-1)[0])


@dataclass(kw_only=True)
class ImageMetrics:
    """Appearance metrics of one image or averaged over a set."""

    psnr: float
    """Peak signal-to-noise ratio, dB."""
    ssim: float
    """Structural similarity in [-1, 1]."""
    lpips: float | None
    """LPIPS distance, or None when no local LPIPS model was given."""


def image_metrics(
    images: list[np.ndarray], references: list[np.ndarray], *, lpips_weights: str | os.PathLike[str] | None = None
) -> ImageMetrics:
    """Mean PSNR, SSIM and (when a local model is given) LPIPS over pairs of images."""
    if len(images) != len(references) or not images:
        raise InvalidDataError(
            f"image_metrics: need matching, non-empty lists, got {len(images)} and {len(references)}"
        )
    scores = [lpips(a, b, weights=lpips_weights) for a, b in zip(images, references, strict=True)]
    return ImageMetrics(
        psnr=float(np.mean([psnr(a, b) for a, b in zip(images, references, strict=True)])),
        ssim=float(np.mean([ssim(a, b) for a, b in zip(images, references, strict=True)])),
        lpips=None if any(s is None for s in scores) else float(np.mean(scores)),
    )
