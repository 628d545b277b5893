"""The exported physics scene is self-contained and simulates in Newton as authored."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdVol

from holousd import BACKGROUND, Collider, MeshData, PhysicsProps, Pose, SceneGraph, export_sim


def _box(sx: float, sy: float, sz: float) -> MeshData:
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]) * [sx, sy, sz]
    faces = [[0, 1, 2], [1, 3, 2], [4, 6, 5], [5, 6, 7], [0, 4, 1], [1, 4, 5],
             [2, 3, 6], [3, 7, 6], [0, 2, 4], [2, 6, 4], [1, 5, 3], [3, 5, 7]]  # fmt: skip
    return MeshData(points=corners, faces=faces)


def _stack_scene(path: Path) -> SceneGraph:
    """Floor; a box resting centred on a box (x = -1); a box overhanging its support's edge (x = +1)."""
    scene = SceneGraph.create(path)
    scene.add_background()
    floor = MeshData(points=_box(6, 6, 0.2).points - [0, 0, 0.1], faces=_box(1, 1, 1).faces)
    scene.set_mesh(BACKGROUND, floor)
    scene.set_collider(BACKGROUND, Collider(approximation="none", parts=[floor]))
    scene.set_physics(BACKGROUND, PhysicsProps(mass=None))
    bodies = [
        ("base_a", _box(0.4, 0.4, 0.2), (-1.0, 0.0, 0.1), BACKGROUND),
        ("top_a", _box(0.2, 0.2, 0.2), (-1.0, 0.0, 0.3), "base_a"),
        ("base_b", _box(0.4, 0.4, 0.2), (1.0, 0.0, 0.1), BACKGROUND),
        ("top_b", _box(0.2, 0.2, 0.2), (1.0 + 0.26, 0.0, 0.3), "base_b"),  # centre 6 cm beyond the edge
    ]
    for i, (name, mesh, position, parent) in enumerate(bodies, start=1):
        scene.add_object(name, instance_id=i, pose=Pose(translation=position))
        scene.set_mesh(name, mesh)
        scene.set_collider(name, Collider(approximation="convexHull", parts=[mesh]))
        volume = float(np.prod(mesh.bounds[1] - mesh.bounds[0]))
        scene.set_physics(name, PhysicsProps(mass=volume * 500.0, static_friction=0.7, dynamic_friction=0.65))
        scene.set_support(name, parent)
    scene.save()
    return scene


def test_export_is_flat_and_free_of_appearance(example_copy: Path, tmp_path: Path) -> None:
    out = export_sim(SceneGraph.open(example_copy).stage, tmp_path / "sim" / "sim.usda")
    layer = Sdf.Layer.FindOrOpen(str(out))
    assert not layer.subLayerPaths and not layer.GetExternalReferences()
    stage = Usd.Stage.Open(str(out))
    assert not any(p.IsA(UsdVol.ParticleField) or p.IsA(UsdGeom.Camera) for p in stage.Traverse())
    assert not any(p.HasAPI("HoloSdfAPI") or p.GetPropertiesInNamespace("holo:sdf") for p in stage.Traverse())
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == "Z"
    scene = SceneGraph(stage)
    assert scene.get_support("mug") == "book"
    assert scene.get_physics("mug").mass > 0
    assert len(scene.get_collider("table").parts) == 5


def test_exported_scene_simulates_in_newton(tmp_path: Path) -> None:
    """A box resting on a box moves < 2 mm in 1 s; a box overhanging an edge falls."""
    import newton

    scene = _stack_scene(tmp_path / "stack.usda")
    out = export_sim(scene.stage, tmp_path / "sim.usda")

    builder = newton.ModelBuilder(up_axis="Z")
    result = builder.add_usd(str(out))
    model = builder.finalize(device="cpu")
    path_to_body = {str(k): v for k, v in result["path_body_map"].items()}
    # the authored friction reaches Newton (it reads bindings on the collider prims themselves)
    colliding = (model.shape_flags.numpy() & int(newton.ShapeFlags.COLLIDE_SHAPES)) != 0
    of_top_a = colliding & (model.shape_body.numpy() == path_to_body["/World/Objects/top_a"])
    assert of_top_a.sum() == 1
    np.testing.assert_allclose(model.shape_material_mu.numpy()[of_top_a], 0.65, atol=1e-6)
    solver = newton.solvers.SolverXPBD(model, iterations=8, enable_restitution=False)
    pipeline = newton.CollisionPipeline(model)
    contacts = pipeline.contacts()
    state_0, state_1, control = model.state(), model.state(), model.control()
    start = state_0.body_q.numpy().copy()
    for _ in range(240):
        state_0.clear_forces()
        pipeline.collide(state_0, contacts)
        solver.step(state_0, state_1, control, contacts, 1.0 / 240.0)
        state_0, state_1 = state_1, state_0
    end = state_0.body_q.numpy()

    def moved(name: str) -> float:
        body = path_to_body[f"/World/Objects/{name}"]
        return float(np.linalg.norm(end[body, :3] - start[body, :3]))

    assert moved("top_a") < 0.002, moved("top_a")
    assert moved("base_a") < 0.002, moved("base_a")
    assert moved("top_b") > 0.05, moved("top_b")
