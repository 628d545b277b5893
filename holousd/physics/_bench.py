"""Physics benchmark: simulation cost vs object count and collider kind, and the support-chain check."""

from __future__ import annotations

import json
import math
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics, UsdShade

from . import _scene
from ._colliders import DecompositionConfig, convex_decomposition
from ._model import ModelConfig, build_model
from ._solvers import SolverConfig, make_stepper
from ._stability import StabilityConfig, stability_alone

__all__ = ["bench_physics", "bench_scene"]


def _box(h: float) -> tuple[np.ndarray, np.ndarray]:
    from ._colliders import convex_hull

    pts = np.array([[sx * h, sy * h, sz * h] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    return convex_hull(pts)


def _bowl(radius: float = 0.08, wall: float = 0.01, segments: int = 20) -> tuple[np.ndarray, np.ndarray]:
    import manifold3d as mf

    shell = mf.Manifold.sphere(radius, segments) - mf.Manifold.sphere(radius - wall, segments)
    lower = mf.Manifold.cube([4 * radius] * 3, True).translate([0, 0, -2 * radius])
    foot = mf.Manifold.cube([4 * radius] * 3, True).translate([0, 0, 2 * radius - 0.8 * radius])
    mesh = ((shell ^ lower) ^ foot).to_mesh()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


def bench_scene(count: int, kind: str, *, chain: int = 0, parts_cache: dict[str, list] | None = None) -> Usd.Stage:
    """An in-memory scene of ``count`` objects resting on a floor (or a stack of ``chain`` boxes).

    Args:
        count: Number of objects in a grid, 0.3 m apart.
        kind: ``"hull"`` (boxes with a hull), ``"decomposition"`` (bowls with CoACD parts) or ``"mesh"`` (bowls
            with a triangle-mesh collider).
        chain: If > 0, ignore ``count`` and stack this many 10 cm boxes, each supported by the one below.
        parts_cache: Reused decomposition parts (computed once per benchmark).
    """
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    scene = UsdPhysics.Scene.Define(stage, "/World/PhysicsScene")
    scene.CreateGravityDirectionAttr(Gf.Vec3f(0, 0, -1))
    scene.CreateGravityMagnitudeAttr(9.81)
    mat = UsdShade.Material.Define(stage, "/World/Materials/Default")
    UsdPhysics.MaterialAPI.Apply(mat.GetPrim()).CreateDynamicFrictionAttr(0.5)
    side = max(1, math.ceil(math.sqrt(max(count, 1))))
    half = 0.3 * side / 2 + 0.5
    floor_pts, floor_faces = _box(1.0)
    floor_pts = floor_pts * np.array([half, half, 0.05]) - np.array([0, 0, 0.05])
    UsdGeom.Xform.Define(stage, "/World/Background")
    _scene.author_collider_mesh(stage, "/World/Background/Geom", floor_pts, floor_faces, "none")
    UsdGeom.Xform.Define(stage, "/World/Objects")
    if chain > 0:
        placements = [(f"Box_{i}", (0.0, 0.0, 0.05 + 0.1 * i), "hull") for i in range(chain)]
    else:
        placements = [
            (f"Obj_{i:03d}", (0.3 * (i % side - side / 2), 0.3 * (i // side - side / 2), 0.0), kind)
            for i in range(count)
        ]
    box = _box(0.05)
    bowl = _bowl() if kind != "hull" else None
    cache = parts_cache if parts_cache is not None else {}
    if kind == "decomposition" and "bowl" not in cache:
        cache["bowl"] = convex_decomposition(*bowl, DecompositionConfig())
    previous = None
    for name, (x, y, z), k in placements:
        path = f"/World/Objects/{name}"
        xf = UsdGeom.Xform.Define(stage, path)
        if k == "hull":
            z = z or 0.05
        else:
            z = 0.8 * 0.08
        xf.AddTranslateOp().Set(Gf.Vec3d(x, y, z))
        xf.AddOrientOp().Set(Gf.Quatf(1.0))
        UsdPhysics.RigidBodyAPI.Apply(xf.GetPrim())
        UsdPhysics.MassAPI.Apply(xf.GetPrim()).CreateMassAttr(0.5)
        UsdShade.MaterialBindingAPI.Apply(xf.GetPrim()).Bind(mat, UsdShade.Tokens.weakerThanDescendants, "physics")
        UsdGeom.Scope.Define(stage, f"{path}/Collision")
        if k == "hull":
            _scene.author_collider_mesh(stage, f"{path}/Collision/Part_000", *box, "convexHull")
        elif k == "mesh":
            _scene.author_collider_mesh(stage, f"{path}/Collision/Part_000", *bowl, "none")
        else:
            for j, (pp, pf) in enumerate(cache["bowl"]):
                _scene.author_collider_mesh(stage, f"{path}/Collision/Part_{j:03d}", pp, pf, "convexHull")
        rel = xf.GetPrim().CreateRelationship(_scene.SUPPORTED_BY_REL, custom=False)
        rel.SetTargets([Sdf.Path(previous or "/World/Background")])
        if chain > 0:
            previous = path
    return stage


def bench_physics(
    out_dir: str | os.PathLike[str],
    *,
    counts: tuple[int, ...] = (5, 20, 50),
    seconds: float = 0.5,
    mesh_seconds: float = 0.1,
    log: Callable[[str], None] | None = None,
) -> str:
    """Write ``bench_physics.json`` into ``out_dir`` and return its path.

    Figures: wall seconds per simulated second (240 Hz, XPBD and MuJoCo, timed after a first step so kernel
    compilation and solver setup are excluded; those are reported apart) for each object count and collider
    kind; model build time; and the time of one warm "object alone on its static support chain" check for a
    chain of 3 boxes (top box dynamic), with the full protocol (2 s) and with ``stop_when_decided``. No figure
    is asserted anywhere.

    Args:
        out_dir: Output folder (created).
        counts: Object counts to measure.
        seconds: Simulated time per hull / decomposition measurement, s.
        mesh_seconds: Simulated time per triangle-mesh measurement, s (mesh contact is slow on CPU).
        log: Receives one progress line per measurement.
    """
    say = log or (lambda _msg: None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    parts_cache: dict[str, list] = {}
    rows = []
    for solver in ("xpbd", "mujoco"):
        for kind in ("hull", "decomposition", "mesh"):
            if solver == "mujoco" and kind == "mesh":
                continue  # MuJoCo collides meshes as hulls; a decomposed mesh is the decomposition row
            for n in counts:
                stage = bench_scene(n, kind, parts_cache=parts_cache)
                t0 = time.perf_counter()
                pm = build_model(stage, config=ModelConfig(decompose_concave_meshes=solver == "mujoco"))
                build_s = time.perf_counter() - t0
                sim_s = mesh_seconds if kind == "mesh" else seconds
                t0 = time.perf_counter()
                stepper = make_stepper(pm, SolverConfig(name=solver))
                stepper.step(1 / 240)  # compiles kernels on a cold cache; generates per-pipeline kernels
                first_step_s = time.perf_counter() - t0
                steps = max(1, round(sim_s * 240))
                t0 = time.perf_counter()
                for _ in range(steps):
                    stepper.step(1 / 240)
                    _ = stepper.body_q
                wall = time.perf_counter() - t0
                rows.append(
                    {
                        "solver": solver,
                        "collider": kind,
                        "objects": n,
                        "shapes": int(pm.model.shape_count),
                        "build_s": round(build_s, 4),
                        "solver_setup_and_first_step_s": round(first_step_s, 4),
                        "simulated_s": sim_s,
                        "wall_s_per_simulated_s": round(wall / sim_s, 4),
                    }
                )
                say(f"bench-physics: {solver} {kind} x{n}: {wall / sim_s:.3f} s per simulated s")
    chain_rows = []
    stage = bench_scene(0, "hull", chain=3)
    top = "/World/Objects/Box_2"
    for solver in ("xpbd", "mujoco"):
        for early in (False, True):
            cfg = StabilityConfig(solver=solver, stop_when_decided=early)
            stability_alone(stage, top, cfg)  # warm-up
            t0 = time.perf_counter()
            verdict = stability_alone(stage, top, cfg)
            chain_rows.append(
                {
                    "solver": solver,
                    "stop_when_decided": early,
                    "seconds": round(time.perf_counter() - t0, 4),
                    "stable": verdict.stable,
                }
            )
            say(f"bench-physics: chain of 3 ({solver}, stop_when_decided={early}): {chain_rows[-1]['seconds']} s")
    data = {
        "device": _device(),
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "rate_hz": 240,
        "notes": "mujoco has no triangle-mesh rows: it collides every mesh as its convex hull, so holousd "
        "decomposes non-convex meshes for it (the decomposition rows).",
        "simulation": rows,
        "support_chain_check": {"chain_length": 3, "target_s": 0.5, "runs": chain_rows},
    }
    path = out / "bench_physics.json"
    from holousd._atomic import atomic_path

    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2))
    return str(path)


def _device() -> str:
    from ._model import default_device

    return default_device()
