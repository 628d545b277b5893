"""SceneGraph: round trips of every node property, layers, edits, flattening and bad input."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics

import holousd
from holousd import (
    BACKGROUND,
    Collider,
    Energies,
    GaussianSplats,
    InvalidDataError,
    MeshData,
    PhysicsProps,
    Pose,
    SceneError,
    SceneGraph,
    SchemaVersionError,
    SdfField,
)
from tests.usd_kit import assert_no_tf_diagnostics, assert_valid_usd

CUBE = MeshData(
    points=[[x, y, z] for x in (-0.1, 0.1) for y in (-0.1, 0.1) for z in (-0.1, 0.1)],
    faces=[[0, 1, 2], [1, 3, 2], [4, 6, 5], [5, 6, 7], [0, 4, 1], [1, 4, 5],
           [2, 3, 6], [3, 7, 6], [0, 2, 4], [2, 6, 4], [1, 5, 3], [3, 5, 7]],
)  # fmt: skip


def _splats(n: int, rng: np.random.Generator, bound: bool = True) -> GaussianSplats:
    quat = rng.normal(size=(n, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    bary = rng.random((n, 3))
    bary /= bary.sum(axis=1, keepdims=True)
    binding = (
        dict(
            face_index=rng.integers(0, 12, n),
            barycentric=bary,
            normal_offset=rng.normal(size=n) * 1e-3,
            in_plane_rotation=rng.random(n) * np.pi,
            in_plane_scale=rng.random((n, 2)) * 0.01,
        )
        if bound
        else {}
    )
    return GaussianSplats(
        positions=rng.normal(size=(n, 3)),
        orientations=quat,
        scales=rng.random((n, 3)) * 0.01,
        opacities=rng.random(n),
        sh_coeffs=rng.normal(size=(n, 4, 3)),
        **binding,
    )


def _full_scene(path: Path) -> tuple[SceneGraph, dict]:
    """A scene with every property of every kind authored; returns it and the values written."""
    rng = np.random.default_rng(7)
    scene = SceneGraph.create(path)
    scene.add_background()
    scene.set_mesh(BACKGROUND, CUBE)
    scene.set_collider(BACKGROUND, Collider(approximation="none", parts=[CUBE]))
    scene.set_physics(BACKGROUND, PhysicsProps(mass=None, static_friction=0.8, dynamic_friction=0.7))
    pose = Pose(translation=[0.5, -0.25, 1.0], orientation=[0.0, 0.0, np.sin(0.3), np.cos(0.3)])
    scene.add_object("crate", instance_id=3, pose=pose, observed_fraction=0.6)
    scene.add_object("lid", instance_id=4)
    values = {
        "pose": pose,
        "mesh": CUBE,
        "sdf": SdfField(grid=rng.normal(size=(5, 6, 7)), origin=[-0.2, -0.2, -0.2], voxel_size=0.05, iso_level=0.01),
        "splats": _splats(50, rng),
        "unbound": _splats(20, rng, bound=False),
        "physics": PhysicsProps(
            mass=2.5,
            center_of_mass=[0.0, 0.01, -0.02],
            diagonal_inertia=[0.1, 0.2, 0.3],
            density=450.0,
            static_friction=0.6,
            dynamic_friction=0.4,
            restitution=0.1,
            linear_damping=0.5,
            angular_damping=0.25,
        ),  # fmt: skip
        "collider": Collider(approximation="convexDecomposition", parts=[CUBE, CUBE]),
        "energies": Energies(stable=1.5, touch=0.002, penetration=1e-6, candidate=2, stands_once_set_up=True),
    }
    scene.set_mesh("crate", values["mesh"])
    scene.set_sdf("crate", values["sdf"])
    scene.set_gaussians("crate", values["splats"])
    scene.set_gaussians("lid", values["unbound"])
    scene.set_physics("lid", PhysicsProps(mass=0.2))
    scene.set_collider("lid", Collider(approximation="convexHull", parts=[CUBE]))
    scene.set_physics("crate", values["physics"])
    scene.set_collider("crate", values["collider"])
    scene.set_support("crate", BACKGROUND)
    scene.set_support("lid", "crate")
    scene.set_beside("crate", ["lid"])
    scene.set_energies("crate", values["energies"])
    return scene, values


def _check_full_scene(scene: SceneGraph, values: dict) -> None:
    pose = scene.get_pose("crate")
    np.testing.assert_allclose(pose.translation, values["pose"].translation, atol=1e-9)
    np.testing.assert_allclose(pose.orientation, values["pose"].orientation, atol=1e-9)
    mesh = scene.get_mesh("crate")
    np.testing.assert_allclose(mesh.points, values["mesh"].points, atol=1e-7)
    np.testing.assert_array_equal(mesh.faces, values["mesh"].faces)
    sdf = scene.get_sdf("crate")
    np.testing.assert_array_equal(sdf.grid, values["sdf"].grid)
    np.testing.assert_allclose(sdf.origin, values["sdf"].origin)
    assert sdf.voxel_size == values["sdf"].voxel_size and sdf.iso_level == values["sdf"].iso_level
    for name, key in (("crate", "splats"), ("lid", "unbound")):
        got, want = scene.get_gaussians(name), values[key]
        for attr in ("positions", "orientations", "scales", "opacities", "sh_coeffs", "face_index", "barycentric",
                     "normal_offset", "in_plane_rotation", "in_plane_scale"):  # fmt: skip
            a, b = getattr(got, attr), getattr(want, attr)
            if b is None:
                assert a is None, attr
            else:
                np.testing.assert_array_equal(a, b, err_msg=attr)
    physics = scene.get_physics("crate")
    want = values["physics"]
    for attr in ("mass", "density", "static_friction", "dynamic_friction", "restitution", "linear_damping",
                 "angular_damping"):  # fmt: skip
        assert getattr(physics, attr) == pytest.approx(getattr(want, attr)), attr
    np.testing.assert_allclose(physics.center_of_mass, want.center_of_mass, atol=1e-7)
    np.testing.assert_allclose(physics.diagonal_inertia, want.diagonal_inertia, atol=1e-7)
    background = scene.get_physics(BACKGROUND)
    assert background.mass is None and background.static_friction == pytest.approx(0.8)
    collider = scene.get_collider("crate")
    assert collider.approximation == "convexDecomposition" and len(collider.parts) == 2
    assert scene.get_collider(BACKGROUND).approximation == "none"
    assert scene.get_support("crate") == BACKGROUND and scene.get_support("lid") == "crate"
    assert scene.get_beside("crate") == ["lid"]
    energies, want_e = scene.get_energies("crate"), values["energies"]
    for attr in ("stable", "touch", "penetration"):  # float32 in the schema
        assert getattr(energies, attr) == pytest.approx(getattr(want_e, attr), rel=1e-6), attr
    assert energies.candidate == want_e.candidate and energies.stands_once_set_up and energies.stands
    assert scene.get_energies("lid") is None
    info = scene.node_info("crate")
    assert (info.role, info.instance_id, info.observed_fraction) == ("object", 3, pytest.approx(0.6))
    assert [n.name for n in scene.nodes()] == [BACKGROUND, "crate", "lid"]


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_round_trip_every_property(tmp_path: Path, suffix: str, capfd: pytest.CaptureFixture) -> None:
    scene, values = _full_scene(tmp_path / f"scene{suffix}")
    _check_full_scene(scene, values)  # in memory
    saved = scene.save()
    reopened = SceneGraph.open(saved)
    _check_full_scene(reopened, values)
    assert_valid_usd(reopened.stage)
    assert_no_tf_diagnostics(capfd)


def test_every_holo_value_is_authored(tmp_path: Path) -> None:
    """Nothing the scene depends on is left to schema fallbacks (a viewer without our plugin reads it all)."""
    scene, _ = _full_scene(tmp_path / "scene.usda")
    registry = Usd.SchemaRegistry()
    for prim in scene.stage.Traverse():
        for api in prim.GetAppliedSchemas():
            definition = registry.FindAppliedAPIPrimDefinition(api) if api.startswith("Holo") else None
            if definition is None:
                continue
            for name in definition.GetPropertyNames():
                prop = prim.GetProperty(name)
                authored = prop.HasAuthoredValue() if isinstance(prop, Usd.Attribute) else prop.HasAuthoredTargets()
                if name == "holo:gom:mesh" or isinstance(prop, Usd.Attribute):
                    assert authored, f"{prim.GetPath()}.{name} is not authored"


def test_layout_and_metadata(tmp_path: Path) -> None:
    scene, _ = _full_scene(tmp_path / "scene.usda")
    stage = scene.stage
    assert UsdGeom.GetStageUpAxis(stage) == "Z"
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert UsdPhysics.GetStageKilogramsPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/World")
    gravity = UsdPhysics.Scene(stage.GetPrimAtPath("/World/PhysicsScene"))
    assert tuple(gravity.GetGravityDirectionAttr().Get()) == (0, 0, -1)
    assert gravity.GetGravityMagnitudeAttr().Get() == pytest.approx(9.81)
    crate = stage.GetPrimAtPath("/World/Objects/crate")
    assert crate.HasAPI(UsdPhysics.RigidBodyAPI) and crate.HasAPI(UsdPhysics.MassAPI)
    assert not stage.GetPrimAtPath("/World/Background").HasAPI(UsdPhysics.RigidBodyAPI)
    parts = stage.GetPrimAtPath("/World/Objects/crate/Collision").GetChildren()
    assert [p.GetName() for p in parts] == ["Part_000", "Part_001"]
    for part in parts:
        assert UsdPhysics.MeshCollisionAPI(part).GetApproximationAttr().Get() == "convexHull"
        assert UsdGeom.Imageable(part).GetPurposeAttr().Get() == "guide"
    splat_prim = stage.GetPrimAtPath("/World/Objects/crate/Splats")
    assert splat_prim.GetTypeName() == "ParticleField3DGaussianSplat"
    assert splat_prim.GetRelationship("holo:gom:mesh").GetTargets() == [Sdf.Path("/World/Objects/crate/Geom")]
    # heavy data lives in per-object files beside the layer
    assert (tmp_path / "assets" / "scene" / "crate.splats.usdc").is_file()
    assert (tmp_path / "assets" / "scene" / "crate.sdf.npz").is_file()


def test_pose_under_moved_parent_is_world_pose(tmp_path: Path) -> None:
    scene = SceneGraph.create()
    scene.add_object("a", instance_id=1)
    UsdGeom.Xformable(scene.stage.GetPrimAtPath("/World")).AddTranslateOp().Set((1.0, 2.0, 3.0))
    pose = Pose(translation=[0.3, 0.2, 0.1], orientation=[np.sin(0.5), 0.0, 0.0, np.cos(0.5)])
    scene.set_pose("a", pose)
    got = scene.get_pose("a")
    np.testing.assert_allclose(got.translation, pose.translation, atol=1e-9)
    np.testing.assert_allclose(got.orientation, pose.orientation, atol=1e-9)


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}  # fmt: skip


def test_stage_layers_record_who_wrote_what(tmp_path: Path) -> None:
    """Each stage transform writes its own layer; property stacks say which layer wrote a value."""
    scene = SceneGraph.create(tmp_path / "00_observe.usda", provenance="s0_observe")
    scene.add_background()
    scene.add_object("cup", instance_id=1)
    scene.save()
    scene.push_layer(tmp_path / "10_fit.usda", provenance="s1_fit")
    scene.set_mesh("cup", CUBE)
    scene.set_sdf("cup", SdfField(grid=np.ones((3, 3, 3)), origin=[0, 0, 0], voxel_size=0.1))
    scene.save()
    scene.push_layer(tmp_path / "20_physics.usda", provenance="s2_physics")
    scene.set_pose("cup", Pose(translation=[0, 0, 0.1]))
    scene.set_physics("cup", PhysicsProps(mass=0.3))
    scene.save()

    stage = Usd.Stage.Open(str(tmp_path / "20_physics.usda"))
    cup = stage.GetPrimAtPath("/World/Objects/cup")

    def writer(attr: Usd.Attribute) -> str:
        return Path(attr.GetPropertyStack(Usd.TimeCode.Default())[0].layer.identifier).name

    assert writer(cup.GetAttribute("holo:node:instanceId")) == "00_observe.usda"
    assert writer(stage.GetPrimAtPath("/World/Objects/cup/Geom").GetAttribute("points")) == "10_fit.usda"
    assert writer(cup.GetAttribute("holo:sdf:voxelSize")) == "10_fit.usda"
    assert writer(cup.GetAttribute("xformOp:translate")) == "20_physics.usda"
    assert writer(cup.GetAttribute("physics:mass")) == "20_physics.usda"
    assert cup.GetAttribute("holo:node:provenance").Get() == "s2_physics"
    # every layer carries the root metadata, so each opens as a complete scene
    for name in ("00_observe.usda", "10_fit.usda", "20_physics.usda"):
        layer = Sdf.Layer.FindOrOpen(str(tmp_path / name))
        assert layer.pseudoRoot.GetInfo("upAxis") == "Z"
        assert layer.pseudoRoot.GetInfo("metersPerUnit") == 1.0
        assert layer.defaultPrim == "World"
    # the fit layer holds only what it changed
    fit = Sdf.Layer.FindOrOpen(str(tmp_path / "10_fit.usda"))
    assert fit.GetPrimAtPath("/World/PhysicsScene") is None
    # stage assets are kept per layer: a later SDF does not overwrite an earlier one
    assert (tmp_path / "assets" / "10_fit" / "cup.sdf.npz").is_file()


def test_edit_layer_leaves_lower_files_identical(example_copy: Path) -> None:
    folder = example_copy.parent
    before = _digest(folder)
    scene = SceneGraph.open(example_copy)
    moved = Pose(translation=[1.0, -1.0, 0.0])
    with scene.edit(folder / "edit_move.usda"):
        scene.set_pose("box", moved)
        scene.set_physics("box", PhysicsProps(mass=5.0))
    after = _digest(folder)
    after.pop("edit_move.usda")
    assert after == before
    np.testing.assert_allclose(SceneGraph.open(folder / "edit_move.usda").get_pose("box").translation, [1, -1, 0])
    np.testing.assert_allclose(SceneGraph.open(example_copy).get_pose("box").translation, [0.08, 0.3, 0.72])
    # the SceneGraph now shows the edited scene; a second edit stacks on the first
    with scene.edit(folder / "edit_more.usda"):
        scene.set_support("box", "background")
    edited = SceneGraph.open(folder / "edit_more.usda")
    assert edited.get_support("box") == BACKGROUND
    assert edited.get_physics("box").mass == pytest.approx(5.0)


def test_failed_edit_writes_nothing(example_copy: Path) -> None:
    scene = SceneGraph.open(example_copy)
    with pytest.raises(RuntimeError), scene.edit(example_copy.parent / "edit_bad.usda"):
        scene.set_pose("box", Pose(translation=[9, 9, 9]))
        raise RuntimeError("user code failed")
    assert not (example_copy.parent / "edit_bad.usda").exists()
    np.testing.assert_allclose(scene.get_pose("box").translation, [0.08, 0.3, 0.72])


def test_reopening_edit_layer_appends(example_copy: Path) -> None:
    edit = example_copy.parent / "edit_a.usda"
    scene = SceneGraph.open(example_copy)
    with scene.edit(edit):
        scene.set_pose("mug", Pose(translation=[0, 0, 2]))
    scene = SceneGraph.open(example_copy)
    with scene.edit(edit):
        scene.set_pose("box", Pose(translation=[0, 0, 3]))
    final = SceneGraph.open(edit)
    assert final.get_pose("mug").translation[2] == pytest.approx(2)
    assert final.get_pose("box").translation[2] == pytest.approx(3)


def test_edit_layer_name_clash_refused(example_copy: Path) -> None:
    other = example_copy.parent / "other.usda"
    SceneGraph.create(other).save()
    scene = SceneGraph.open(example_copy)
    with pytest.raises(SceneError, match="does not sublayer"), scene.edit(other):
        pass


def test_flatten_is_self_contained(example_copy: Path, tmp_path: Path) -> None:
    flat = SceneGraph.open(example_copy).flatten(tmp_path / "flat" / "flat.usda")
    layer = Sdf.Layer.FindOrOpen(str(flat))
    assert not layer.subLayerPaths and not layer.GetExternalReferences()
    scene = SceneGraph.open(flat)
    assert len(scene.get_gaussians("mug")) == 2000
    assert scene.get_support("mug") == "book"


def test_large_arrays_and_long_time_samples_go_to_a_crate_file_under_the_text_layer(tmp_path: Path) -> None:
    from holousd.usd import data_layer_path

    scene = SceneGraph.create(tmp_path / "scene.usda")
    scene.add_object("cup", instance_id=1)
    big = MeshData(points=np.random.default_rng(0).normal(size=(100, 3)), faces=np.tile([0, 1, 2], (40, 1)))
    scene.set_mesh("cup", big)
    prim = scene.stage.GetPrimAtPath("/World/Objects/cup")
    prim.CreateAttribute("holo:test:few", Sdf.ValueTypeNames.FloatArray).Set([1.0, 2.0])
    images = prim.CreateAttribute("holo:test:images", Sdf.ValueTypeNames.AssetArray)
    images.Set(Sdf.AssetPathArray([f"./frames/{k}.png" for k in range(80)]))  # paths stay where they resolve
    spin = prim.CreateAttribute("holo:test:spin", Sdf.ValueTypeNames.Float)
    for t in range(6):
        spin.Set(float(t), Usd.TimeCode(t))
    path = scene.save()
    data = data_layer_path(path)
    assert data == tmp_path / "assets" / "scene" / "arrays.usdc" and data.is_file()
    text = Sdf.Layer.OpenAsAnonymous(str(path))
    assert list(text.subLayerPaths) == ["./assets/scene/arrays.usdc"]
    assert text.GetAttributeAtPath("/World/Objects/cup/Geom.points") is None  # 100 points: in the crate file
    assert text.GetAttributeAtPath("/World/Objects/cup/Geom.faceVertexIndices") is None  # 120 indices
    assert len(text.GetAttributeAtPath("/World/Objects/cup/Geom.faceVertexCounts").default) == 40  # not > 64
    assert text.GetAttributeAtPath("/World/Objects/cup.holo:test:spin") is None  # 6 time samples
    assert list(text.GetAttributeAtPath("/World/Objects/cup.holo:test:few").default) == [1.0, 2.0]
    assert len(text.GetAttributeAtPath("/World/Objects/cup.holo:test:images").default) == 80

    reread = SceneGraph.open(path)  # a fresh read composes the same scene
    np.testing.assert_allclose(reread.get_mesh("cup").points, big.points, atol=1e-6)
    assert reread.stage.GetPrimAtPath("/World/Objects/cup").GetAttribute("holo:test:spin").Get(5) == 5.0
    # Saving again a layer read back from disk folds its crate file in and splits it again; new values win.
    disk = Sdf.Layer.OpenAsAnonymous(str(path))  # the text layer as a fresh process reads it
    points = Sdf.AttributeSpec(disk.GetPrimAtPath("/World/Objects/cup/Geom"), "points", Sdf.ValueTypeNames.Point3fArray)
    points.default = [(0.0, 0.0, 0.0)] * 100
    holousd.usd.save_layer(disk, path)
    fresh = Sdf.Layer.OpenAsAnonymous(str(data))
    assert np.abs(np.asarray(fresh.GetAttributeAtPath("/World/Objects/cup/Geom.points").default)).max() == 0.0
    assert fresh.GetAttributeAtPath("/World/Objects/cup.holo:test:spin") is not None
    # Saved elsewhere, a layer read from disk takes its crate data along (folded from its own data file).
    moved = tmp_path.parent / f"{tmp_path.name}_moved"
    shutil.copytree(tmp_path, moved)  # a layer no process has open yet
    read = Sdf.Layer.FindOrOpen(str(moved / "scene.usda"))
    assert list(read.subLayerPaths) == ["./assets/scene/arrays.usdc"]
    # a layer whose data file went missing is not saved without it
    (moved / "assets" / "scene" / "arrays.usdc").rename(moved / "arrays_elsewhere.usdc")
    with pytest.raises(SceneError, match="data file .* is missing"):
        holousd.usd.save_layer(read, tmp_path / "copy.usda")
    (moved / "arrays_elsewhere.usdc").rename(moved / "assets" / "scene" / "arrays.usdc")
    assert not (tmp_path / "copy.usda").exists()
    copy = holousd.usd.save_layer(read, tmp_path / "copy.usda")
    assert data_layer_path(copy).is_file()
    assert np.abs(SceneGraph.open(copy).get_mesh("cup").points).max() == 0.0
    assert SceneGraph.open(copy).stage.GetPrimAtPath("/World/Objects/cup").GetAttribute("holo:test:spin").Get(5) == 5
    # A layer with nothing large keeps no crate file; a flattened copy is one self-contained file.
    small = SceneGraph.create(tmp_path / "small.usda")
    small.add_object("cup", instance_id=1)
    assert not data_layer_path(small.save()).exists()
    flat = scene.flatten(tmp_path / "flat.usda")
    assert not Sdf.Layer.OpenAsAnonymous(str(flat)).subLayerPaths and not data_layer_path(flat).exists()


def test_set_collider_deactivates_stale_parts(tmp_path: Path) -> None:
    scene = SceneGraph.create(tmp_path / "a.usda")
    scene.add_object("t", instance_id=1)
    scene.set_collider("t", Collider(approximation="convexDecomposition", parts=[CUBE, CUBE, CUBE]))
    scene.save()
    scene.push_layer(tmp_path / "b.usda")
    scene.set_collider("t", Collider(approximation="convexHull", parts=[CUBE]))
    collider = scene.get_collider("t")
    assert collider.approximation == "convexHull" and len(collider.parts) == 1


def test_simulator_side_decomposition_round_trips() -> None:
    scene = SceneGraph.create()
    scene.add_object("t", instance_id=1)
    scene.set_collider("t", Collider(approximation="convexDecomposition", parts=[CUBE]))
    part = scene.stage.GetPrimAtPath("/World/Objects/t/Collision/Part_000")
    assert UsdPhysics.MeshCollisionAPI(part).GetApproximationAttr().Get() == "convexDecomposition"
    assert scene.get_collider("t").approximation == "convexDecomposition"


# ---------------------------------------------------------------- bad input


def test_open_missing_and_non_usd_files(tmp_path: Path) -> None:
    with pytest.raises(SceneError, match="no such file"):
        SceneGraph.open(tmp_path / "nope.usda")
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(SceneError, match="not a USD file"):
        SceneGraph.open(text)
    corrupt = tmp_path / "corrupt.usda"
    corrupt.write_text('#usda 1.0\n def Xform "World" {{{ garbage')
    with pytest.raises(SceneError, match=r"corrupt\.usda: cannot be read as USD"):
        SceneGraph.open(corrupt)
    binary = tmp_path / "corrupt.usdc"
    binary.write_bytes(b"PXR-USDC" + bytes(range(256)) * 4)
    with pytest.raises(SceneError, match=r"corrupt\.usdc"):
        SceneGraph.open(binary)


def test_newer_schema_version_refused(tmp_path: Path) -> None:
    path = tmp_path / "future.usda"
    scene = SceneGraph.create(path)
    scene.root_layer.customLayerData = {"holousd": {"schemaVersion": holousd.SCHEMA_VERSION + 1}}
    scene.save()
    with pytest.raises(SchemaVersionError, match="future.usda: written with holousd schema version 2"):
        SceneGraph.open(path)


def test_create_refuses_to_clobber(example_copy: Path) -> None:
    before = example_copy.read_bytes()
    with pytest.raises(SceneError, match="already exists"):
        SceneGraph.create(example_copy)
    assert example_copy.read_bytes() == before


def test_inconsistent_arrays_rejected() -> None:
    rng = np.random.default_rng(0)
    good = _splats(4, rng)
    with pytest.raises(InvalidDataError, match=r"GaussianSplats.scales: expected shape \[4x3\]"):
        GaussianSplats(positions=good.positions, orientations=good.orientations, scales=good.scales[:3],
                       opacities=good.opacities, sh_coeffs=good.sh_coeffs)  # fmt: skip
    with pytest.raises(InvalidDataError, match="all or nothing"):
        GaussianSplats(positions=good.positions, orientations=good.orientations, scales=good.scales,
                       opacities=good.opacities, sh_coeffs=good.sh_coeffs, face_index=good.face_index)  # fmt: skip
    with pytest.raises(InvalidDataError, match="NaN"):
        Pose(translation=[0, np.nan, 0])
    with pytest.raises(InvalidDataError, match="indices must lie"):
        MeshData(points=np.zeros((3, 3)), faces=[[0, 1, 3]])
    with pytest.raises(InvalidDataError, match="mass"):
        PhysicsProps(mass=-1.0)
    with pytest.raises(InvalidDataError, match="valid object name"):
        SceneGraph.create().add_object("my mug", instance_id=1)


def test_inconsistent_arrays_in_file_name_the_prim(example_copy: Path) -> None:
    splat_file = example_copy.parent / "assets" / "scene" / "mug.splats.usdc"
    layer = Sdf.Layer.FindOrOpen(str(splat_file))
    layer.GetAttributeAtPath("/Splats.opacities").default = [0.5] * 10
    layer.Save()
    scene = SceneGraph.open(example_copy)
    with pytest.raises(SceneError, match=r"/World/Objects/mug/Splats: inconsistent splat arrays"):
        scene.get_gaussians("mug")
    report = holousd.validate(scene.stage)
    assert any(i.rule == "holousd:splat-arrays" and "opacities" in i.where for i in report.issues)


def test_missing_sdf_asset_names_the_prim(example_copy: Path) -> None:
    (example_copy.parent / "assets" / "scene" / "mug.sdf.npz").unlink()
    scene = SceneGraph.open(example_copy)
    with pytest.raises(SceneError, match=r"/World/Objects/mug: SDF file .* cannot be found"):
        scene.get_sdf("mug")


def test_in_memory_scene_cannot_hold_assets() -> None:
    scene = SceneGraph.create()
    scene.add_object("a", instance_id=1)
    with pytest.raises(SceneError, match="in memory"):
        scene.set_sdf("a", SdfField(grid=np.zeros((2, 2, 2)), origin=[0, 0, 0], voxel_size=0.1))


def test_unknown_node_is_clear() -> None:
    with pytest.raises(SceneError, match="no node 'ghost'"):
        SceneGraph.create().get_pose("ghost")


def test_camera_round_trip_and_usd_projection_agree(tmp_path: Path) -> None:
    """The UsdGeom.Camera we author projects points exactly where the OpenCV pinhole does."""
    from scipy.spatial.transform import Rotation

    scene = SceneGraph.create(tmp_path / "cams.usda")
    K = np.array([[300.0, 0, 140.0], [0, 280.0, 100.0], [0, 0, 1]])
    c2w = np.eye(4)
    c2w[:3, :3] = Rotation.from_euler("xyz", [-110, 5, 30], degrees=True).as_matrix()
    c2w[:3, 3] = [0.5, -2.0, 1.4]
    image = tmp_path / "frames" / "000012.png"
    camera = holousd.CameraData(name="Frame_00012", K=K, cam_to_world=c2w, width=256, height=192,
                                image=str(image), frame_id="000012")  # fmt: skip
    scene.set_camera(camera)
    scene.save()
    (got,) = SceneGraph.open(tmp_path / "cams.usda").get_cameras()
    np.testing.assert_allclose(got.K, K, atol=1e-4)
    np.testing.assert_allclose(got.cam_to_world, c2w, atol=1e-9)
    assert (got.width, got.height, got.frame_id) == (256, 192, "000012")
    assert Path(got.image) == image  # stored relative to the layer, resolved back
    # project with USD's own camera model (Gf.Camera) and compare with the pinhole
    gf = UsdGeom.Camera(scene.stage.GetPrimAtPath("/World/Cameras/Frame_00012")).GetCamera(Usd.TimeCode.Default())
    gf.clippingRange = Gf.Range1f(0.01, 100.0)
    view_proj = gf.frustum.ComputeViewMatrix() * gf.frustum.ComputeProjectionMatrix()
    rng = np.random.default_rng(1)
    cam_points = np.c_[rng.uniform(-0.5, 0.5, (20, 2)), rng.uniform(1.0, 4.0, 20)]  # in front of the camera
    for pc in cam_points:
        pw = c2w[:3, :3] @ pc + c2w[:3, 3]
        clip = Gf.Vec4d(*pw, 1.0) * view_proj
        ndc = np.array([clip[0], clip[1]]) / clip[3]
        usd_pixel = [(ndc[0] + 1) / 2 * 256, (1 - ndc[1]) / 2 * 192]
        cv_pixel = (K @ pc)[:2] / pc[2]
        np.testing.assert_allclose(usd_pixel, cv_pixel, atol=1e-3)
