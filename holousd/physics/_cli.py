"""Sub-commands of the physics domain: ``stability``, ``simulate`` and ``bench-physics``.

Heavy imports (warp, newton, mujoco) happen inside the handlers, so registering the commands stays cheap.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from holousd._argtypes import HelpFormatter, emit_json
from holousd._warp import quiet_warp

__all__ = ["add_commands"]


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register ``stability``, ``simulate`` and ``bench-physics`` on the ``holousd`` parser."""
    from ._solvers import SOLVERS
    from ._stability import StabilityConfig

    stab = subparsers.add_parser(
        "stability",
        help="stability verdict per rigid body (stable bodies %%) under the physics protocol",
        description="Simulate every rigid body of a UsdPhysics scene together under gravity only (friction 0.5 on "
        "every collider, no damping, 240 Hz) and report per object its largest translation and rotation and "
        "whether it stayed under 2 cm and 5 degrees. Works on any UsdPhysics scene; objects are named by prim "
        "path. Exit code 0 when the verdict was computed, 2 when the scene cannot be used.",
        formatter_class=HelpFormatter,
    )
    stab.add_argument("scene", type=Path, metavar="SCENE", help="scene file (.usda/.usdc/.usd)")
    stab.add_argument("--json", action="store_true", help="print JSON instead of a table")
    stab.add_argument("--solver", choices=SOLVERS, default="xpbd", help="primary solver")
    stab.add_argument(
        "--cross-check", action="store_true", help="also run a second, independent solver and report agreement"
    )
    stab.add_argument(
        "--cross-solver",
        choices=SOLVERS,
        default=None,
        help="solver of the cross-check (None: the one that is not --solver)",
    )
    stab.add_argument("--seconds", type=float, default=2.0, help="simulated time, s")
    stab.add_argument(
        "--xpbd-iterations",
        type=int,
        default=None,
        metavar="N",
        help="XPBD constraint iterations per step, for experiments (default: the protocol's, "
        f"{StabilityConfig.iterations}); fewer converge contacts less: at 8 a light object resting on a heavy one "
        "can chatter",
    )
    stab.add_argument("--alone", action="store_true", help="also test each object alone on its static support chain")
    stab.set_defaults(handler=_stability)

    sim = subparsers.add_parser(
        "simulate",
        help="simulate a scene and write the motion as a time-sampled USD layer",
        description="Simulate all rigid bodies of a UsdPhysics scene with their authored materials and damping, "
        "optionally pushing objects at t = 0, print how far each moved, and with --out write the trajectories "
        "as translate/orient time samples into a new layer that sublayers the scene (open it in any USD "
        "viewer to play the motion).",
        formatter_class=HelpFormatter,
    )
    sim.add_argument("scene", type=Path, metavar="SCENE", help="scene file (.usda/.usdc/.usd)")
    sim.add_argument("--seconds", type=float, default=2.0, help="simulated time, s")
    sim.add_argument("--out", type=Path, metavar="LAYER.usda", default=None, help="trajectory layer to write")
    sim.add_argument(
        "--push",
        action="append",
        default=[],
        metavar="OBJECT=FX,FY,FZ",
        help="impulse in N*s (world axes) applied at t = 0 to OBJECT (prim path or name under /World/Objects); "
        "repeatable",
    )
    sim.add_argument("--solver", choices=SOLVERS, default="xpbd", help="solver")
    sim.add_argument("--hz", type=float, default=240.0, help="simulation steps per second")
    sim.add_argument("--fps", type=float, default=60.0, help="time codes per second of the written layer")
    sim.add_argument("--json", action="store_true", help="print JSON instead of a table")
    sim.set_defaults(handler=_simulate)

    bench = subparsers.add_parser(
        "bench-physics",
        help="benchmark simulation cost vs object count and collider kind",
        description="Measure seconds of wall time per simulated second for 5, 20 and 50 objects with convex-hull, "
        "decomposition and triangle-mesh colliders, and the time of one object-on-its-support-chain check; "
        "write bench_physics.json into DIR.",
        formatter_class=HelpFormatter,
    )
    bench.add_argument("--out", type=Path, metavar="DIR", required=True, help="folder for bench_physics.json")
    bench.add_argument("--counts", default="5,20,50", help="comma-separated object counts to measure")
    bench.add_argument("--seconds", type=float, default=0.5, help="simulated time per measurement, s")
    bench.set_defaults(handler=_bench)


def _fail(command: str, exc: Exception) -> int:
    print(f"holousd {command}: error: {exc}", file=sys.stderr)
    return 2


class _Progress:
    """A tqdm progress bar on stderr per solver run (tqdm disables itself when stderr is not a terminal)."""

    def __init__(self, label: str) -> None:
        self.label = label
        self._bars: dict[str, object] = {}

    def __call__(self, what: str, fraction: float) -> None:
        from tqdm import tqdm

        bar = self._bars.get(what)
        if bar is None:
            bar = self._bars[what] = tqdm(total=100, desc=f"{self.label} [{what}]", unit="%", leave=False, disable=None)
        bar.update(round(100 * fraction) - bar.n)
        if fraction >= 1.0:
            bar.close()


def _stability(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ._errors import PhysicsInputError
    from ._stability import StabilityConfig, stability, stability_each_alone

    quiet_warp()
    cross = None
    if args.cross_check:
        cross = args.cross_solver or ("mujoco" if args.solver != "mujoco" else "xpbd")
    try:
        if args.seconds <= 0:
            raise PhysicsInputError(f"--seconds {args.seconds}: give a positive duration in seconds")
        if args.xpbd_iterations is not None and args.xpbd_iterations < 1:
            raise PhysicsInputError(f"--xpbd-iterations {args.xpbd_iterations}: give at least 1")
        cfg = StabilityConfig(seconds=args.seconds, solver=args.solver)
        if args.xpbd_iterations is not None:
            cfg = replace(cfg, iterations=args.xpbd_iterations)
        report = stability(str(args.scene), cfg, cross_check=cross, progress=_Progress(f"stability {args.scene}"))
        alone = stability_each_alone(str(args.scene), cfg) if args.alone else None
    except PhysicsInputError as exc:
        return _fail("stability", exc)
    data = report.to_dict()
    data["xpbd_iterations"] = cfg.iterations
    if alone is not None:
        data["alone"] = alone.to_dict()
    if args.json:
        emit_json(args, data)
        return 0
    rows = [("object", "translation_m", "rotation_deg", "stable")]
    rows += [
        (o.name, f"{o.translation_m:.4f}", f"{o.rotation_deg:.2f}", "yes" if o.stable else "NO") for o in report.objects
    ]
    _print_table(rows)
    # "stable bodies %": of this scene's rigid bodies (holousd eval's Stable% is of the ground truth's objects)
    n = len(report.objects)
    stable = sum(o.stable for o in report.objects)
    count = f", {cfg.iterations} iterations" if args.xpbd_iterations is not None and report.solver == "xpbd" else ""
    print(f"stable bodies ({report.solver}{count}, {report.seconds:g} s): {stable} of {n}, {report.stable_pct:.1f}%")
    if report.cross_check is not None:
        cc = report.cross_check
        cc_stable = sum(o.stable for o in cc.objects)
        cc_pct = 100 * cc_stable / max(1, len(cc.objects))
        print(f"stable bodies ({cc.solver}, cross-check): {cc_stable} of {len(cc.objects)}, {cc_pct:.1f}%; "
              f"agreement {cc.agreement_pct:.1f}%")  # fmt: skip
        for a, b in zip(report.objects, cc.objects, strict=True):
            if a.stable != b.stable:
                print(f"  disagree: {a.name} ({report.solver}: {a.stable}, {cc.solver}: {b.stable})")
    if alone is not None:
        print(f"stable bodies alone on their support chain: {alone.stable_pct:.1f}%")
        for o in alone.objects:
            verdict = "stable" if o.stable else "UNSTABLE"
            print(f"  {o.name}: {verdict} ({o.translation_m:.4f} m, {o.rotation_deg:.2f} deg)")
    return 0


def _parse_push(text: str) -> tuple[str, tuple[float, float, float]]:
    from ._errors import PhysicsInputError

    name, sep, vec = text.partition("=")
    parts = vec.split(",")
    if not sep or not name or len(parts) != 3:
        raise PhysicsInputError(f"--push {text!r}: write OBJECT=FX,FY,FZ, e.g. --push cup=0.1,0,0 (N*s)")
    try:
        return name, (float(parts[0]), float(parts[1]), float(parts[2]))
    except ValueError as exc:
        raise PhysicsInputError(f"--push {text!r}: FX,FY,FZ must be numbers (N*s)") from exc


def _simulate(args: argparse.Namespace) -> int:
    from . import _scene
    from ._errors import PhysicsInputError
    from ._model import ModelConfig
    from ._simulate import SimulationConfig, simulate, write_trajectory_layer
    from ._solvers import SolverConfig

    quiet_warp()
    try:
        if args.seconds <= 0 or args.hz <= 0 or args.fps <= 0:
            raise PhysicsInputError("--seconds, --hz and --fps must be positive")
        stage = _scene.open_stage(str(args.scene))
        impulses: dict[str, tuple[float, float, float]] = {}
        for text in args.push:
            name, vec = _parse_push(text)
            impulses[_scene.resolve_object(stage, name)] = vec
        progress = _Progress(f"simulate {args.scene}")
        traj = simulate(
            stage,
            SimulationConfig(seconds=args.seconds, hz=args.hz, solver=SolverConfig(name=args.solver)),
            model_config=ModelConfig(decompose_concave_meshes=args.solver == "mujoco"),
            impulses=impulses,
            progress=lambda f: progress(args.solver, f),
        )
        written = write_trajectory_layer(traj, args.scene, args.out, fps=args.fps) if args.out else None
    except PhysicsInputError as exc:
        return _fail("simulate", exc)
    summary = [
        {
            "name": p,
            "final_position_m": [float(v) for v in traj.positions[p][-1]],
            "translation_m": float(traj.translation_m(p)[-1]),
            "rotation_deg": float(traj.rotation_deg(p)[-1]),
        }
        for p in traj.positions
    ]
    if args.json:
        emit_json(args, {"seconds": float(traj.times[-1]), "solver": traj.solver, "layer": written,
                         "objects": summary})  # fmt: skip
        return 0
    rows = [("object", "translation_m", "rotation_deg")]
    rows += [(o["name"], f"{o['translation_m']:.4f}", f"{o['rotation_deg']:.2f}") for o in summary]
    _print_table(rows)
    if written:
        print(f"wrote {written} ({args.fps:g} time codes per second, sublayers {args.scene})")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from ._bench import bench_physics
    from ._errors import PhysicsInputError

    quiet_warp()
    try:
        counts = tuple(int(c) for c in args.counts.split(","))
    except ValueError:
        return _fail("bench-physics", PhysicsInputError(f"--counts {args.counts!r}: give integers like 5,20,50"))
    try:
        path = bench_physics(args.out, counts=counts, seconds=args.seconds, log=lambda m: print(m, file=sys.stderr))
    except PhysicsInputError as exc:
        return _fail("bench-physics", exc)
    print(Path(path).read_text())
    return 0


def _print_table(rows: list[tuple[str, ...]]) -> None:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
