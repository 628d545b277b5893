"""Sub-commands of the USD domain: ``info``, ``validate``, ``export``."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path

__all__ = ["add_commands"]


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register ``info``, ``validate`` and ``export`` on the ``holousd`` parser."""
    info = subparsers.add_parser(
        "info",
        help="summarise a scene: nodes, relations, physics, splat counts",
        description="Summarise a holousd scene: layers, stage metadata, and per node its support parent, "
        "touching siblings, mesh size, SDF resolution, splat count, mass and collider.",
    )
    info.add_argument("scene", type=Path, metavar="SCENE", help="scene file (.usda/.usdc/.usd/.usdz)")
    info.add_argument("--json", action="store_true", help="print JSON instead of a table")
    info.set_defaults(handler=_info)

    validate = subparsers.add_parser(
        "validate",
        help="check a scene with every OpenUSD validator and holousd's rules",
        description="Run all pxr.UsdValidation validators plus holousd's rules (stage metadata, support tree, "
        "mass and collider per object, resolvable assets, consistent splat arrays). Exit code 0 only when "
        "the scene is clean (no errors or warnings), 1 when problems were found, 2 when the file cannot be read.",
    )
    validate.add_argument("scene", type=Path, metavar="SCENE", help="scene file")
    validate.add_argument("--json", action="store_true", help="print a JSON report instead of text")
    validate.set_defaults(handler=_validate)

    export = subparsers.add_parser(
        "export",
        help="write a flattened physics scene for simulators and/or a USDZ package",
        description="Export a scene. --sim writes one flattened, self-contained physics scene (meshes, "
        "colliders, rigid bodies, materials, relations; no splats, cameras or SDF files) that Newton's "
        "ModelBuilder.add_usd, Isaac Sim and other UsdPhysics readers load. --usdz packages the full scene "
        "with all its assets. Existing outputs are replaced only once the new file is complete.",
    )
    export.add_argument("scene", type=Path, metavar="SCENE", help="scene file")
    export.add_argument("--sim", type=Path, metavar="OUT.usda", help="flattened physics scene to write")
    export.add_argument("--usdz", type=Path, metavar="OUT.usdz", help="USDZ package of the full scene to write")
    export.set_defaults(handler=_export)


def _open(path: Path):  # noqa: ANN202 - returns holousd.SceneGraph, imported lazily
    from holousd.usd._scene import SceneGraph

    return SceneGraph.open(path)


def _info(args: argparse.Namespace) -> int:
    summary = _open(args.scene).summary()
    if args.json:
        data = asdict(summary)
        data["total_splats"] = summary.total_splats
        print(json.dumps(data, indent=2))
        return 0
    print(f"scene: {summary.path}")
    print(f"layers (strongest first): {', '.join(Path(layer).name for layer in summary.layers)}")
    print(
        f"upAxis {summary.up_axis}, metersPerUnit {summary.meters_per_unit:g}, "
        f"kilogramsPerUnit {summary.kilograms_per_unit:g}, holousd schema {summary.schema_version}"
    )
    header = ("node", "id", "supported by", "beside", "faces", "sdf", "splats", "mass kg", "collider")
    rows = [header]
    for n in summary.nodes:
        rows.append(
            (
                n.name,
                str(n.instance_id),
                n.supported_by or "-",
                ",".join(n.beside) or "-",
                str(n.mesh_faces),
                "x".join(map(str, n.sdf_resolution)) if n.sdf_resolution else "-",
                str(n.splats),
                f"{n.mass_kg:.3f}" if n.mass_kg is not None else "static",
                f"{n.collider} ({n.collider_parts})" if n.collider else "none!",
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    for row in rows:
        print("  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip())
    print(f"{len(summary.nodes)} nodes, {summary.total_splats} splats")
    return 0


def _validate(args: argparse.Namespace) -> int:
    from holousd.usd._validate import validate

    report = validate(_open(args.scene).stage)
    if args.json:
        print(json.dumps(report.to_dict(), indent=2))
    else:
        for issue in report.issues:
            print(issue)
        errors = sum(i.severity == "error" for i in report.issues)
        warnings = sum(i.severity == "warning" for i in report.issues)
        verdict = "clean" if report.ok else "NOT clean"
        print(f"{args.scene}: {verdict} ({errors} errors, {warnings} warnings)", file=sys.stderr)
    return 0 if report.ok else 1


def _export(args: argparse.Namespace) -> int:
    from holousd._errors import HolousdError
    from holousd.usd._export import export_sim, export_usdz

    if args.sim is None and args.usdz is None:
        raise HolousdError("nothing to export: give --sim OUT.usda and/or --usdz OUT.usdz")
    for out in (args.sim, args.usdz):
        if out is not None and out.resolve() == args.scene.resolve():
            raise HolousdError(f"{out}: refusing to overwrite the input scene; choose another output path")
    scene = _open(args.scene)
    if args.sim is not None:
        print(f"wrote {export_sim(scene.stage, args.sim)}")
    if args.usdz is not None:
        print(f"wrote {export_usdz(scene.stage, args.usdz)}")
    return 0
