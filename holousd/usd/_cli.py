"""Sub-commands of the USD domain: ``info``, ``validate``, ``export``."""

from __future__ import annotations

import argparse
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

from holousd._argtypes import emit_json
from holousd._errors import SceneError

__all__ = ["add_commands"]


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register ``info``, ``validate`` and ``export`` on the ``holousd`` parser."""
    info = subparsers.add_parser(
        "info",
        help="summarise a scene: nodes, relations, physics, splat counts",
        description="Summarise a holousd scene: layers, stage metadata, and per node its support parent, "
        "touching siblings, mesh size, SDF resolution, splat count, mass and collider, and (where the physics "
        "set-up recorded them) its move from the fitted pose, its collider's reach outside the rendered mesh and "
        "its mesh's deepest penetration into another node, in cm.",
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
        help="write a physics scene for simulators, a USDZ package, glTF meshes and/or 3DGS .ply splats",
        description="Export a scene. --sim writes one flattened, self-contained physics scene (meshes, "
        "colliders, rigid bodies, materials, relations; no splats, cameras or SDF files) that Newton's "
        "ModelBuilder.add_usd, Isaac Sim and other UsdPhysics readers load; a scene that holousd validate finds "
        "broken for simulation is refused unless --force. --usdz packages the full scene with all its assets. "
        "--glb writes the coloured meshes as glTF binaries (Y-up) for game engines. "
        "Existing outputs are replaced only once the new file is complete.",
    )
    export.add_argument("scene", type=Path, metavar="SCENE", help="scene file")
    export.add_argument("--sim", type=Path, metavar="OUT.usda", help="flattened physics scene to write")
    export.add_argument("--usdz", type=Path, metavar="OUT.usdz", help="USDZ package of the full scene to write")
    export.add_argument("--glb", type=Path, metavar="DIR",
                        help="every node's coloured mesh as glTF binary (DIR/<node>.glb, and DIR/scene.glb with all of "
                        "them; world frame turned Y-up, metres) for game engines and viewers")  # fmt: skip
    export.add_argument("--force", action="store_true",
                        help="export even when holousd validate finds errors that break simulation (support cycle, "
                        "dangling relation, body without mass or collider)")  # fmt: skip
    export.set_defaults(handler=_export)


def _open(path: Path):  # noqa: ANN202 - returns holousd.SceneGraph, imported lazily
    from holousd.usd._scene import SceneGraph

    return SceneGraph.open(path)


def _search_lines(energies: dict) -> list[str]:  # name -> Energies
    """One line per object the s2 search scored: the chosen candidate beside the runner-up."""
    lines = []
    for name, e in energies.items():
        if e.chosen is None:
            continue
        runner = e.runner_up()
        runner_text = f"{runner[0]} {runner[1]:.2f}" if runner else "none left (the others rejected by E_obs)"
        total = f"total {e.total:.2f}" if e.total >= 0 else "kept as fitted, E_obs rejected every candidate"
        lines.append(f"  {name}: {e.chosen} {total} (E_obs {e.observation:.2f}, "
                     f"E_stable {e.stable:.2f}{' (stands once set up)' if e.stands_once_set_up else ''}, "
                     f"touch {100 * e.touch:.1f} cm, pene {1e6 * e.penetration:.1f} cm^3)"
                     f"; runner-up {runner_text}; {len(e.candidates)} candidates")  # fmt: skip
    return lines


def _info(args: argparse.Namespace) -> int:
    scene = _open(args.scene)
    summary = scene.summary()
    energies = {n.name: e for n in summary.nodes if (e := scene.get_energies(n.name)) is not None}
    try:
        cameras = scene.get_cameras()
    except SceneError as exc:  # a camera another tool wrote without what ours carry: describe the rest
        cameras = []
        print(f"warning: {exc}", file=sys.stderr)
    if args.json:
        data = asdict(summary)
        data["total_splats"] = summary.total_splats
        data["search"] = {name: asdict(e) for name, e in energies.items()}
        data["cameras"] = [{"name": c.name, "frame_id": c.frame_id, "pose_move_m": c.pose_move.tolist(),
                            "pose_turn_deg": c.pose_turn_deg.tolist()} for c in cameras]  # fmt: skip
        emit_json(args, data)
        return 0
    print(f"scene: {summary.path}")
    print(f"layers (strongest first): {', '.join(Path(layer).name for layer in summary.layers)}")
    print(
        f"upAxis {summary.up_axis}, metersPerUnit {summary.meters_per_unit:g}, "
        f"kilogramsPerUnit {summary.kilograms_per_unit:g}, holousd schema {summary.schema_version}"
    )
    header = ("node", "id", "supported by", "beside", "faces", "sdf", "splats", "mass kg", "collider", "shift cm",
              "reach cm", "pen cm")  # fmt: skip
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
                _mass_cell(n),
                f"{n.collider} ({n.collider_parts})" if n.collider else "none!",
                *(f"{v:.2f}" if v is not None else "-"
                  for v in (n.fit_shift_cm, n.collider_reach_cm, n.penetration_cm)),  # fmt: skip
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    for row in rows:
        print("  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip())
    print(f"{len(summary.nodes)} nodes, {summary.total_splats} splats")
    if cameras:
        print(_camera_line(cameras))
    lines = _search_lines(energies)
    if lines:
        solver = next(iter(energies.values())).solver or "unrecorded"
        print(f"s2 search (chosen candidate, lowest total wins; E_stable measured {solver}):")
        print("\n".join(lines))
    unset = [n.name for n in summary.nodes if n.dynamic and n.mass_kg is None]
    if unset:
        print(f"warning: {', '.join(unset)}: rigid body without an authored mass (a simulator then guesses one from "
              "its own default density); author UsdPhysics.MassAPI mass", file=sys.stderr)  # fmt: skip
    return 0


def _camera_line(cameras: list) -> str:
    """How many observation cameras, and how far s1_fit moved and turned them from the capture's poses."""
    moved = [np.linalg.norm(c.pose_move) for c in cameras]
    turned = [np.linalg.norm(c.pose_turn_deg) for c in cameras]
    if not any(moved) and not any(turned):
        return f"{len(cameras)} cameras, at the capture's poses"
    return (f"{len(cameras)} cameras, poses aligned against the depth by s1_fit: moved median "
            f"{1000 * np.median(moved):.1f} mm (largest {1000 * max(moved):.1f}), turned median "
            f"{np.median(turned):.2f} deg (largest {max(turned):.2f}); per camera: holo:camera:poseMove / poseTurn, "
            "or --json")  # fmt: skip


def _mass_cell(node) -> str:  # noqa: ANN001 - NodeSummary
    if node.mass_kg is not None:
        return f"{node.mass_kg:.3f}"
    return "unset!" if node.dynamic else "static"


def _validate(args: argparse.Namespace) -> int:
    from holousd.usd._validate import validate

    report = validate(_open(args.scene).stage)
    if args.json:
        emit_json(args, report.to_dict())
    else:
        for issue in report.issues:
            print(issue)
        errors = sum(i.severity == "error" for i in report.issues)
        warnings = sum(i.severity == "warning" for i in report.issues)
        verdict = "clean" if report.ok else "NOT clean"
        print(f"{args.scene}: {verdict} ({errors} errors, {warnings} warnings)", file=sys.stderr)
    return 0 if report.ok else 1


_SIM_RULES = frozenset({"support-tree", "support-cycle", "dangling-relationship", "rigid-body", "mass", "collider",
                        "up-axis", "meters-per-unit", "kilograms-per-unit", "schema-version", "unknown-schema"})
"""holousd validation rules whose errors make an exported physics scene wrong in a simulator."""


def _refuse_broken_physics(stage, scene: Path) -> None:  # noqa: ANN001 - Usd.Stage, imported lazily
    from holousd._errors import HolousdError
    from holousd.usd._validate import validate

    broken = [i for i in validate(stage).issues
              if i.severity == "error" and i.rule.removeprefix("holousd:") in _SIM_RULES]  # fmt: skip
    if broken:
        first = broken[0]
        more = f" (and {len(broken) - 1} more: holousd validate {scene})" if len(broken) > 1 else ""
        raise HolousdError(f"{first.where}: {first.message}; {first.fix}{more}; nothing was exported "
                           "(--force exports it anyway)")  # fmt: skip


def _export(args: argparse.Namespace) -> int:
    from holousd._errors import HolousdError
    from holousd._paths import output_file
    from holousd.usd._export import export_glb, export_sim, export_usdz

    if args.sim is None and args.usdz is None and args.glb is None:
        raise HolousdError("nothing to export: give --sim OUT.usda, --usdz OUT.usdz, --glb DIR and/or --ply DIR")
    if args.glb is not None and args.glb.exists() and not args.glb.is_dir():
        raise HolousdError(f"{args.glb}: --glb takes a folder, and this is a file; give a folder path")
    for out in (args.sim, args.usdz):
        if out is not None and out.resolve() == args.scene.resolve():
            raise HolousdError(f"{out}: refusing to overwrite the input scene; choose another output path")
    for out in (args.sim, args.usdz):
        if out is not None:
            output_file(out, "export file")
    scene = _open(args.scene)
    if args.sim is not None:
        if not args.force:
            _refuse_broken_physics(scene.stage, args.scene)
        print(f"wrote {export_sim(scene.stage, args.sim)}")
    if args.usdz is not None:
        print(f"wrote {export_usdz(scene.stage, args.usdz)}")
    if args.glb is not None:
        files = export_glb(scene, args.glb)
        print(f"wrote {len(files)} .glb files to {args.glb} ({files[-1].name}: the whole scene)")
    return 0
