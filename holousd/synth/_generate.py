"""Generate procedural benchmark scenes: observations in a capture format plus complete ground truth.

Per scene folder::

    <scene>/                  the capture, in the chosen format (native: observations.json, rgb/, masks/, ...)
    <scene>/gt/scene.usda     ground-truth scene graph (SceneGraph API): meshes, colliders, physics, support, beside
    <scene>/gt/graph.json     support tree, beside pairs, poses, physical parameters, observation statistics
    <scene>/gt/meshes/        <name>.ply watertight mesh per object in object coordinates (pose in graph.json),
                              background.ply (room shell, world coordinates)

The same seed gives byte-identical files.
"""

from __future__ import annotations

import os
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from holousd._atomic import atomic_path
from holousd._errors import HolousdError
from holousd.io import write as write_observations
from holousd.io._files import write_json
from holousd.synth._camera import camera_path, intrinsics_for
from holousd.synth._example import _union
from holousd.synth._layout import SceneSpec
from holousd.synth._render import SceneRenderer, SynthCapture
from holousd.synth._sensor import sensor_model
from holousd.synth._suites import SUITES, build_scene
from holousd.usd import BACKGROUND, Collider, MeshData, PhysicsProps, SceneGraph

__all__ = ["SceneResult", "SynthConfig", "generate_scene", "generate_suite", "object_meshes"]

_SURFACE_SAMPLES = 1500
"""Surface points per object used to measure the observed fraction."""
_PREVIEW_WIDTH = 96
"""Width of the low-resolution pass that checks every object is seen, pixels."""


@dataclass(kw_only=True)
class SynthConfig:
    """How scenes are generated."""

    seed: int = 0
    """Seed of layouts, textures and camera paths (same seed -> byte-identical output)."""
    frames: int = 100
    """Frames per scene."""
    width: int = 320
    """Image width, pixels."""
    height: int = 240
    """Image height, pixels."""
    format: str = "native"
    """Capture format of the observations: 'native', 'nerfstudio' or 'monosdf' (see holousd.io)."""
    progress: bool = True
    """Show progress bars on stderr."""
    overwrite: bool = False
    """Replace scene folders that already hold a generated scene."""
    sensor: str = "clean"
    """Sensor model of the capture (see :mod:`holousd.synth._sensor`): 'clean' (the renderer's exact frames),
    'phone' or 'lidar'. The ground truth stays exact."""


@dataclass(kw_only=True)
class SceneResult:
    """What :func:`generate_scene` wrote."""

    name: str
    """Scene name."""
    folder: Path
    """Scene folder."""
    description: str
    """What the scene exercises."""
    objects: int
    """Number of objects (instance ids 1..objects)."""
    frames: int
    """Frames rendered."""
    observed_fraction: dict[str, float] = field(default_factory=dict)
    """Object name -> fraction of its surface some frame observes."""


def object_meshes(spec: SceneSpec) -> dict[str, MeshData]:
    """Watertight union mesh of each object's parts, object coordinates."""
    return {obj.name: _union(obj.template.parts) for obj in spec.objects}


def _sample_surface(mesh: MeshData, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    tri = mesh.points[mesh.faces]  # [F, 3, 3]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    face = rng.choice(len(area), size=count, p=area / area.sum())
    a, b = rng.random(count), rng.random(count)
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    points = tri[face, 0] + a[:, None] * (tri[face, 1] - tri[face, 0]) + b[:, None] * (tri[face, 2] - tri[face, 0])
    normals = cross[face] / np.maximum(np.linalg.norm(cross[face], axis=1, keepdims=True), 1e-12)
    return points + 1e-4 * normals, normals


def _write_ply(path: Path, mesh: MeshData) -> None:
    """Binary little-endian PLY (float32 vertices, int32 triangles), deterministic bytes."""
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment holousd synth ground truth, metres\n"
        f"element vertex {len(mesh.points)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(mesh.faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode("ascii")
    faces = np.zeros(len(mesh.faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    faces["n"], faces["v"] = 3, mesh.faces
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header)
            fh.write(mesh.points.astype("<f4").tobytes())
            fh.write(faces.tobytes())


def _mass_properties(mesh: MeshData) -> tuple[float, np.ndarray]:
    """Volume (m^3) and centre of mass ([3], object coordinates) of a closed mesh."""
    tri = mesh.points[mesh.faces]
    vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0  # [F] signed tetra volumes
    total = float(vol.sum())
    com = (vol[:, None] * tri.sum(axis=1) / 4.0).sum(axis=0) / total
    return total, com


def _prepare_folder(folder: Path, overwrite: bool) -> None:
    if folder.exists() and any(folder.iterdir()):
        if not overwrite:
            raise HolousdError(f"{folder}: folder exists and is not empty; pass --overwrite or choose another --out")
        if not (folder / "gt" / "graph.json").is_file():
            raise HolousdError(
                f"{folder}: not a holousd synth scene (no gt/graph.json); refusing to overwrite it; "
                "choose another --out"
            )
        shutil.rmtree(folder)
    folder.mkdir(parents=True, exist_ok=True)


def _capture(
    spec: SceneSpec, meshes: dict[str, MeshData], config: SynthConfig, rng: np.random.Generator, samples: dict
) -> SynthCapture:
    renderer = SceneRenderer(spec, meshes, spec.room.mesh())
    path_rng_state = rng.bit_generator.state
    extra: list[str] = []
    preview_w = min(_PREVIEW_WIDTH, config.width)
    preview_h = max(1, round(config.height * preview_w / config.width))
    for _ in range(3):
        rng.bit_generator.state = path_rng_state
        poses = camera_path(spec, config.frames, rng, extra=extra, close=extra)
        preview = SynthCapture(
            renderer, np.repeat(intrinsics_for(preview_w, preview_h)[None], len(poses), 0), poses, preview_w, preview_h
        )
        preview.render_all()
        unseen = [o.name for o in spec.objects if preview.pixels[o.instance_id] == 0 and o.name not in extra]
        if not unseen:
            break
        extra += unseen
    intrinsics = np.repeat(intrinsics_for(config.width, config.height)[None], len(poses), 0)
    return SynthCapture(renderer, intrinsics, poses, config.width, config.height, samples)


def _write_ground_truth(
    spec: SceneSpec, folder: Path, meshes: dict[str, MeshData], capture: SynthCapture, config: SynthConfig, suite: str
) -> dict[str, float]:
    gt = folder / "gt"
    room = spec.room.mesh()
    _write_ply(gt / "meshes" / "background.ply", room)
    observed = {name: float(seen.mean()) for name, seen in capture.seen.items()}
    scene = SceneGraph.create(gt / "scene.usda", overwrite=True, provenance="holousd synth")
    scene.add_background(observed_fraction=1.0)
    scene.set_mesh(BACKGROUND, room)
    scene.set_collider(BACKGROUND, Collider(approximation="convexDecomposition", parts=spec.room.slabs()))
    scene.set_physics(BACKGROUND, PhysicsProps(mass=None, static_friction=0.6, dynamic_friction=0.6, density=2000.0))
    nodes: list[dict] = [
        {
            "name": BACKGROUND,
            "instance_id": 0,
            "role": "background",
            "category": "room",
            "mesh": "meshes/background.ply",
            "frame": "world",
            "room_size": [float(v) for v in spec.room.size],
            "children": [o.name for o in spec.objects if o.parent == BACKGROUND],
        }
    ]
    for obj in spec.objects:
        mesh = meshes[obj.name]
        _write_ply(gt / "meshes" / f"{obj.name}.ply", mesh)
        volume, com = _mass_properties(mesh)
        tpl = obj.template
        mass = tpl.density * volume
        scene.add_object(obj.name, instance_id=obj.instance_id, pose=obj.pose, observed_fraction=observed[obj.name])
        scene.set_mesh(obj.name, mesh)
        approximation = "convexDecomposition" if len(tpl.parts) > 1 else "convexHull"
        scene.set_collider(obj.name, Collider(approximation=approximation, parts=tpl.parts))
        scene.set_physics(
            obj.name,
            PhysicsProps(
                mass=mass,
                center_of_mass=com,
                density=tpl.density,
                static_friction=tpl.friction,
                dynamic_friction=tpl.friction,
            ),
        )
        scene.set_support(obj.name, obj.parent)
        world = obj.pose.apply(mesh.points)
        nodes.append(
            {
                "name": obj.name,
                "instance_id": obj.instance_id,
                "role": "object",
                "category": str(tpl.category),
                "parent": obj.parent,
                "children": [o.name for o in spec.objects if o.parent == obj.name],
                "beside": sorted(obj.beside),
                "pose": {
                    "translation": [float(v) for v in obj.pose.translation],
                    "orientation_xyzw": [float(v) for v in obj.pose.orientation],
                },
                "mesh": f"meshes/{obj.name}.ply",
                "frame": "object",
                "collider": approximation,
                "collider_parts": len(tpl.parts),
                "size": [float(v) for v in tpl.size],
                "bounds_world": [[float(v) for v in world.min(axis=0)], [float(v) for v in world.max(axis=0)]],
                "volume_m3": volume,
                "density_kg_m3": tpl.density,
                "mass_kg": mass,
                "center_of_mass": [float(v) for v in com],
                "static_friction": tpl.friction,
                "dynamic_friction": tpl.friction,
                "observed_fraction": observed[obj.name],
                "pixels_observed": int(capture.pixels[obj.instance_id]),
                "frames_observed": int(capture.frames_seen[obj.instance_id]),
            }
        )
    for obj in spec.objects:
        if obj.beside:
            scene.set_beside(obj.name, sorted(obj.beside))
    scene.save()
    graph = {
        "format": "holousd-synth-graph",
        "version": 1,
        "scene": spec.name,
        "suite": suite,
        "description": spec.description,
        "seed": config.seed,
        "conventions": "metres, kilograms, world Z up; poses object-to-world; quaternions (x, y, z, w); meshes in "
        "object coordinates (background in world coordinates); observed_fraction = share of 1500 surface samples "
        "that some frame sees unoccluded",
        "root": BACKGROUND,
        "nodes": nodes,
        "support": [[o.name, o.parent] for o in spec.objects],
        "beside_pairs": [list(p) for p in spec.beside_pairs()],
        "capture": {"format": config.format, "frames": config.frames, "width": config.width, "height": config.height,
                    "sensor": sensor_model(config.sensor).to_dict()},  # fmt: skip
    }
    write_json(gt / "graph.json", graph)
    write_json(gt / "cameras.json", {
        "format": "holousd-synth-cameras", "version": 1,
        "conventions": "true camera-to-world poses of the capture's frames (OpenCV cameras, world Z up, metres), "
        "in frame order; the capture's own poses carry the sensor's tracking error",
        "poses": [[[float(x) for x in row] for row in p] for p in capture.poses],
    })  # fmt: skip
    return observed


def generate_scene(
    spec: SceneSpec, folder: str | os.PathLike[str], config: SynthConfig, *, suite: str = "custom"
) -> SceneResult:
    """Render ``spec`` and write its capture and ground truth into ``folder``.

    Args:
        spec: The scene layout.
        folder: Scene folder (created; an existing generated scene is replaced only with ``config.overwrite``).
        config: Frames, resolution, format, seed.
        suite: Name of the suite recorded in graph.json.
    """
    folder = Path(folder)
    sensor_model(config.sensor)  # an unknown sensor fails before anything is written
    _prepare_folder(folder, config.overwrite)
    rng = np.random.default_rng([config.seed, 7])
    meshes = object_meshes(spec)
    samples = {}
    for obj in spec.objects:
        points, normals = _sample_surface(meshes[obj.name], _SURFACE_SAMPLES, rng)
        samples[obj.name] = (obj.pose.apply(points), normals @ obj.pose.rotation_matrix().T)
    capture = _capture(spec, meshes, config, rng, samples)
    names = {o.instance_id: o.name for o in spec.objects}
    obs = capture.observations(names, sensor_model(config.sensor), config.seed)
    write_observations(obs, folder, format=config.format, progress=config.progress)
    capture.render_all()  # statistics of any frame the writer did not read
    observed = _write_ground_truth(spec, folder, meshes, capture, config, suite)
    return SceneResult(
        name=spec.name,
        folder=folder,
        description=spec.description,
        objects=len(spec.objects),
        frames=len(capture),
        observed_fraction=observed,
    )


def generate_suite(
    suite: str, out: str | os.PathLike[str], config: SynthConfig, scenes: list[str] | None = None
) -> list[SceneResult]:
    """Generate every scene of ``suite`` ('demo', 'bench', 'hard') under ``out/<scene>/``; writes ``out/suite.json``.

    Args:
        suite: Suite name.
        out: Output folder.
        config: Generation settings.
        scenes: Only these scenes of the suite (default: all).
    """
    if suite not in SUITES:
        raise HolousdError(f"unknown suite {suite!r}; choose one of {', '.join(SUITES)}")
    names = scenes or list(SUITES[suite])
    unknown = [n for n in names if n not in SUITES[suite]]
    if unknown:
        raise HolousdError(f"suite {suite!r} has no scene {unknown[0]!r}; its scenes are {', '.join(SUITES[suite])}")
    out = Path(out)
    results = []
    for name in names:
        if config.progress:
            print(f"[{suite}] {name}", file=sys.stderr)
        spec = build_scene(suite, name, config.seed)
        results.append(generate_scene(spec, out / name, config, suite=suite))
    entries = _index_entries(out / "suite.json", suite, config)  # scenes generated earlier with the same settings
    for r in results:
        entries[r.name] = {"name": r.name, "folder": r.name, "objects": r.objects, "frames": r.frames,
                           "width": config.width, "height": config.height, "description": r.description}  # fmt: skip
    index = {
        "format": "holousd-synth-suite",
        "version": 1,
        "suite": suite,
        "seed": config.seed,
        "sensor": config.sensor,
        "scenes": [entries[n] for n in SUITES[suite] if n in entries],
    }
    write_json(out / "suite.json", index)
    return results


def _index_entries(path: Path, suite: str, config: SynthConfig) -> dict[str, dict]:
    """The scene entries of an existing ``suite.json`` made with the same suite, seed, sensor, frames and size whose
    folders still exist (so generating a few scenes into a suite folder keeps the others listed); {} otherwise."""
    import json

    try:
        index = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(index, dict) or index.get("suite") != suite or index.get("seed") != config.seed:
        return {}
    if index.get("sensor", "clean") != config.sensor:
        return {}
    kept = {}
    for entry in index.get("scenes", []):
        if not isinstance(entry, dict) or not (path.parent / str(entry.get("folder", ""))).is_dir():
            continue
        if (entry.get("frames"), entry.get("width"), entry.get("height")) == (config.frames, config.width,
                                                                              config.height):  # fmt: skip
            kept[str(entry["name"])] = entry
    return kept
