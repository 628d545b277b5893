"""Sub-commands of the end-to-end pipeline: ``reconstruct``, ``eval``, ``bench`` and ``demo``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from holousd._argtypes import emit_json, positive_int, resolution

__all__ = ["add_commands"]

_RECONSTRUCT_EPILOG = """stages (layers in DIR):
  observe     00_observe.usda     cameras, image references, one node per instance id
  fit         10_fit.usda         per-object SDF grids and watertight meshes
  search      15_search.usda      completion candidates per object, the lowest-energy one kept along the
                                  support tree (--search tree|ground|none)
  physics     20_physics.usda     support tree, beside pairs, settling, colliders, mass, friction 0.5
  appearance  30_appearance.usda  Gaussian splats fitted on the meshes (every 8th frame held out)
DIR/scene.usda sublayers the last stage's layer. Each layer records its wall time, peak memory, config and input
hash in customLayerData (holousd: {stage: {...}}); --resume skips stages whose record matches."""


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register ``reconstruct``, ``eval``, ``bench`` and ``demo`` on the ``holousd`` parser."""
    from holousd.stages._pipeline import STAGES

    rec = subparsers.add_parser(
        "reconstruct",
        help="capture -> simulation-ready USD scene (observe, fit, search, physics set-up, appearance)",
        description="Run the whole pipeline on a capture with instance masks and write DIR/scene.usda.",
        epilog=_RECONSTRUCT_EPILOG,
    )
    rec.add_argument("input", type=Path, metavar="INPUT", help="capture folder or file (any format holousd.io reads)")
    rec.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    rec.add_argument("--preset", choices=("fast", "default", "best"), default="default", help="speed / accuracy")
    rec.add_argument("--until", choices=STAGES, default=None, help="last stage to run (default: all)")
    rec.add_argument("--resume", action="store_true", help="skip stages whose layer is up to date")
    rec.add_argument("--seed", type=int, default=0, help="seed of every stage")
    rec.add_argument("--search", choices=("tree", "ground", "none"), default="tree",
                     help="s2 search: 'tree' (completion candidates chosen along the support tree, the "
                     "method), 'ground' (each object against the room only), 'none' (the fitted shapes); "
                     "default tree")  # fmt: skip
    rec.add_argument("--threads", type=positive_int, default=None,
                     help="torch CPU threads of the fit and appearance, and worker processes of the search (default: "
                     "torch's; one search worker per core)")  # fmt: skip
    rec.add_argument("--ray", default=None, metavar="ADDRESS",
                     help="propose and score the search's completion candidates as Ray tasks: 'local', 'auto' (the "
                     "running cluster) or HOST:PORT; the same scene as without (needs holousd[ray])")  # fmt: skip
    rec.add_argument("--refine-poses", choices=("auto", "on", "off"), default="auto",
                     help="camera poses, with metric depth: 'auto' aligns them against the depth and uses the "
                     "aligned ones when they are clearly better than the capture's (poses from structure from motion "
                     "or a weak tracker; a good tracker's are kept), 'on' uses them whenever the frames overlap, "
                     "'off' never looks; the fit layer's cameras record how far each moved; default auto")  # fmt: skip
    add_depth_arguments(rec)
    rec.add_argument("--no-appearance", action="store_true", help="skip the appearance stage")
    rec.add_argument("--no-progress", action="store_true", help="no progress bars on stderr")
    rec.set_defaults(handler=_reconstruct)

    ev = subparsers.add_parser(
        "eval",
        help="evaluate a reconstruction against synth ground truth (geometry, render, physics, cost)",
        description="Geometry (Chamfer cm, F-score at 5 cm, normal consistency), render PSNR/SSIM at held-out "
        "frames, OR%, Stable% and penetration volume, and cost per stage.",
    )
    ev.add_argument("recon", type=Path, metavar="RECON_DIR", help="reconstruct output folder or a scene file")
    ev.add_argument("--gt", type=Path, required=True, metavar="GT_DIR", help="synth scene folder or its gt/ folder")
    ev.add_argument("--json", action="store_true", help="print JSON instead of a table")
    ev.add_argument("--samples", type=positive_int, default=200_000, help="surface samples for the geometry metrics")
    ev.add_argument("--no-physics", action="store_true", help="do not run the stability verdict")
    ev.set_defaults(handler=_eval)

    bench = subparsers.add_parser(
        "bench",
        help="reconstruct + eval every scene of a synth suite per preset; JSON, charts, failure-mode table",
        description="Writes OUT/bench.json (every evaluation, with the command line and the machine), OUT/bench.png "
        "(F1, Chamfer, PSNR, Stable% against wall time, one point per scene and preset), OUT/summary.md (means per "
        "preset) and, for the hard suite, OUT/hard_stable.md (Stable% per failure mode). With --table, only prints "
        "the summary table of existing bench.json files (the README's results table is made this way).",
    )
    bench.add_argument("--suite", choices=("bench", "hard", "demo"), default="bench", help="synth suite")
    bench.add_argument("--presets", default="fast,default", help="comma-separated presets")
    bench.add_argument("--out", type=Path, default=None, metavar="DIR", help="output folder (required unless --table)")
    bench.add_argument("--table", type=Path, nargs="+", default=None, metavar="JSON",
                       help="print the markdown summary of these bench.json files and exit")  # fmt: skip
    bench.add_argument("--scenes", default=None, metavar="A,B", help="only these scenes of the suite")
    bench.add_argument("--search", default="tree", metavar="MODES",
                       help="comma-separated s2 search modes run with every preset (tree, ground, none): the "
                       "ablation rows; a mode other than tree is labelled PRESET@MODE (default: tree)")  # fmt: skip
    bench.add_argument("--sensor", default="clean", metavar="SENSORS",
                       help="comma-separated sensor models of the generated captures (clean, phone, lidar, sfm, "
                       "video; see holousd synth --help): each preset runs on each, side by side, a run on another "
                       "sensor than clean labelled PRESET[SENSOR] (default: clean)")  # fmt: skip
    bench.add_argument("--data", type=Path, default=None, metavar="DIR",
                       help="existing synth output of the suite (default: generate into OUT/data)")  # fmt: skip
    bench.add_argument("--frames", type=positive_int, default=60, help="frames per generated scene")
    bench.add_argument("--resolution", type=resolution, default=(160, 120), metavar="WxH", help="generated size")
    bench.add_argument("--seed", type=int, default=0, help="seed of generation and reconstruction")
    bench.add_argument("--threads", type=positive_int, default=None, help="torch CPU threads (default: torch's)")
    bench.add_argument("--ray", default=None, metavar="ADDRESS",
                       help="run the scenes as Ray tasks: 'local' (a Ray instance started here), 'auto' (the "
                       "running cluster) or HOST:PORT; the figures are those of a sequential run (needs "
                       "holousd[ray])")  # fmt: skip
    bench.set_defaults(handler=_bench)

    demo = subparsers.add_parser(
        "demo",
        help="synthesise the demo scene, reconstruct it (fast), evaluate it and write an HTML report",
        description="A quick end-to-end run (a few minutes on 2 CPU cores) ending in OUT/report.html.",
    )
    demo.add_argument("--out", type=Path, default=Path("holousd_demo"), metavar="DIR", help="output folder")
    demo.add_argument("--frames", type=positive_int, default=40, help="frames of the synthesised capture")
    demo.add_argument("--resolution", type=resolution, default=(160, 120), metavar="WxH", help="capture size")
    demo.add_argument("--preset", choices=("fast", "default", "best"), default="fast", help="reconstruction preset")
    demo.add_argument("--seed", type=int, default=0, help="seed of generation and reconstruction")
    demo.add_argument("--threads", type=positive_int, default=None, help="torch CPU threads (default: torch's)")
    demo.add_argument("--search", choices=("tree", "ground", "none"), default="tree", help="s2 search mode")
    demo.add_argument("--sensor", choices=("clean", "phone", "lidar", "sfm", "video"), default="clean",
                      help="sensor model of the synthesised capture (see holousd synth --help)")  # fmt: skip
    demo.set_defaults(handler=_demo)


def add_depth_arguments(parser: argparse.ArgumentParser) -> None:
    """``--depth`` and ``--depth-option`` (where the depth the stages read comes from)."""
    parser.add_argument("--depth", default="auto", metavar="SOURCE",
                        help="where depth comes from: 'auto' (the capture's; a capture without depth gets depth by "
                        "multi-view stereo from its colour frames and poses), 'capture' (the capture's only; without "
                        "it the masks alone, a visual hull), 'stereo', 'learned' (a monocular depth network from "
                        "--depth-option weights=PATH) or a holousd.depth plug-in; default auto")  # fmt: skip
    parser.add_argument("--depth-option", action="append", default=[], metavar="KEY=VALUE",
                        help="an option of the depth prior, repeatable (learned: weights=PATH, kind=relative|metric, "
                        "output=depth|inverse, device=cpu; stereo: near=, far=, window=, min_ncc=, ...)")  # fmt: skip


def depth_options(args: argparse.Namespace) -> dict[str, str]:
    """``--depth-option KEY=VALUE`` pairs as a dict (a one-line error for a malformed one)."""
    from holousd._errors import HolousdError

    out = {}
    for item in args.depth_option:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise HolousdError(f"--depth-option {item!r}: write KEY=VALUE, e.g. weights=depth_model.pt2")
        out[key.strip()] = value.strip()
    return out


def _reconstruct(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from holousd.stages._pipeline import preset, reconstruct

    config = preset(args.preset, seed=args.seed, progress=not args.no_progress, threads=args.threads,
                    search=args.search)  # fmt: skip
    config = replace(config, fit=replace(config.fit, refine_poses=args.refine_poses),
                     observe=replace(config.observe, depth=args.depth, depth_options=depth_options(args)))
    if args.no_appearance:
        config = replace(config, appearance=replace(config.appearance, enabled=False))
    if args.ray:
        from holousd._tasks import require_ray

        require_ray()
        config = replace(config, search=replace(config.search, ray=args.ray))
    result = reconstruct(args.input, args.out, config, until=args.until, resume=args.resume)
    ran = [s.name for s in result.stages if not s.skipped]
    print(f"wrote {result.scene_file} ({len(ran)} stage(s) run, {result.total_s:.1f} s, "
          f"peak {result.peak_mem_mb:.0f} MiB)")  # fmt: skip
    print(f"next: holousd info {result.scene_file}")
    return 0


def format_evaluation(d: dict) -> str:
    """Human-readable table of an evaluation dict (``SceneEvaluation.to_dict()``)."""

    def f(v: object, spec: str = ".2f") -> str:
        return "-" if v is None else (format(v, spec) if isinstance(v, float) else str(v))

    g, r, p, c = d["geometry"], d["render"], d["physics"], d["cost"]
    lines = [
        f"geometry scene:   Chamfer {f(g['scene']['chamfer_cm'])} cm  F1 {f(g['scene']['f1'], '.1f')}  "
        f"NC {f(g['scene']['nc'], '.1f')}",
        f"geometry objects: Chamfer {f(g['objects']['chamfer_cm'])} cm  F1 {f(g['objects']['f1'], '.1f')}  "
        f"NC {f(g['objects']['nc'], '.1f')}",
        f"render:           PSNR {f(r['psnr'])} dB  SSIM {f(r['ssim'], '.3f')}"
        f"  (meshes: PSNR {f(r.get('mesh_psnr'))} dB textured, {f(r.get('vertex_psnr'))} dB in per-point colour)",
        f"physics:          OR {f(p['or_pct'], '.1f')}%  Stable {f(p['stable_pct'], '.1f')}%  "
        f"penetration {f(p['penetration_cm3'])} cm^3"
        + (
            f"  ({p['solver']}; {p['cross_check']['solver']}: Stable {p['cross_check']['stable_pct']:.1f}%, "
            f"agreement {p['cross_check']['agreement_pct']:.0f}%)"
            if p.get("cross_check")
            else ""
        ),
        f"geometry records: worst collider reach outside the mesh {f(p.get('max_collider_reach_cm'))} cm  "
        f"penetration {f(p.get('max_penetration_cm'))} cm  move from the fit {f(p.get('max_fit_shift_cm'))} cm",
        f"cost:             {f(c['total_s'], '.1f')} s  peak {f(c['peak_mem_mb'], '.0f')} MiB  "
        + "  ".join(f"{k} {v:.1f}s" for k, v in c["stages"].items()),
        "",
        "per object: Chamfer / F1 / NC against the complete ground-truth surface; f1_seen: its observed part only",
        f"{'object':<14}{'recon':<14}{'chamfer_cm':>11}{'f1':>7}{'f1_seen':>8}{'nc':>6}  {'stable':<7}parent gt/recon",
    ]
    for o in d["objects"]:
        lines.append(
            f"{o['name']:<14}{f(o['recon']):<14}{f(o['chamfer_cm']):>11}{f(o['f1'], '.1f'):>7}"
            f"{f(o.get('f1_visible'), '.1f'):>8}{f(o['nc'], '.0f'):>6}  "
            f"{('yes' if o['stable'] else 'NO') if o['stable'] is not None else '-':<7}"
            f"{o['parent_gt']}/{o['parent_recon']}"
        )
    lines += [f"note: {n}" for n in d["notes"]]
    return "\n".join(lines)


def _eval(args: argparse.Namespace) -> int:
    from holousd.eval._scene_eval import EvalConfig, evaluate_scene

    result = evaluate_scene(args.recon, args.gt, EvalConfig(samples=args.samples, physics=not args.no_physics))
    d = result.to_dict()
    if args.json:
        emit_json(args, d)
    else:
        print(format_evaluation(d))
    return 0


def _bench(args: argparse.Namespace) -> int:
    from holousd._errors import HolousdError
    from holousd.eval._bench_suite import BenchSuiteConfig, load_bench, run_bench, summary_table

    if args.table:
        print(summary_table([load_bench(path) for path in args.table]), end="")
        return 0
    if args.out is None:
        raise HolousdError("--out DIR is required (or --table FILE to summarise existing results)")
    from holousd.stages._search import MODES

    modes = [m.strip() for m in args.search.split(",") if m.strip()]
    bad = [m for m in modes if m not in MODES]
    if bad or not modes:
        raise HolousdError(f"--search {args.search!r}: choose among {', '.join(MODES)} (comma-separated)")
    presets = [p if m == "tree" else f"{p}@{m}" for p in (p.strip() for p in args.presets.split(",") if p.strip())
               for m in modes]  # fmt: skip
    scenes = [s.strip() for s in args.scenes.split(",")] if args.scenes else None
    config = BenchSuiteConfig(suite=args.suite, presets=presets, scenes=scenes, data=args.data, frames=args.frames,
                              width=args.resolution[0], height=args.resolution[1], seed=args.seed,
                              threads=args.threads, ray=args.ray,
                              sensors=[s.strip() for s in args.sensor.split(",") if s.strip()])  # fmt: skip
    if args.ray is not None:
        from holousd._tasks import require_ray

        require_ray()
    result = run_bench(args.out, config)
    for path in result.files:
        print(f"wrote {path}")
    return 0


def _demo(args: argparse.Namespace) -> int:
    from holousd.eval._report import DemoConfig, run_demo

    config = DemoConfig(frames=args.frames, width=args.resolution[0], height=args.resolution[1], preset=args.preset,
                        seed=args.seed, threads=args.threads, search=args.search, sensor=args.sensor)  # fmt: skip
    report = run_demo(args.out, config)
    print(f"demo report: {report}", file=sys.stdout)
    return 0
