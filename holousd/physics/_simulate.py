"""Simulate a UsdPhysics stage and keep per-object trajectories; write them as a time-sampled USD layer."""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdUtils, Vt

from ._errors import PhysicsInputError
from ._model import ColliderOverride, ModelConfig, PhysicsModel, build_model
from ._solvers import SolverConfig, make_stepper

__all__ = [
    "SimulationConfig",
    "Trajectories",
    "rotation_angle_deg",
    "simulate",
    "simulate_model",
    "write_trajectory_layer",
]


@dataclass(kw_only=True)
class SimulationConfig:
    """How long and how finely to simulate, with which solver."""

    seconds: float = 2.0
    """Simulated duration, s."""
    hz: float = 240.0
    """Simulation step rate, steps per simulated second (dt = 1 / hz)."""
    solver: SolverConfig = field(default_factory=SolverConfig)
    """Solver name and iterations."""
    apply_damping: bool = True
    """Apply HoloPhysicsAPI damping as v <- v * exp(-c * dt) after every step."""


@dataclass(kw_only=True)
class Trajectories:
    """Per-object poses over time, keyed by rigid-body prim path."""

    times: np.ndarray
    """[T] sample times, s (sample 0 is the initial state)."""
    positions: dict[str, np.ndarray]
    """Per object [T, 3] world position of the body frame (the prim's origin), metres."""
    orientations: dict[str, np.ndarray]
    """Per object [T, 4] world orientation quaternion (w, x, y, z), unit length."""
    solver: str
    """Name of the solver that produced them."""

    def translation_m(self, path: str) -> np.ndarray:
        """[T] distance of the prim's origin from its initial position, metres."""
        pos = self.positions[path]
        return np.linalg.norm(pos - pos[0], axis=1)

    def rotation_deg(self, path: str) -> np.ndarray:
        """[T] angle of the rotation from the initial orientation, degrees."""
        return rotation_angle_deg(self.orientations[path][0], self.orientations[path])


def rotation_angle_deg(q0: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Angle of the rotation taking ``q0`` [4] to each of ``q`` [T, 4] (w, x, y, z), degrees.

    Uses ``2 atan2(|v|, |w|)`` of the relative quaternion, accurate for small angles (unlike ``acos``).
    """
    q = np.atleast_2d(q)
    w0, v0 = q0[0], -np.asarray(q0[1:])  # conjugate of q0
    w, v = q[:, 0], q[:, 1:]
    rel_w = w0 * w - v @ v0
    rel_v = w0 * v + w[:, None] * v0 + np.cross(v0, v)
    return np.degrees(2.0 * np.arctan2(np.linalg.norm(rel_v, axis=1), np.abs(rel_w)))


def simulate(
    source: str | os.PathLike[str] | Usd.Stage,
    config: SimulationConfig | None = None,
    *,
    dynamic: Sequence[str] | None = None,
    static: Sequence[str] = (),
    colliders: Mapping[str, ColliderOverride] | None = None,
    model_config: ModelConfig | None = None,
    impulses: Mapping[str, Sequence[float]] | None = None,
    progress: Callable[[float], None] | None = None,
) -> Trajectories:
    """Build a model from a stage (see :func:`build_model`) and simulate it under gravity.

    Args:
        source: Stage or file path.
        config: Duration, rate, solver, damping.
        dynamic: Bodies to simulate (None: all rigid bodies).
        static: Bodies made static (support chain).
        colliders: Per-body collider replacements.
        model_config: Material overrides and device.
        impulses: Linear impulse per body prim path, N*s in world axes, applied at the centre of mass at t = 0.
        progress: Called with the completed fraction (0..1) about 20 times during the run.

    Returns:
        Trajectories of the dynamic bodies.
    """
    pm = build_model(source, dynamic=dynamic, static=static, colliders=colliders, config=model_config)
    return simulate_model(pm, config, impulses=impulses, progress=progress)


def simulate_model(
    pm: PhysicsModel,
    config: SimulationConfig | None = None,
    *,
    impulses: Mapping[str, Sequence[float]] | None = None,
    progress: Callable[[float], None] | None = None,
    stop: Callable[[np.ndarray], bool] | None = None,
) -> Trajectories:
    """Simulate an already built model from its initial state; see :func:`simulate`.

    Damping (HoloPhysicsAPI) is applied after every step as ``v <- v * exp(-c_lin * dt)`` and
    ``w <- w * exp(-c_ang * dt)``: the exact solution of dv/dt = -c v over one step, so it is unconditionally
    stable and independent of the solver (Newton's importer does not read damping).

    ``stop(samples [t, B, 7])`` (poses so far: p, q xyzw) is asked every 12 steps whether the run can end
    early; the trajectories then end at that step.
    """
    cfg = config or SimulationConfig()
    if cfg.seconds <= 0 or cfg.hz <= 0:
        raise PhysicsInputError(f"seconds ({cfg.seconds}) and hz ({cfg.hz}) must be positive")
    stepper = make_stepper(pm, cfg.solver)
    dt = 1.0 / cfg.hz
    steps = max(1, int(round(cfg.seconds * cfg.hz)))
    masses = pm.model.body_mass.numpy()
    for path, impulse in (impulses or {}).items():
        if path not in pm.body_paths:
            raise PhysicsInputError(f"{pm.source}: impulse target {path} is not a dynamic body of this model")
        idx = pm.body_index(path)
        if masses[idx] <= 0:
            raise PhysicsInputError(f"{pm.source}: {path} has zero mass; author physics:mass or a density")
        stepper.add_velocity(idx, np.asarray(impulse, dtype=np.float64) / masses[idx])
    lin = np.exp(-pm.linear_damping * dt)  # [B]
    ang = np.exp(-pm.angular_damping * dt)  # [B]
    damp = cfg.apply_damping and bool(np.any(lin != 1.0) or np.any(ang != 1.0))

    samples = np.empty((steps + 1, pm.model.body_count, 7))  # [T, B, 7] (p, q xyzw)
    samples[0] = stepper.body_q
    report_every = max(1, steps // 20)
    for i in range(steps):
        stepper.step(dt)
        if damp:
            stepper.scale_velocities(lin, ang)
        samples[i + 1] = stepper.body_q
        if stop is not None and (i + 1) % 12 == 0 and stop(samples[: i + 2]):
            samples = samples[: i + 2]
            if progress is not None:
                progress(1.0)
            break
        if progress is not None and ((i + 1) % report_every == 0 or i + 1 == steps):
            progress((i + 1) / steps)
    if stepper.dropped_contacts:
        print(f"warning: {pm.source}: {cfg.solver.name} dropped contacts {stepper.dropped_contacts} times (its "
              f"arena of {cfg.solver.mujoco_arena_mb} MiB is full): bodies may fall through their supports; raise "
              "SolverConfig.mujoco_arena_mb", file=sys.stderr)  # fmt: skip
    if not np.all(np.isfinite(samples)):
        raise PhysicsInputError(
            f"{pm.source}: the simulation diverged (non-finite poses); check masses, scales and overlapping colliders"
        )
    positions, orientations = {}, {}
    for idx, path in enumerate(pm.body_paths):
        if not path:
            continue
        positions[path] = samples[:, idx, :3].copy()
        q = samples[:, idx, 3:7]
        orientations[path] = np.concatenate([q[:, 3:4], q[:, :3]], axis=1)  # xyzw -> wxyz
    return Trajectories(
        times=np.arange(len(samples)) * dt, positions=positions, orientations=orientations, solver=cfg.solver.name
    )


def write_trajectory_layer(
    traj: Trajectories,
    scene_path: str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    *,
    fps: float = 60.0,
) -> str:
    """Write trajectories as time samples into a new layer that sublayers the scene.

    Each body prim gets ``xformOp:translate`` (double3) and ``xformOp:orient`` samples of its *local* transform
    (parent transforms taken from the scene) and an ``xformOpOrder`` of translate, orient (then scale when the
    prim has a scale op). ``timeCodesPerSecond = framesPerSecond = fps``; time code k is t = k / fps. Stage
    metadata (upAxis, metersPerUnit, ...) is copied from the scene. The file is written atomically (temp file
    in the same folder, then ``os.replace``); a ``.usda`` layer keeps the time samples in its crate data file
    (``assets/<stem>/arrays.usdc``, see :func:`holousd.usd.save_layer`).

    Args:
        traj: Trajectories from :func:`simulate`.
        scene_path: The scene file on disk that the new layer sublayers.
        out_path: The layer file to write (``.usda``, ``.usdc`` or ``.usd``).
        fps: Time codes (frames) per second; trajectories are resampled to the nearest simulated step.

    Returns:
        The written path.
    """
    scene_path = os.path.abspath(os.fspath(scene_path))
    out_path = os.path.abspath(os.fspath(out_path))
    scene_layer = Sdf.Layer.FindOrOpen(scene_path)
    if scene_layer is None:
        raise PhysicsInputError(f"{scene_path}: cannot open the scene layer; pass the scene file the run used")
    stage = Usd.Stage.Open(scene_layer)
    layer = Sdf.Layer.CreateAnonymous(os.path.splitext(out_path)[1] or ".usda")
    UsdUtils.CopyLayerMetadata(scene_layer, layer, skipSublayers=True)
    layer.subLayerPaths.append(os.path.relpath(scene_path, os.path.dirname(out_path)))
    frames = max(1, int(math.floor(traj.times[-1] * fps + 1e-9)))
    layer.timeCodesPerSecond = fps
    layer.framesPerSecond = fps
    layer.startTimeCode = 0
    layer.endTimeCode = frames
    sample_idx = np.clip(np.searchsorted(traj.times, np.arange(frames + 1) / fps - 1e-9), 0, len(traj.times) - 1)

    cache = UsdGeom.XformCache(Usd.TimeCode.Default())
    for path, pos in traj.positions.items():
        prim = stage.GetPrimAtPath(path)
        if not prim:
            raise PhysicsInputError(
                f"{scene_path}: no prim at {path}; write the layer over the scene that was simulated"
            )
        parent_inv = np.linalg.inv(np.array(cache.GetLocalToWorldTransform(prim.GetParent()), dtype=np.float64))
        existing = {op.GetOpName(): op for op in UsdGeom.Xformable(prim).GetOrderedXformOps()}
        t_type = Sdf.ValueTypeNames.Double3
        if "xformOp:translate" in existing:
            t_type = existing["xformOp:translate"].GetAttr().GetTypeName()
        r_type = Sdf.ValueTypeNames.Quatf
        if "xformOp:orient" in existing:
            r_type = existing["xformOp:orient"].GetAttr().GetTypeName()
        vec_cls = Gf.Vec3f if t_type == Sdf.ValueTypeNames.Float3 else Gf.Vec3d
        quat_cls = Gf.Quatd if r_type == Sdf.ValueTypeNames.Quatd else Gf.Quatf
        spec = Sdf.CreatePrimInLayer(layer, path)  # an `over` (ancestors too)
        t_spec = Sdf.AttributeSpec(spec, "xformOp:translate", t_type)
        r_spec = Sdf.AttributeSpec(spec, "xformOp:orient", r_type)
        quats = traj.orientations[path]
        for frame, k in enumerate(sample_idx):
            world = Gf.Matrix4d(1.0)
            w, x, y, z = (float(v) for v in quats[k])
            world.SetRotateOnly(Gf.Quatd(w, Gf.Vec3d(x, y, z)))
            world.SetTranslateOnly(Gf.Vec3d(*map(float, pos[k])))
            local = np.array(world, dtype=np.float64) @ parent_inv  # row vectors: world = local * parentWorld
            rot = Gf.Matrix4d(local.tolist()).ExtractRotationQuat().GetNormalized()
            im = rot.GetImaginary()
            layer.SetTimeSample(t_spec.path, float(frame), vec_cls(*map(float, local[3, :3])))
            layer.SetTimeSample(r_spec.path, float(frame), quat_cls(rot.GetReal(), im[0], im[1], im[2]))
        order = ["xformOp:translate", "xformOp:orient"] + (["xformOp:scale"] if "xformOp:scale" in existing else [])
        o_spec = Sdf.AttributeSpec(spec, "xformOpOrder", Sdf.ValueTypeNames.TokenArray, Sdf.VariabilityUniform)
        o_spec.default = Vt.TokenArray(order)
    from holousd.usd import save_layer

    return str(save_layer(layer, out_path))
