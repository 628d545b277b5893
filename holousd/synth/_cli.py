"""Sub-commands of the synth domain: ``example`` and ``synth``."""

from __future__ import annotations

import argparse
from pathlib import Path

from holousd._argtypes import positive_int, resolution

__all__ = ["add_commands"]


_SUITE_HELP = """suites:
  demo   one room showing everything (stack, touching siblings, thin plate, shelf, object against a wall);
         renders in well under a minute at the default size
  bench  6 varied procedural rooms: furniture against the walls, a table, small objects, stacks
  hard   one scene per physical failure mode, named after it: stack, against_wall, thin,
         small_beside_large, touching_siblings, shelf, top_only

Each scene goes to OUT/<scene>/: the capture in --format (native: observations.json, rgb/, masks/, depth/,
normals/), and ground truth in gt/: scene.usda (meshes, colliders, mass, friction, support and beside
relations; passes holousd validate), graph.json (support tree, beside pairs, poses, physical parameters,
observed fraction per object) and meshes/<name>.ply (watertight, object coordinates). Depth is metric
z-depth along the optical axis; normals are in the OpenCV camera frame; mask 0 is the room.
With --sensor phone, lidar or sfm the capture carries that device's defects (the model, channel by channel, is
documented in holousd/synth/_sensor.py and recorded in gt/graph.json); gt/cameras.json holds the true poses.
The same --seed gives byte-identical files."""


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register ``example`` and ``synth`` on the ``holousd`` parser."""
    synth = subparsers.add_parser(
        "synth",
        help="generate procedural benchmark scenes: rendered captures with complete ground truth",
        description="Generate procedural indoor scenes (rooms furnished with multi-part furniture and small "
        "objects placed by real support relations), ray-trace a hand-held camera sweep through each and write "
        "the capture plus complete ground truth.",
        epilog=_SUITE_HELP,
    )
    synth.add_argument("--suite", choices=("demo", "bench", "hard"), default="demo", help="which scenes to generate")
    synth.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder, one sub-folder per scene")
    synth.add_argument("--seed", type=int, default=0, help="seed of layouts, textures and camera paths")
    synth.add_argument("--frames", type=positive_int, default=100, help="frames rendered per scene")
    synth.add_argument(
        "--resolution", type=resolution, default="320x240", metavar="WxH", help="image size in pixels, e.g. 320x240"
    )
    synth.add_argument(
        "--format",
        choices=("native", "nerfstudio", "monosdf"),
        default="native",
        help="capture format of the observations (see holousd/io/FORMAT.md)",
    )
    synth.add_argument(
        "--scenes",
        default=None,
        metavar="NAME[,NAME...]",
        help="comma-separated scenes of the suite to generate; None = all",
    )
    synth.add_argument(
        "--sensor",
        choices=("clean", "phone", "lidar", "sfm", "video"),
        default="clean",
        help="what the capture device does to the frames: clean = the renderer's exact depth, normals, masks and "
        "poses; phone = a phone's LiDAR depth (half resolution, noisy, holes), a video segmenter's masks, a "
        "tracker's drifting poses, auto-exposure, blur, no normals; lidar = a depth camera on a tracked rig "
        "(less of each); sfm = that depth camera with poses off by about a centimetre and a degree per frame "
        "(structure from motion, a weak tracker); video = the phone without its depth sensor (colour, masks and poses "
        "only). The ground truth in gt/ stays exact",
    )
    synth.add_argument("--overwrite", action="store_true", help="replace scene folders generated before")
    synth.add_argument("--no-progress", action="store_true", help="do not show progress bars on stderr")
    synth.set_defaults(handler=_synth)

    example = subparsers.add_parser(
        "example",
        help="write the bundled example scene (table, book, mug, box) to a folder",
        description="Write a small, complete example scene to OUT/scene.usda with its assets: a floor and wall, "
        "a table (explicit convex decomposition), a book on it, a mug on the book and a box beside the book, "
        "with meshes, SDF grids, splats bound to faces, physics and support relations.",
    )
    example.add_argument("out", type=Path, metavar="OUT", help="folder to write scene.usda and assets/ into")
    example.add_argument("--seed", type=int, default=0, help="seed of the splat sampling")
    example.add_argument("--overwrite", action="store_true", help="replace an existing OUT/scene.usda")
    example.set_defaults(handler=_example)


def _synth(args: argparse.Namespace) -> int:
    import time

    from holousd.synth._generate import SynthConfig, generate_suite

    width, height = args.resolution
    config = SynthConfig(
        seed=args.seed,
        frames=args.frames,
        width=width,
        height=height,
        format=args.format,
        progress=not args.no_progress,
        overwrite=args.overwrite,
        sensor=args.sensor,
    )
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()] if args.scenes else None
    start = time.perf_counter()
    results = generate_suite(args.suite, args.out, config, scenes=scenes)
    for r in results:
        print(f"{r.folder}: {r.objects} objects, {r.frames} frames")
    print(f"wrote {len(results)} scene(s) to {args.out} in {time.perf_counter() - start:.1f} s")
    print(f"next: holousd validate {results[0].folder / 'gt' / 'scene.usda'}")
    return 0


def _example(args: argparse.Namespace) -> int:
    from holousd.synth._example import build_example_scene

    path = build_example_scene(args.out, seed=args.seed, overwrite=args.overwrite)
    print(f"wrote {path}")
    print(f"next: holousd info {path}")
    return 0
