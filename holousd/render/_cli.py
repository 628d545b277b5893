"""Sub-commands of the render domain: ``render`` and ``bench-render``, and ``export --ply`` (the splats in the 3DGS
layout: the render domain adds the option to the usd domain's ``export``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from holousd._argtypes import resolution

__all__ = ["add_commands"]


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register ``render`` and ``bench-render`` on the ``holousd`` parser."""
    render = subparsers.add_parser(
        "render",
        help="render a scene's Gaussian splats to PNGs and an mp4",
        description="Render every node's splats, placed by its pose (edit layers apply), to OUT/frame_XXXX.png and "
        "OUT/render.mp4. Frame i is rendered at time code i of the stage's time range, so a simulation "
        "layer's trajectories play back.",
    )
    render.add_argument("scene", type=Path, metavar="SCENE", help="scene file (.usda/.usdc/.usd)")
    render.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    render.add_argument("--cameras", choices=("orbit", "observed"), default="orbit",
                        help="orbit around the objects, or the UsdGeom.Camera prims under /World/Cameras")  # fmt: skip
    render.add_argument("--frames", type=int, default=48, help="number of frames")
    render.add_argument("--resolution", type=resolution, default=(256, 256), metavar="WxH", help="image size")
    render.add_argument("--fps", type=int, default=24, help="video frame rate")
    render.add_argument("--background", type=float, nargs=3, default=(1.0, 1.0, 1.0), metavar=("R", "G", "B"),
                        help="colour behind the splats, in [0, 1]")  # fmt: skip
    render.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    render.set_defaults(handler=_render)

    bench = subparsers.add_parser(
        "bench-render",
        help="appearance benchmark: fit splats on the example scene, held-out PSNR/SSIM, fit and render time",
        description="Ray-cast reference images of the example scene's textured meshes, fit Gaussians-on-mesh "
        "to the training views from the meshes alone, and report held-out PSNR / SSIM (LPIPS with a local model), "
        "splat counts, fit time and the time to render 100k splats at 256x256. Writes DIR/bench_render.json "
        "and DIR/bench_render.png.",
    )
    bench.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    bench.add_argument("--iterations", type=int, default=200, help="Adam steps of the fit")
    bench.add_argument("--spacing-px", type=float, default=3.0, help="splat spacing on screen at the closest view")
    bench.add_argument("--lpips-weights", type=Path, default=None,
                       help="local TorchScript LPIPS model; without it LPIPS is reported as unavailable")  # fmt: skip
    bench.add_argument(
        "--threads", type=int, default=0, help="torch CPU threads (0: torch's default; 1 is faster on a busy machine)"
    )
    bench.set_defaults(handler=_bench)

    export = subparsers.choices.get("export")
    if export is not None:  # holousd.usd._cli registered it first
        export.add_argument("--ply", type=Path, metavar="DIR",
                            help="also write every node's Gaussian splats as a standard 3DGS .ply (world frame; "
                            "DIR/<node>.ply, and DIR/scene.ply with all of them) for splat viewers and tools")
        export.description += (" --ply writes the splats in the layout of the 3D Gaussian Splatting code"
                               " (positions, SH DC and rest coefficients, opacity before the sigmoid, log scales,"
                               " rotation w first).")
        export.set_defaults(handler=_export_with_ply(export.get_default("handler")))


def _export_with_ply(usd_export):  # noqa: ANN001, ANN202 - the usd domain's handler; returns the wrapped one
    def handler(args: argparse.Namespace) -> int:
        from holousd._errors import HolousdError

        if getattr(args, "ply", None) is None:
            return usd_export(args)
        if args.ply.exists() and not args.ply.is_dir():
            raise HolousdError(f"{args.ply}: --ply takes a folder, and this is a file; give a folder path")
        from holousd.render._exchange import export_ply
        from holousd.usd import SceneGraph

        files = export_ply(SceneGraph.open(args.scene), args.ply)  # first: a failing splat export writes nothing
        print(f"wrote {len(files)} .ply files to {args.ply} ({files[-1].name}: the whole scene)")
        if args.sim is not None or args.usdz is not None or args.glb is not None:
            return usd_export(args)
        return 0

    return handler


def _set_threads(threads: int) -> None:
    if threads > 0:
        import torch

        torch.set_num_threads(threads)


def _render(args: argparse.Namespace) -> int:
    _set_threads(args.threads)
    from holousd.render._scene import render_video
    from holousd.usd import SceneGraph

    scene = SceneGraph.open(args.scene)
    width, height = args.resolution
    result = render_video(scene, args.out, cameras=args.cameras, frames=args.frames, width=width, height=height,
                          fps=args.fps, background=tuple(args.background), progress=True)  # fmt: skip
    print(f"rendered {len(result.pngs)} frames of {result.splats} splats "
          f"({result.seconds_per_frame:.3f} s/frame) to {args.out}")  # fmt: skip
    if result.mp4 is not None:
        print(f"video: {result.mp4}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from holousd.eval._bench_render import BenchConfig, bench_render

    _set_threads(args.threads)
    if args.iterations < 1:
        print("holousd bench-render: error: --iterations must be >= 1", file=sys.stderr)
        return 2
    config = BenchConfig(iterations=args.iterations, spacing_px=args.spacing_px,
                         lpips_weights=str(args.lpips_weights) if args.lpips_weights else None)  # fmt: skip
    report = bench_render(args.out, config, progress=True)
    print(f"splats: {report.total_splats} {report.splat_counts}")
    print(f"fit: {report.fit_seconds:.1f} s for {report.fit_iterations} steps (target <= 180 s)")
    print(
        f"held-out PSNR {report.heldout_psnr:.2f} dB (target >= 28), SSIM {report.heldout_ssim:.3f} (target >= 0.85), "
        f"LPIPS {report.heldout_lpips if report.heldout_lpips is not None else 'unavailable'}"
    )
    print(f"render: {report.render_seconds:.3f} s per 256x256 frame of {report.render_splats} splats (target <= 0.5 s)")
    print(f"wrote {args.out / 'bench_render.json'} and {args.out / 'bench_render.png'}")
    return 0
