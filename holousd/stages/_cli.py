"""Sub-commands of the stages domain: ``fit`` (s0_observe + s1_fit) and ``bench-fit``."""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from holousd._argtypes import positive_int
from holousd.stages._pipeline_cli import add_depth_arguments, depth_options

__all__ = ["add_commands", "drop_depth", "run_fit"]

_PRESET_HELP = """presets (holousd.stages._fit):
  fast     TSDF / visual-hull initialisation + 40 volume-rendering steps; about half a minute per
           18-object scene on 2 CPU cores
  default  finer grids, 200 refinement steps of 2048 rays
  best     finest grids, 600 refinement steps of 4096 rays

Writes OUT/00_observe.usda (cameras, one node per instance id, background) and OUT/10_fit.usda (per-object SDF
grids under OUT/assets/10_fit/, watertight meshes in object coordinates, object poses, background mesh), plus
OUT/fit_report.json. Fitting needs instance masks; depth (metric or relative) and normals are used when the
capture has them."""


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register ``fit`` and ``bench-fit`` on the ``holousd`` parser."""
    fit = subparsers.add_parser(
        "fit",
        help="fit per-object SDFs and watertight meshes to a capture (stages s0_observe + s1_fit)",
        description="Recover every instance's visible geometry from a capture with instance masks: one SDF grid "
        "and one watertight mesh per object, written as USD layers 00_observe.usda and 10_fit.usda.",
        epilog=_PRESET_HELP,
    )
    fit.add_argument("input", type=Path, metavar="INPUT", help="capture folder or file (any format holousd.io reads)")
    fit.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder for the layers")
    fit.add_argument("--preset", choices=("fast", "default", "best"), default="default", help="speed / accuracy")
    fit.add_argument("--seed", type=int, default=0, help="seed of ray sampling")
    fit.add_argument("--iterations", type=int, default=None, help="refinement steps (default: the preset's)")
    fit.add_argument("--no-depth", action="store_true",
                     help="ignore the capture's depth and normals and estimate none (the masks alone)")  # fmt: skip
    add_depth_arguments(fit)
    fit.add_argument("--refine-poses", choices=("auto", "on", "off"), default="auto",
                     help="camera poses, with metric depth: aligned against the depth and used when clearly better "
                     "than the capture's ('auto'), whenever the frames overlap ('on'), or never looked at ('off'); see "
                     "holousd reconstruct --help")  # fmt: skip
    fit.add_argument("--threads", type=positive_int, default=None, help="torch CPU threads (default: torch's)")
    fit.add_argument("--no-progress", action="store_true", help="do not show a progress bar on stderr")
    fit.set_defaults(handler=_fit_command)

    bench = subparsers.add_parser(
        "bench-fit",
        help="benchmark s1_fit geometry on a synth suite: accuracy against wall time per preset",
        description="Generate (or reuse) a synth suite, fit every scene with each preset, with and without the "
        "depth input, and report OR%, visible-surface F-score at 5 cm and Chamfer distance against the ground "
        "truth next to wall time and peak memory. Writes OUT/bench_fit.json and the chart OUT/bench_fit.png.",
    )
    bench.add_argument("--suite", choices=("demo", "bench", "hard"), default="bench", help="synth suite")
    bench.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    bench.add_argument("--data", type=Path, default=None, metavar="DIR",
                       help="existing synth output of the suite (default: generate into OUT/data)")  # fmt: skip
    bench.add_argument("--presets", default="fast,default", help="comma-separated presets to run")
    bench.add_argument("--scenes", default=None, metavar="NAME[,NAME...]", help="only these scenes")
    bench.add_argument("--depth", choices=("both", "with", "without"), default="both",
                       help="run with the depth input, without it (RGB + masks only), or both")  # fmt: skip
    bench.add_argument("--resolution", default="256x256", metavar="WxH", help="resolution of generated scenes")
    bench.add_argument("--frames", type=positive_int, default=100, help="frames per generated scene")
    bench.add_argument("--seed", type=int, default=0, help="seed of generation and fitting")
    bench.add_argument("--threads", type=positive_int, default=None, help="torch CPU threads (default: torch's)")
    bench.set_defaults(handler=_bench_command)


# --------------------------------------------------------------------------------------------- fit
def drop_depth(obs: Any) -> Any:
    """The same capture without depth and normals (RGB, masks and cameras only), still lazy."""
    from holousd.io._observations import LazyArray, Observations

    def lazy(channel: str, read: Any) -> list[LazyArray]:
        return [LazyArray((lambda i=i: read(i)), obs.source(i, channel)) for i in range(len(obs))]

    return Observations(
        rgb=lazy("rgb", obs.rgb),
        intrinsics=obs.intrinsics,
        poses=obs.poses,
        width=obs.width,
        height=obs.height,
        masks=lazy("mask", obs.mask) if obs.has_masks else None,
        frame_ids=obs.frame_ids,
        instance_names=obs.instance_names,
        root=obs.root,
        camera_file=obs.camera_file,
    )


def run_fit(input_path: Path, out: Path, preset: str, *, seed: int = 0, iterations: int | None = None,
            use_depth: bool = True, progress: bool = True, threads: int | None = None,
            refine_poses: str = "auto", depth: str = "auto",
            depth_options: dict[str, str] | None = None) -> dict[str, Any]:  # fmt: skip
    """Load a capture, run s0_observe and s1_fit into ``out`` and return a JSON-ready report (``depth``,
    ``depth_options``: where the depth comes from, as :class:`holousd.stages._observe.ObserveConfig` says)."""
    from holousd._atomic import folder_transaction
    from holousd._paths import output_folder
    from holousd.io import load
    from holousd.stages import _fit, _observe
    from holousd.stages._pipeline import OUTPUT_PATTERNS, checked, with_depth_source

    start = time.perf_counter()
    out = output_folder(out, "--out folder", create=False)
    from holousd._errors import HolousdError

    if not use_depth and depth not in ("auto", "capture"):
        raise HolousdError(f"--no-depth with --depth {depth}: choose one (--no-depth fits from the masks alone)")
    obs = load(input_path)
    if not use_depth:
        obs = drop_depth(obs)
    config = replace(_fit.PRESETS[preset], seed=seed, progress=progress, threads=threads, refine_poses=refine_poses)
    if iterations is not None:
        config = replace(config, iterations=iterations)
    def say(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    observe = _observe.ObserveConfig(depth=depth if use_depth else "capture", depth_options=depth_options or {})
    obs = with_depth_source(checked(obs, say), observe, config, say)
    out.mkdir(parents=True, exist_ok=True)
    with folder_transaction(out, OUTPUT_PATTERNS):
        scene = _observe.run(obs, out, observe)
        result = _fit.fit(scene, obs, config)
    wall = time.perf_counter() - start
    return {
        "input": str(input_path),
        "out": str(out),
        "preset": preset,
        "depth": obs.depth_kind or "none",
        "depth_prior": obs.metadata.get("depth_prior"),
        "seed": seed,
        "wall_time_s": wall,
        "fit_time_s": result.wall_time_s,
        "timings_s": result.timings,
        "peak_memory_mb": result.peak_memory_mb,
        "floor_z": result.floor_z,
        "background_faces": result.background_faces,
        "final_losses": result.final_losses,
        "poses": _pose_report(result.poses),
        "objects": [
            {
                "name": o.name,
                "instance_id": o.instance_id,
                "voxel_size": o.voxel_size,
                "resolution": list(o.resolution),
                "faces": o.faces,
                "watertight": o.watertight,
                "fallback": o.fallback,
                "pixels": o.pixels,
            }
            for o in result.objects
        ],  # fmt: skip
        "layers": [str(out / _observe.OBSERVE_LAYER), str(out / _fit.FIT_LAYER)],
    }


def _pose_report(aligned: Any) -> dict[str, Any] | None:
    """What the fit's pose alignment found, JSON-ready (None: not run)."""
    if aligned is None:
        return None
    finite = {"residual_before_m": aligned.residual_before, "residual_after_m": aligned.residual_after}
    return {"applied": aligned.applied, "pairs": aligned.pairs,
            **{key: value if value < float("inf") else None for key, value in finite.items()},
            "moved_m": aligned.translation.tolist(), "turned_deg": aligned.rotation_deg.tolist()}  # fmt: skip


def _fit_command(args: argparse.Namespace) -> int:
    from holousd._atomic import atomic_path

    report = run_fit(args.input, args.out, args.preset, seed=args.seed, iterations=args.iterations,
                     use_depth=not args.no_depth, progress=not args.no_progress, threads=args.threads,
                     refine_poses=args.refine_poses, depth=args.depth, depth_options=depth_options(args))  # fmt: skip
    with atomic_path(args.out / "fit_report.json") as tmp:
        tmp.write_text(json.dumps(report, indent=2))
    meshes = sum(1 for o in report["objects"] if o["faces"])
    print(
        f"fitted {meshes}/{len(report['objects'])} objects in {report['wall_time_s']:.1f} s "
        f"(peak {report['peak_memory_mb']:.0f} MiB, depth: {report['depth']}) -> {report['layers'][1]}"
    )
    return 0


# --------------------------------------------------------------------------------------------- bench
def _bench_job(scene_dir: str, out: str, preset: str, seed: int, use_depth: bool,
               threads: int | None = None) -> dict[str, Any]:  # fmt: skip
    """One fit + evaluation, run in a fresh process so that its peak memory is its own."""
    from holousd.eval._geometry import evaluate_fit

    report = run_fit(Path(scene_dir), Path(out), preset, seed=seed, use_depth=use_depth, progress=False,
                     threads=threads)  # fmt: skip
    metrics = evaluate_fit(scene_dir, Path(out) / "10_fit.usda", seed=seed)
    report["metrics"] = {
        "object_rate": metrics.object_rate,
        "missing": metrics.missing,
        "visible": asdict(metrics.visible),
        "complete": asdict(metrics.complete),
        "per_object": {k: {"fscore": v.fscore, "chamfer_cm": v.chamfer_cm} for k, v in metrics.per_object.items()},
    }
    return report


def _run_isolated(*args: Any) -> dict[str, Any]:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_bench_job, *args).result()


def _bench_command(args: argparse.Namespace) -> int:
    from holousd._atomic import atomic_path
    from holousd._errors import HolousdError
    from holousd.stages._fit import PRESETS

    presets = [p.strip() for p in args.presets.split(",") if p.strip()]
    unknown = [p for p in presets if p not in PRESETS]
    if unknown:
        raise HolousdError(f"unknown preset {unknown[0]!r}; choose from {', '.join(PRESETS)}")
    wanted = [s.strip() for s in args.scenes.split(",") if s.strip()] if args.scenes else None
    data = args.data
    if data is None:  # generate what is not there yet, only the scenes asked for
        from holousd.synth import SynthConfig, generate_suite, scene_names

        w, h = (int(v) for v in args.resolution.lower().split("x"))
        data = args.out / "data"
        scenes = wanted or scene_names(args.suite)
        todo = [s for s in scenes if not (data / s / "gt" / "graph.json").is_file()]
        if todo:
            generate_suite(args.suite, data, SynthConfig(seed=args.seed, frames=args.frames, width=w, height=h),
                           scenes=todo)  # fmt: skip
    else:
        index_file = Path(data) / "suite.json"
        if not index_file.is_file():
            raise HolousdError(f"{index_file}: no synth suite here; run 'holousd synth --suite {args.suite} "
                               f"--out {data}'")  # fmt: skip
        scenes = [s["folder"] for s in json.loads(index_file.read_text())["scenes"]]
        missing = [s for s in wanted or [] if s not in scenes]
        if missing:
            raise HolousdError(f"{index_file}: no scene {missing[0]!r} here (it has {', '.join(scenes)})")
        scenes = [s for s in scenes if wanted is None or s in wanted]
    modes = {"both": [True, False], "with": [True], "without": [False]}[args.depth]
    runs = []
    from tqdm import tqdm

    jobs = [(p, d, s) for p in presets for d in modes for s in scenes]
    for preset, use_depth, scene in tqdm(jobs, desc="bench-fit", file=sys.stderr):
        out = args.out / "runs" / f"{preset}_{'depth' if use_depth else 'nodepth'}" / scene
        report = _run_isolated(str(Path(data) / scene), str(out), preset, args.seed, use_depth, args.threads)
        report["scene"] = scene
        runs.append(report)
        m = report["metrics"]["visible"]
        print(f"{preset:8s} {'depth' if use_depth else 'no-depth':8s} {scene:20s} F1 {m['fscore']:5.1f}  "
              f"CD {m['chamfer_cm']:5.2f} cm  OR {report['metrics']['object_rate']:5.1f}%  "
              f"{report['wall_time_s']:6.1f} s  {report['peak_memory_mb']:6.0f} MiB", file=sys.stderr)  # fmt: skip
    summary = _summarise(runs)
    result = {"suite": args.suite, "data": str(data), "scenes": scenes, "summary": summary, "runs": runs}
    with atomic_path(args.out / "bench_fit.json") as tmp:
        tmp.write_text(json.dumps(result, indent=2))
    _chart(summary, args.out / "bench_fit.png")
    for row in summary:
        print(
            f"{row['preset']:8s} {row['depth']:8s} F1@5cm {row['fscore']:5.1f}  Chamfer {row['chamfer_cm']:5.2f} cm  "
            f"OR {row['object_rate']:5.1f}%  {row['wall_time_s']:6.1f} s/scene  peak {row['peak_memory_mb']:.0f} MiB"
        )
    return 0


def _summarise(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    import numpy as np

    rows = []
    keys = sorted({(r["preset"], r["depth"]) for r in runs}, key=lambda k: (k[0], k[1]))
    for preset, depth in keys:
        sel = [r for r in runs if r["preset"] == preset and r["depth"] == depth]
        rows.append({
            "preset": preset,
            "depth": depth,
            "scenes": len(sel),
            "fscore": float(np.mean([r["metrics"]["visible"]["fscore"] for r in sel])),
            "chamfer_cm": float(np.mean([r["metrics"]["visible"]["chamfer_cm"] for r in sel])),
            "fscore_complete": float(np.mean([r["metrics"]["complete"]["fscore"] for r in sel])),
            "object_rate": float(np.mean([r["metrics"]["object_rate"] for r in sel])),
            "wall_time_s": float(np.mean([r["wall_time_s"] for r in sel])),
            "wall_time_max_s": float(np.max([r["wall_time_s"] for r in sel])),
            "peak_memory_mb": float(np.max([r["peak_memory_mb"] for r in sel])),
        })  # fmt: skip
    return rows


def _chart(summary: list[dict[str, Any]], path: Path) -> None:
    """Two scatter panels (F-score and Chamfer against wall time) drawn with PIL."""
    from PIL import Image, ImageDraw

    from holousd._atomic import atomic_path

    width, height = 1000, 460
    img = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(img)
    colours = {"metric": (31, 119, 180), "none": (214, 39, 40), "relative": (44, 160, 44)}
    times = [r["wall_time_s"] for r in summary] or [1.0]
    t_max = max(times) * 1.15
    cd_max = max([r["chamfer_cm"] for r in summary] + [1.0]) * 1.2
    panels = [
        ("visible F-score @ 5 cm (%)", "fscore", 0.0, 100.0),
        ("visible Chamfer (cm)", "chamfer_cm", 0.0, cd_max),
    ]
    for p, (title, key, y_lo, y_hi) in enumerate(panels):
        x0, y0, x1, y1 = 70 + p * 500, 40, 460 + p * 500, 400
        draw.rectangle([x0, y0, x1, y1], outline="black")
        draw.text((x0, 15), title + " vs wall time per scene", fill="black")
        draw.text(((x0 + x1) // 2 - 40, y1 + 30), "wall time (s)", fill="black")
        for j in range(5):
            ty = y1 - j * (y1 - y0) / 4
            draw.line([x0 - 4, ty, x0, ty], fill="black")
            draw.text((x0 - 45, ty - 6), f"{y_lo + j * (y_hi - y_lo) / 4:.1f}", fill="black")
            tx = x0 + j * (x1 - x0) / 4
            draw.line([tx, y1, tx, y1 + 4], fill="black")
            draw.text((tx - 10, y1 + 8), f"{j * t_max / 4:.0f}", fill="black")
        for r in summary:
            x = x0 + (x1 - x0) * r["wall_time_s"] / t_max
            y = y1 - (y1 - y0) * (min(r[key], y_hi) - y_lo) / max(y_hi - y_lo, 1e-9)
            c = colours.get(r["depth"], (0, 0, 0))
            draw.ellipse([x - 6, y - 6, x + 6, y + 6], fill=c, outline="black")
            draw.text((x + 9, y - 7), f"{r['preset']} ({'depth' if r['depth'] != 'none' else 'no depth'})", fill=c)
    draw.text((70, height - 22), "blue: with depth, red: RGB + masks only; one point per preset, mean over scenes",
              fill="black")  # fmt: skip
    with atomic_path(path) as tmp:
        img.save(tmp, format="PNG")
