"""Rendering: a differentiable CPU Gaussian rasteriser, Gaussians-on-mesh binding and fitting, mesh ray
casting, and scene / video rendering (``holousd render``, ``holousd bench-render``)."""

from holousd.render._binding import (
    FLATNESS,
    SH_C0,
    SplatBudget,
    bound_gaussians,
    initial_bound_splats,
    rotations_to_quats,
    splat_budget,
    splats_in_world,
    sync_bound_splats,
)
from holousd.render._camera import Camera, look_at, orbit_cameras
from holousd.render._fit import FitConfig, FitNode, FitResult, colors_from_frames, fit_bound_splats
from holousd.render._frames import Frame, as_frames
from holousd.render._rasterize import (
    RasterConfig,
    RenderResult,
    covariances_from_quats,
    covariances_from_rotations,
    rasterize,
    rasterize_reference,
)
from holousd.render._raycast import RayHits, raycast, render_textured
from holousd.render._scene import (
    SceneRenderer,
    VideoResult,
    observed_cameras,
    render_video,
    scene_orbit,
    sh_to_rgb,
    time_codes,
    write_mp4,
    write_png,
)
from holousd.render._volume import (
    RayBatch,
    RenderOutput,
    SdfGridSet,
    VolumeConfig,
    laplace_density,
    render_rays,
)

__all__ = [
    "RayBatch",
    "RenderOutput",
    "SdfGridSet",
    "VolumeConfig",
    "laplace_density",
    "render_rays",
    "FLATNESS",
    "SH_C0",
    "Camera",
    "FitConfig",
    "FitNode",
    "FitResult",
    "Frame",
    "RasterConfig",
    "RayHits",
    "RenderResult",
    "SceneRenderer",
    "SplatBudget",
    "VideoResult",
    "as_frames",
    "bound_gaussians",
    "colors_from_frames",
    "covariances_from_quats",
    "covariances_from_rotations",
    "fit_bound_splats",
    "initial_bound_splats",
    "look_at",
    "observed_cameras",
    "orbit_cameras",
    "rasterize",
    "rasterize_reference",
    "raycast",
    "render_textured",
    "render_video",
    "rotations_to_quats",
    "scene_orbit",
    "sh_to_rgb",
    "splat_budget",
    "splats_in_world",
    "sync_bound_splats",
    "time_codes",
    "write_mp4",
    "write_png",
]
