"""Evaluation: image metrics (PSNR, SSIM, LPIPS), geometry metrics (Chamfer, F-score, normal consistency) and
the benchmark harnesses."""

from holousd.eval._geometry import (
    GeometryMetrics,
    SceneGeometryReport,
    evaluate_fit,
    geometry_metrics,
    sample_surface,
    visible_mask,
)
from holousd.eval._image import ImageMetrics, image_metrics, lpips, psnr, ssim, ssim_torch

__all__ = [
    "GeometryMetrics",
    "ImageMetrics",
    "SceneGeometryReport",
    "evaluate_fit",
    "geometry_metrics",
    "image_metrics",
    "lpips",
    "psnr",
    "sample_surface",
    "ssim",
    "ssim_torch",
    "visible_mask",
]
