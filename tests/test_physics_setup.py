"""The physics set-up's collider adjustments on hand-made geometry: flat cuts, contents, carving, separation,
wall clipping and base extension (no simulation; the pipeline tests simulate)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from holousd.graph import Relations
from holousd.physics import cut_above, cut_axis, cut_below
from holousd.stages._physics_setup import (
    PhysicsSetupConfig,
    Wall,
    _carve,
    _clip_to_walls,
    _contents,
    _depth_inside,
    _extend_bases,
    _separate,
)
from holousd.usd import MeshData, Pose, SceneGraph


def _box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    t = trimesh.creation.box(bounds=np.array([lo, hi], float))
    return np.asarray(t.vertices, float), np.asarray(t.faces)


def _sphere(centre: tuple[float, float, float], radius: float) -> tuple[np.ndarray, np.ndarray]:
    t = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    return np.asarray(t.vertices) + centre, np.asarray(t.faces)


def test_cuts_give_flat_faces_on_the_plane() -> None:
    ball = _sphere((0.0, 0.0, 0.1), 0.1)
    (base,) = cut_below([ball], 0.01)
    assert base[0][:, 2].min() == pytest.approx(0.01)
    footprint = base[0][np.abs(base[0][:, 2] - 0.01) < 1e-9]
    assert len(footprint) >= 8 and np.ptp(footprint[:, 0]) > 0.07  # a disc of radius ~0.04, not a point
    (top,) = cut_above([ball], 0.19)
    assert top[0][:, 2].max() == pytest.approx(0.19)
    (side,) = cut_axis([ball], 0, 0.05, -1.0)
    assert side[0][:, 0].max() == pytest.approx(0.05) and side[0][:, 0].min() == pytest.approx(-0.1, abs=0.01)
    assert cut_below([ball], 0.3) == []  # nothing above the plane
    assert np.array_equal(cut_below([ball], -0.1)[0][0], ball[0])  # untouched


def test_a_shelf_holds_its_contents_a_table_does_not() -> None:
    # a shelf: two boards and two sides; a bottle stands on the lower board inside; a book lies on the table
    shelf = [_box((0, 0, 0), (0.6, 0.3, 0.02)), _box((0, 0, 0.5), (0.6, 0.3, 0.52)), _box((0, 0, 0), (0.02, 0.3, 0.52)),
             _box((0.58, 0, 0), (0.6, 0.3, 0.52))]  # fmt: skip
    pts = np.concatenate([p for p, _ in shelf])
    faces = np.concatenate([f + k * 8 for k, (_, f) in enumerate(shelf)])
    world = {"shelf": (pts, faces), "bottle": _box((0.25, 0.1, 0.02), (0.32, 0.17, 0.3)),
             "table": _box((2, 0, 0), (3, 1, 0.75)), "book": _box((2.4, 0.4, 0.75), (2.6, 0.6, 0.78))}  # fmt: skip
    rel = Relations(support={"shelf": "background", "bottle": "shelf", "table": "background", "book": "table"})
    holds = _contents(world, rel, PhysicsSetupConfig())
    assert holds == {"shelf": ["bottle"]}


def test_carving_trims_the_part_over_a_child_and_keeps_the_rest() -> None:
    # a coarse decomposition filled the compartment: one part spans board to board, the bottle inside it
    part = _box((0.0, 0.0, 0.0), (0.6, 0.3, 0.52))
    bottle = _box((0.25, 0.1, 0.03), (0.32, 0.17, 0.3))[0]
    parts, cuts = _carve([part], [bottle], tolerance=0.005, clearance=0.001)
    assert cuts == 1 and len(parts) == 1
    assert (_depth_inside(parts[0][0], bottle) <= 0.005).all()
    kept = trimesh.convex.convex_hull(parts[0][0]).volume / (0.6 * 0.3 * 0.52)
    assert kept > 0.4  # the biggest of the six cuts, not the whole part


def _scene_with(tmp_path, objects: dict[str, tuple[np.ndarray, np.ndarray]]) -> SceneGraph:  # noqa: ANN001
    scene = SceneGraph.create(tmp_path / "s.usda")
    for k, (name, (p, f)) in enumerate(objects.items(), start=1):
        scene.add_object(name, instance_id=k)
        scene.set_mesh(name, MeshData(points=p, faces=f))
        scene.set_pose(name, Pose(translation=[0.0, 0.0, 0.0]))
    return scene


def test_overlapping_neighbours_are_cut_apart_at_the_middle(tmp_path) -> None:  # noqa: ANN001
    a, b = _box((0, 0, 0), (0.4, 0.4, 0.4)), _box((0.38, 0.1, 0), (0.48, 0.2, 0.1))  # 2 cm overlap in x
    scene = _scene_with(tmp_path, {"big": a, "small": b})
    colliders = {n: ("hull", [MeshData(points=p, faces=f)], 1.0) for n, (p, f) in (("big", a), ("small", b))}
    rel = Relations(support={"big": "background", "small": "background"})
    offsets = {"big": np.zeros(3), "small": np.zeros(3)}
    cuts = _separate(colliders, scene, offsets, rel, PhysicsSetupConfig())
    assert cuts == {"big": 1, "small": 1}
    big, small = colliders["big"][1][0].points, colliders["small"][1][0].points
    assert big[:, 0].max() == pytest.approx(0.39 - 0.0005) and small[:, 0].min() == pytest.approx(0.39 + 0.0005)
    assert big[:, 1].max() == pytest.approx(0.4)  # only x was cut: the thinnest side of the overlap


def test_mesh_is_clipped_at_the_wall_it_runs_into() -> None:
    p, f = _box((1.8, 0.0, 0.0), (2.2, 0.5, 1.0))  # 20 cm past a wall at x = 2.0 facing -x
    pose = Pose(translation=[0.1, 0.0, 0.0])
    local = MeshData(points=p - [0.1, 0.0, 0.0], faces=f)
    trimmed, removed = _clip_to_walls(local, pose, [Wall(normal=(-1.0, 0.0, 0.0), offset=-2.0)],
                                     clearance=0.001)  # fmt: skip
    world = pose.apply(trimmed.points)
    assert world[:, 0].max() == pytest.approx(1.999, abs=1e-5) and removed == pytest.approx(0.201 * 0.5 * 1.0, rel=1e-3)
    far = Wall(normal=(1.0, 0.0, 0.0), offset=-2.0)  # a wall far away
    same, none = _clip_to_walls(local, pose, [far], clearance=0.001)
    assert same is local and none == 0.0


def test_a_table_missing_its_far_legs_gets_a_base(tmp_path) -> None:  # noqa: ANN001
    top = _box((0, 0, 0.7), (1.2, 0.6, 0.75))
    leg = _box((0, 0, 0.0), (0.05, 0.6, 0.7))  # only the legs at x = 0 were reconstructed
    pts = np.concatenate([top[0], leg[0]])
    faces = np.concatenate([top[1], leg[1] + 8])
    hull = trimesh.convex.convex_hull(pts)
    table = (np.asarray(hull.vertices), np.asarray(hull.faces))
    scene = _scene_with(tmp_path, {"table": table, "cup": _box((2, 2, 0), (2.1, 2.1, 0.1))})
    colliders = {n: ("hull", [MeshData(points=p, faces=f)], 1.0) for n, (p, f) in (("table", table),
                 ("cup", _box((2, 2, 0), (2.1, 2.1, 0.1))))}  # fmt: skip
    local = {"table": MeshData(points=pts, faces=faces), "cup": colliders["cup"][1][0]}
    done = _extend_bases(colliders, local, scene, {"table": np.zeros(3), "cup": np.zeros(3)}, PhysicsSetupConfig())
    assert done == {"table"}
    grown = colliders["table"][1][0].points
    base = grown[grown[:, 2] < 1e-9]
    assert base[:, 0].max() == pytest.approx(1.2)  # the base now spans the table
