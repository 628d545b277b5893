"""Evaluation: image metrics (PSNR, SSIM, LPIPS), geometry metrics (Chamfer, F-score, normal consistency) and
the benchmark harnesses;
end-to-end scene evaluation (``holousd eval``), the suite benchmark (``holousd bench``) and the demo report."""

from holousd.eval._bench_suite import BenchSuiteConfig, BenchSuiteResult, run_bench
from holousd.eval._geometry import (
    GeometryMetrics,
    SceneGeometryReport,
    evaluate_fit,
    geometry_metrics,
    sample_surface,
    visible_mask,
)
from holousd.eval._image import ImageMetrics, image_metrics, lpips, psnr, ssim, ssim_torch
from holousd.eval._report import DemoConfig, run_demo, write_report
from holousd.eval._scene_eval import EvalConfig, ObjectRow, SceneEvaluation, evaluate_scene

__all__ = [
    "BenchSuiteConfig",
    "BenchSuiteResult",
    "DemoConfig",
    "EvalConfig",
    "GeometryMetrics",
    "ImageMetrics",
    "ObjectRow",
    "SceneEvaluation",
    "SceneGeometryReport",
    "evaluate_fit",
    "evaluate_scene",
    "geometry_metrics",
    "image_metrics",
    "lpips",
    "psnr",
    "run_bench",
    "run_demo",
    "sample_surface",
    "ssim",
    "ssim_torch",
    "visible_mask",
    "write_report",
]
