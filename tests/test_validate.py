"""Validation: holousd's rules catch broken scenes and name the prim and the fix; clean scenes pass."""

from __future__ import annotations

from pathlib import Path

from pxr import Sdf, Usd, UsdGeom

import holousd
from holousd import SceneGraph
from tests.usd_kit import assert_valid_usd


def _rules(stage: Usd.Stage) -> dict[str, list[holousd.usd.ValidationIssue]]:
    found: dict[str, list] = {}
    for issue in holousd.validate(stage).issues:
        found.setdefault(issue.rule, []).append(issue)
    return found


def test_example_scene_is_clean(example_dir: Path) -> None:
    assert_valid_usd(SceneGraph.open(example_dir / "scene.usda").stage)


def test_support_cycle(example_copy: Path) -> None:
    scene = SceneGraph.open(example_copy)
    scene.set_support("table", "mug")  # table -> mug -> book -> table
    issues = _rules(scene.stage)["holousd:support-cycle"]
    assert len(issues) == 1
    assert "/World/Objects/table" in issues[0].message and "/World/Objects/mug" in issues[0].message
    assert not holousd.validate(scene.stage).ok


def test_missing_collider(example_copy: Path) -> None:
    scene = SceneGraph.open(example_copy)
    scene.stage.RemovePrim("/World/Objects/mug/Collision")
    issues = _rules(scene.stage)["holousd:collider"]
    assert [i.where for i in issues] == ["/World/Objects/mug"]
    assert "set_collider" in issues[0].fix


def test_missing_mass(example_copy: Path) -> None:
    scene = SceneGraph.open(example_copy)
    scene.stage.GetPrimAtPath("/World/Objects/box").GetAttribute("physics:mass").Clear()
    assert [i.where for i in _rules(scene.stage)["holousd:mass"]] == ["/World/Objects/box"]


def test_missing_metadata(tmp_path: Path) -> None:
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.Xform.Define(stage, "/World")
    rules = _rules(stage)
    for rule in ("holousd:up-axis", "holousd:meters-per-unit", "holousd:kilograms-per-unit", "holousd:default-prim"):
        assert rule in rules, rule
    assert "metersPerUnit" in rules["holousd:meters-per-unit"][0].message
    # the OpenUSD validators flag it too
    assert any(rule.startswith("usdGeomValidators:StageMetadataChecker") for rule in rules)


def test_dangling_relationships(example_copy: Path) -> None:
    scene = SceneGraph.open(example_copy)
    mug = scene.stage.GetPrimAtPath("/World/Objects/mug")
    mug.GetRelationship("holo:supportedBy").SetTargets([Sdf.Path("/World/Objects/saucer")])
    mug.GetRelationship("holo:beside").SetTargets([Sdf.Path("/World/Objects/spoon")])
    issues = _rules(scene.stage)["holousd:dangling-relationship"]
    assert {i.where for i in issues} == {"/World/Objects/mug.holo:supportedBy", "/World/Objects/mug.holo:beside"}


def test_two_parents_and_no_parent(example_copy: Path) -> None:
    scene = SceneGraph.open(example_copy)
    stage = scene.stage
    stage.GetPrimAtPath("/World/Objects/mug").GetRelationship("holo:supportedBy").SetTargets(
        [Sdf.Path("/World/Objects/book"), Sdf.Path("/World/Objects/box")]
    )
    stage.GetPrimAtPath("/World/Objects/box").GetRelationship("holo:supportedBy").ClearTargets(True)
    issues = _rules(stage)["holousd:support-tree"]
    assert {i.where for i in issues} == {"/World/Objects/mug", "/World/Objects/box"}


def test_unknown_schema_version_and_api(example_copy: Path) -> None:
    scene = SceneGraph.open(example_copy)
    scene.stage.GetPrimAtPath("/World/Objects/mug").AddAppliedSchema("HoloWarpDriveAPI")
    scene.root_layer.customLayerData = {"holousd": {"schemaVersion": 99}}
    rules = _rules(scene.stage)
    assert rules["holousd:unknown-schema"][0].where == "/World/Objects/mug"
    assert "99" in rules["holousd:schema-version"][0].message


def test_unresolvable_assets(example_copy: Path) -> None:
    assets = example_copy.parent / "assets" / "scene"
    (assets / "book.sdf.npz").unlink()
    (assets / "box.splats.usdc").unlink()
    rules = _rules(SceneGraph.open(example_copy).stage)
    wheres = {i.where for i in rules["holousd:asset"]}
    assert wheres == {"/World/Objects/book.holo:sdf:file", "/World/Objects/box/Splats"}


def test_splat_binding_past_mesh(example_copy: Path) -> None:
    layer = Sdf.Layer.FindOrOpen(str(example_copy.parent / "assets" / "scene" / "mug.splats.usdc"))
    faces = list(layer.GetAttributeAtPath("/Splats.holo:gom:faceIndex").default)
    faces[0] = 10_000
    layer.GetAttributeAtPath("/Splats.holo:gom:faceIndex").default = faces
    layer.Save()
    issues = _rules(SceneGraph.open(example_copy).stage)["holousd:splat-binding"]
    assert "face index 10000" in issues[0].message


def test_one_geometry_rules(example_copy: Path) -> None:
    import numpy as np

    from holousd.usd import Collider, MeshData, Pose

    scene = SceneGraph.open(example_copy)
    assert not {"holousd:collider-reach", "holousd:overlap", "holousd:watertight"} & set(_rules(scene.stage))
    box = scene.get_mesh("box")
    lifted = MeshData(points=box.points + [0.0, 0.0, 0.05], faces=box.faces)  # a collider 5 cm above the mesh
    scene.set_collider("box", Collider(approximation="convexHull", parts=[lifted]))
    (reach,) = _rules(scene.stage)["holousd:collider-reach"]
    assert reach.where == "/World/Objects/box/Collision" and "5.0 cm outside" in reach.message
    scene.set_collider("box", Collider(approximation="convexHull", parts=[box]))
    assert "holousd:hull-vertices" not in _rules(scene.stage)
    import trimesh

    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.02)  # a hull of 642 vertices
    scene.set_collider("box", Collider(approximation="convexDecomposition", parts=[
        box, MeshData(points=np.asarray(ball.vertices) + box.points.mean(axis=0), faces=np.asarray(ball.faces))]))
    (many,) = _rules(scene.stage)["holousd:hull-vertices"]
    assert many.severity == "info" and holousd.validate(scene.stage).ok  # a note, not a problem
    assert "1 of 2 collider parts are hulls of more than 64 vertices (up to 642)" in many.message
    scene.set_collider("box", Collider(approximation="convexHull", parts=[box]))
    mug = scene.get_pose("mug")
    scene.set_pose("box", Pose(translation=np.asarray(mug.translation) + [0.03, 0.0, 0.0]))  # into the mug
    (overlap,) = _rules(scene.stage)["holousd:overlap"]
    assert "box" in overlap.message and "mug" in overlap.message and "cm^3" in overlap.message
    scene.set_mesh("book", MeshData(points=scene.get_mesh("book").points, faces=scene.get_mesh("book").faces[:-2]))
    (hole,) = _rules(scene.stage)["holousd:watertight"]
    assert hole.where == "/World/Objects/book/Geom"
