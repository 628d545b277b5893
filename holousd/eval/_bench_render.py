"""Appearance benchmark: fit Gaussians-on-mesh to ray-cast reference images of the example scene.

Reference ("ground truth"): the example scene's ground-truth meshes ray-cast with a procedural texture and
Lambertian shading (2 x 2 supersampling), independent of the splat model. Training views orbit the objects at
two heights; held-out views sit between them at a third height. The fit starts from the meshes alone (splat
count from the footprint rule, colours sampled from the training images). Speed: one 256 x 256 frame of
~100k splats (bound to the same meshes) is rasterised and timed.
"""

from __future__ import annotations

import json
import os
import platform
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from holousd._atomic import atomic_path
from holousd.render._binding import SH_C0, initial_bound_splats, splat_budget
from holousd.render._camera import Camera
from holousd.render._fit import FitConfig
from holousd.render._frames import Frame
from holousd.render._raycast import render_textured
from holousd.render._scene import SceneRenderer, scene_orbit, write_png
from holousd.usd import MeshData, Pose, SceneGraph

__all__ = ["BenchConfig", "BenchReport", "bench_render", "bench_chart"]

_BASE = {"background": (0.8, 0.78, 0.72), "table": (0.55, 0.35, 0.2), "book": (0.7, 0.12, 0.1),
         "mug": (0.9, 0.9, 0.85), "box": (0.2, 0.4, 0.8)}  # fmt: skip
_TARGETS = {"heldout_psnr_min": 28.0, "heldout_ssim_min": 0.85, "fit_seconds_max": 180.0, "render_seconds_max": 0.5}
_LIGHT = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])


@dataclass(kw_only=True)
class BenchConfig:
    """Settings of :func:`bench_render`."""

    width: int = 256
    """Image width, pixels."""
    height: int = 256
    """Image height, pixels."""
    train_views: int = 24
    """Training views (two orbits)."""
    test_views: int = 6
    """Held-out views (a third orbit, between the training azimuths)."""
    iterations: int = 200
    """Adam steps of the fit."""
    spacing_px: float = 3.0
    """Splat spacing on screen at the closest view, pixels (the count rule's knob)."""
    max_splats: int = 20_000
    """Per-node upper clamp of the splat count."""
    speed_splats: int = 100_000
    """Splats in the rendering-speed test."""
    speed_repeats: int = 5
    """Timed renders in the speed test (the median is reported)."""
    seed: int = 0
    """Seed of every random choice."""
    lpips_weights: str | None = None
    """Local TorchScript LPIPS model (None: LPIPS reported as unavailable)."""


@dataclass(kw_only=True)
class BenchReport:
    """Benchmark figures (also written as bench_render.json)."""

    reference: str
    """What the ground-truth images are."""
    machine: str
    """CPU / threads the figures were measured on."""
    resolution: list[int]
    """Image width, height."""
    splat_counts: dict[str, int]
    """Splats per node chosen by the footprint rule."""
    splat_budget: dict[str, dict[str, float]]
    """Per node: desired (unclamped) count, observed area m^2, median footprint m/px."""
    total_splats: int
    """Sum of splat_counts."""
    fit_seconds: float
    """Wall time of the optimisation."""
    fit_iterations: int
    """Adam steps."""
    train_psnr: float
    """PSNR over the last pass of training steps, dB."""
    heldout_psnr: float
    """Mean PSNR on held-out views, dB."""
    heldout_ssim: float
    """Mean SSIM (scikit-image) on held-out views."""
    heldout_lpips: float | None
    """Mean LPIPS on held-out views, or None when unavailable."""
    lpips_note: str
    """Why LPIPS is or is not reported."""
    render_splats: int
    """Splats in the speed test."""
    render_seconds: float
    """Median wall time to rasterise one frame of render_splats splats, seconds."""
    targets: dict[str, float] = field(default_factory=lambda: dict(_TARGETS))
    """Targets of issue 6."""


def _shader(names: list[str], poses: list[Pose]):  # noqa: ANN202
    """Procedural texture in object coordinates with Lambertian shading in the world."""

    def shade(mesh_idx: np.ndarray, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        out = np.zeros((len(points), 3))
        for k, (name, pose) in enumerate(zip(names, poses, strict=True)):
            sel = mesh_idx == k
            if not sel.any():
                continue
            p = (points[sel] - pose.translation) @ pose.rotation_matrix()
            period = 0.5 if name == "background" else 0.12
            w = 2 * np.pi / period
            pattern = (np.sin(w * p[:, 0]) + np.sin(w * p[:, 1] + 1.0) + np.sin(w * p[:, 2] + 2.0)) / 3.0
            checker = (np.floor(p / (2 * period)).sum(axis=1) % 2) * 0.08
            base = np.asarray(_BASE.get(name, (0.6, 0.6, 0.6)))
            light = 0.55 + 0.45 * np.clip(normals[sel] @ _LIGHT, 0.0, None)
            out[sel] = np.clip(base[None] * (0.8 + 0.2 * pattern + checker)[:, None] * light[:, None], 0.0, 1.0)
        return out

    return shade


def _reference_frames(scene: SceneGraph, cameras: list[Camera]) -> list[Frame]:
    names = [n.name for n in scene.nodes()]
    poses = [scene.get_pose(n) for n in names]
    meshes = [MeshData(points=pose.apply(scene.get_mesh(n).points), faces=scene.get_mesh(n).faces)
              for n, pose in zip(names, poses, strict=True)]  # fmt: skip
    ids = np.array([scene.node_info(n).instance_id for n in names] + [-1])
    frames = []
    for cam in cameras:
        image, label = render_textured(meshes, cam, _shader(names, poses), supersample=2)
        frames.append(Frame(image=image, camera=cam, mask=ids[label].astype(np.int32)))
    return frames


def _speed_splats(scene: SceneGraph, count: int, seed: int) -> None:
    """Replace every node's splats by ``count`` splats in total, spread by area (for the speed test)."""
    areas = {}
    for node in scene.nodes():
        mesh = scene.get_mesh(node.name)
        tri = mesh.points[mesh.faces]
        areas[node.name] = float(
            0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
        )
    total = sum(areas.values())
    for i, (name, area) in enumerate(areas.items()):
        n = max(int(round(count * area / total)), 1)
        mesh = scene.get_mesh(name)
        budget = splat_budget(mesh, Pose(), [], min_splats=n, max_splats=n, candidates=max(4 * n, 1000), seed=seed + i)
        splats = initial_bound_splats(mesh, budget, seed=seed + i, scale_factor=0.6 * np.sqrt(area / n))
        rgb = np.asarray(_BASE.get(name, (0.6, 0.6, 0.6)))
        splats.sh_coeffs = np.broadcast_to(((rgb - 0.5) / SH_C0)[None, None, :], (n, 1, 3)).astype(np.float32)
        scene.set_gaussians(name, splats)


def bench_render(
    out_dir: str | os.PathLike[str], config: BenchConfig | None = None, *, progress: bool = True
) -> BenchReport:
    """Run the appearance benchmark in ``out_dir``: scene, reference and fitted images, JSON and chart.

    Returns:
        The :class:`BenchReport` (also written to ``out_dir/bench_render.json``; the chart to
        ``out_dir/bench_render.png``).
    """
    import torch

    from holousd.eval import image_metrics
    from holousd.stages import AppearanceConfig, fit_appearance
    from holousd.synth import build_example_scene

    config = config or BenchConfig()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    scene_path = build_example_scene(out_dir / "scene", seed=config.seed, overwrite=True)
    scene = SceneGraph.open(scene_path)
    w, h = config.width, config.height
    half = config.train_views // 2
    train_cams = scene_orbit(scene, half, width=w, height=h, elevation=0.5) + scene_orbit(
        scene, config.train_views - half, width=w, height=h, elevation=1.0, start_deg=-90 + 180 / max(half, 1)
    )
    test_cams = scene_orbit(scene, config.test_views, width=w, height=h, elevation=0.75,
                            start_deg=-90 + 90 / max(half, 1))  # fmt: skip
    train = _reference_frames(scene, train_cams)
    test = _reference_frames(scene, test_cams)

    stage = AppearanceConfig(
        layer="appearance.usda", spacing_px=config.spacing_px, max_splats=config.max_splats, seed=config.seed,
        fit=FitConfig(iterations=config.iterations, seed=config.seed, progress=progress),
    )  # fmt: skip
    result = fit_appearance(scene, train, stage)
    renderer = SceneRenderer(result.scene, background=(0.0, 0.0, 0.0))
    renders = [renderer.render(f.camera).color.numpy() for f in test]
    for i, (img, ref) in enumerate(zip(renders, test, strict=True)):
        write_png(out_dir / f"heldout_{i:02d}_render.png", img)
        write_png(out_dir / f"heldout_{i:02d}_reference.png", ref.image)
    metrics = image_metrics(renders, [f.image for f in test], lpips_weights=config.lpips_weights)

    speed_scene = SceneGraph.open(scene_path)
    speed_scene.push_layer(out_dir / "scene" / "speed.usda", provenance="bench-speed", replace=True)
    _speed_splats(speed_scene, config.speed_splats, config.seed)
    speed_renderer = SceneRenderer(speed_scene, background=(0.0, 0.0, 0.0))
    speed_renderer.render(test_cams[0])  # warm-up
    times = []
    for _ in range(config.speed_repeats):
        started = time.perf_counter()
        speed_renderer.render(test_cams[0])
        times.append(time.perf_counter() - started)

    report = BenchReport(
        reference="ray-cast example-scene meshes (procedural texture, Lambertian shading, 2x2 supersampling); "
        f"{len(train)} training and {len(test)} held-out orbit views",
        machine=f"{platform.processor() or platform.machine()}, torch threads {torch.get_num_threads()}, "
        f"{os.cpu_count()} CPUs",
        resolution=[w, h],
        splat_counts=dict(result.counts),
        splat_budget={
            k: {"desired": b.desired, "observed_area_m2": b.observed_area, "footprint_median_m": b.footprint_median}
            for k, b in result.budgets.items()
        },  # fmt: skip
        total_splats=int(sum(result.counts.values())),
        fit_seconds=result.fit.seconds,
        fit_iterations=result.fit.iterations,
        train_psnr=result.fit.train_psnr,
        heldout_psnr=metrics.psnr,
        heldout_ssim=metrics.ssim,
        heldout_lpips=metrics.lpips,
        lpips_note="computed with " + str(config.lpips_weights)
        if metrics.lpips is not None
        else "unavailable: no local LPIPS model given (pass --lpips-weights; nothing is downloaded)",
        render_splats=speed_renderer.splat_count,
        render_seconds=float(np.median(times)),
    )
    with atomic_path(out_dir / "bench_render.json") as tmp:
        tmp.write_text(json.dumps(asdict(report), indent=2))
    bench_chart(report, out_dir / "bench_render.png")
    return report


def bench_chart(report: BenchReport, path: str | os.PathLike[str]) -> Path:
    """Draw the report as a PNG: measured value against target for each figure (PIL, no matplotlib)."""
    from PIL import Image, ImageDraw

    rows = [
        ("held-out PSNR (dB)", report.heldout_psnr, report.targets["heldout_psnr_min"], 40.0, True),
        ("held-out SSIM", report.heldout_ssim, report.targets["heldout_ssim_min"], 1.0, True),
        ("fit time (s)", report.fit_seconds, report.targets["fit_seconds_max"], max(report.fit_seconds, 200.0), False),
        (f"render {report.render_splats // 1000}k splats (s)", report.render_seconds,
         report.targets["render_seconds_max"], max(report.render_seconds, 1.0), False),
    ]  # fmt: skip
    width, row_h, left = 720, 60, 230
    img = Image.new("RGB", (width, 70 + row_h * len(rows)), "white")
    draw = ImageDraw.Draw(img)
    draw.text((10, 10), f"holousd bench-render: {report.total_splats} splats fitted, "
              f"{report.resolution[0]}x{report.resolution[1]}, {report.machine}", fill="black")  # fmt: skip
    draw.text((10, 28), "bar = measured, line = target (green: target met)", fill="gray")
    for i, (label, value, target, scale, higher_better) in enumerate(rows):
        y = 55 + i * row_h
        ok = value >= target if higher_better else value <= target
        span = width - left - 20
        draw.text((10, y + 12), label, fill="black")
        draw.rectangle([left, y + 5, left + int(span * min(value / scale, 1.0)), y + 35],
                       fill=(60, 160, 80) if ok else (200, 70, 60))  # fmt: skip
        tx = left + int(span * min(target / scale, 1.0))
        draw.line([tx, y, tx, y + 40], fill="black", width=2)
        draw.text(
            (left + 5, y + 38), f"{value:.3g} (target {'>=' if higher_better else '<='} {target:g})", fill="black"
        )
    with atomic_path(path) as tmp:
        img.save(tmp, format="PNG")
    return Path(path)
