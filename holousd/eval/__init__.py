"""Evaluation: image metrics (PSNR, SSIM, LPIPS) for appearance; benchmark harnesses live beside the domains."""

from holousd.eval._image import ImageMetrics, image_metrics, lpips, psnr, ssim, ssim_torch

__all__ = ["ImageMetrics", "image_metrics", "lpips", "psnr", "ssim", "ssim_torch"]
