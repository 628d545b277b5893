"""Splat exchange: ``holousd export --ply`` writes the 3DGS layout, read back with an independent reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdShade
from scipy.spatial.transform import Rotation

from holousd import Pose, SceneGraph
from holousd.cli import main
from holousd.render import sh_to_rgb
from holousd.render._binding import splats_in_world
from holousd.render._exchange import rotate_sh

plyfile = pytest.importorskip("plyfile", reason="plyfile (the dev extra) reads the exported .ply files back")


def _rgb(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    import torch

    return sh_to_rgb(torch.tensor(np.asarray(sh, np.float64)), torch.tensor(dirs)).numpy()


def _read(path: Path) -> dict[str, np.ndarray]:
    vertex = plyfile.PlyData.read(str(path))["vertex"]
    return {name: np.asarray(vertex[name], np.float64) for name in vertex.data.dtype.names}


def test_export_ply_round_trips_through_plyfile(example_copy: Path, tmp_path: Path, capsys) -> None:
    scene = SceneGraph.open(example_copy)
    scene_file = example_copy.parent / "edit_turn.usda"
    with scene.edit(scene_file):  # a turned node with view-dependent colour: its splats and SH turn with it
        turn = Rotation.from_euler("z", 35.0, degrees=True).as_quat()
        scene.set_pose("mug", Pose(translation=scene.get_pose("mug").translation, orientation=turn))
        splats = scene.get_gaussians("mug")
        higher = np.random.default_rng(0).normal(scale=0.1, size=(len(splats), 3, 3))
        splats.sh_coeffs = np.concatenate([splats.sh_coeffs[:, :1], higher], axis=1).astype(np.float32)
        scene.set_gaussians("mug", splats)
    out = tmp_path / "ply"
    assert main(["export", str(scene_file), "--ply", str(out)]) == 0
    assert "scene.ply" in capsys.readouterr().out
    scene = SceneGraph.open(scene_file)
    names = [n.name for n in scene.nodes() if scene.stage.GetPrimAtPath(n.path).GetChild("Splats")]
    assert "mug" in names and scene.get_gaussians("mug").sh_degree == 1
    total = 0
    for name in names:
        ply = _read(out / f"{name}.ply")
        splats = scene.get_gaussians(name)
        centres, rotations, scales = splats_in_world(splats, scene.get_pose(name), scene.get_mesh(name)
                                                     if splats.bound else None)  # fmt: skip
        k = splats.sh_coeffs.shape[1]
        assert len(ply["x"]) == len(splats) > 0
        np.testing.assert_allclose(np.stack([ply["x"], ply["y"], ply["z"]], 1), centres, atol=1e-6)
        np.testing.assert_allclose(1 / (1 + np.exp(-ply["opacity"])), splats.opacities, atol=1e-5)
        np.testing.assert_allclose(np.exp(np.stack([ply[f"scale_{i}"] for i in range(3)], 1)), scales, rtol=1e-5)
        wxyz = np.stack([ply[f"rot_{i}"] for i in range(4)], 1)
        np.testing.assert_allclose(np.linalg.norm(wxyz, axis=1), 1.0, atol=1e-5)
        read = Rotation.from_quat(np.concatenate([wxyz[:, 1:], wxyz[:, :1]], 1)).as_matrix()
        np.testing.assert_allclose(read, rotations, atol=1e-5)
        assert sum(key.startswith("f_rest_") for key in ply) == 3 * (k - 1)
        # the colour seen along a world direction is the stored colour seen along the object's direction
        dc = np.stack([ply[f"f_dc_{c}"] for c in range(3)], 1)
        rest = np.zeros((len(splats), 3, k - 1))  # f_rest_{c (K-1) + j}: coefficient j + 1 of colour c
        for i in range(3 * (k - 1)):
            rest[:, i // (k - 1), i % (k - 1)] = ply[f"f_rest_{i}"]
        world_sh = np.concatenate([dc[:, None, :], np.transpose(rest, (0, 2, 1))], axis=1)
        dirs = np.random.default_rng(0).normal(size=(len(splats), 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        rot = scene.get_pose(name).rotation_matrix()
        np.testing.assert_allclose(_rgb(world_sh, dirs), _rgb(splats.sh_coeffs, dirs @ rot), atol=1e-5)
        total += len(splats)
    assert len(_read(out / "scene.ply")["x"]) == total
    assert not list(out.glob(".*"))  # no temporary file left behind


def test_sh_rotation_is_exact_for_every_band() -> None:
    rng = np.random.default_rng(1)
    sh = rng.normal(size=(50, 16, 3))
    rot = Rotation.from_euler("xyz", [20.0, -40.0, 70.0], degrees=True).as_matrix()
    dirs = rng.normal(size=(50, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    world = _rgb(rotate_sh(sh, rot) * 0.01, dirs)  # small coefficients: the clamp at 0 stays off
    np.testing.assert_allclose(world, _rgb(sh * 0.01, dirs @ rot), atol=1e-9)
    back = rotate_sh(rotate_sh(sh, rot), rot.T)
    np.testing.assert_allclose(back, sh, atol=1e-9)
    assert not np.allclose(rotate_sh(sh, rot)[:, 1:], sh[:, 1:])  # it did turn


def test_export_ply_refuses_a_file_and_a_scene_without_splats(tmp_path: Path, example_copy: Path, capsys) -> None:
    target = tmp_path / "taken.ply"
    target.write_text("keep me")
    assert main(["export", str(example_copy), "--ply", str(target)]) != 0
    assert "--ply takes a folder" in capsys.readouterr().err and target.read_text() == "keep me"
    bare = SceneGraph.create(tmp_path / "bare.usda")
    bare.add_background()
    bare.save()
    assert main(["export", str(tmp_path / "bare.usda"), "--ply", str(tmp_path / "out")]) != 0
    assert "no node has Gaussian splats" in capsys.readouterr().err and not (tmp_path / "out").exists()


def test_export_glb_has_world_meshes_turned_y_up_with_their_colours(example_copy: Path, tmp_path: Path) -> None:
    import trimesh

    scene = SceneGraph.open(example_copy)
    edited = example_copy.parent / "edit_colour.usda"
    with scene.edit(edited):
        points = scene.get_mesh("book").points
        red = np.tile([0.8, 0.1, 0.05], (len(points), 1))
        scene.set_surface_color("book", red)
    out = tmp_path / "glb"
    assert main(["export", str(edited), "--glb", str(out)]) == 0
    scene = SceneGraph.open(edited)
    meshes = [n.name for n in scene.nodes() if scene.stage.GetPrimAtPath(n.path).GetChild("Geom")]
    assert sorted(p.stem for p in out.glob("*.glb")) == sorted([*meshes, "scene"])
    book = trimesh.load(out / "book.glb", force="mesh", process=False)
    world = scene.get_pose("book").apply(scene.get_mesh("book").points)
    np.testing.assert_allclose(book.vertices, np.stack([world[:, 0], world[:, 2], -world[:, 1]], 1), atol=1e-5)
    np.testing.assert_allclose(book.visual.vertex_colors[:, :3] / 255.0, red, atol=1 / 255)
    mug = trimesh.load(out / "mug.glb", force="mesh", process=False)
    assert np.all(mug.visual.vertex_colors[:, :3] == 128)  # no colour baked: grey
    whole = trimesh.load(out / "scene.glb", process=False)
    assert sorted(whole.geometry) == sorted(meshes)


def test_texture_baked_from_the_splats_is_bound_through_a_preview_surface(example_copy: Path) -> None:
    from holousd import InvalidDataError, SceneError
    from holousd.render._bake import bake_texture, sample_texture, srgb_from_linear, surface_srgb, vertex_colors

    scene = SceneGraph.open(example_copy)
    mesh, splats = scene.get_mesh("table"), scene.get_gaussians("table")
    texture = bake_texture(mesh, splats)
    assert texture.st.shape == (len(mesh.faces), 3, 2) and texture.image.dtype == np.uint8
    assert texture.st.min() >= 0.0 and texture.st.max() <= 1.0 and max(texture.image.shape[:2]) <= 1024
    rng = np.random.default_rng(0)  # random points on random faces: the texture gives the splats' colour there
    faces = rng.integers(0, len(mesh.faces), 500)
    bary = rng.dirichlet(np.ones(3), 500)
    points = np.einsum("nk,nkc->nc", bary, mesh.points[mesh.faces[faces]])
    st = np.einsum("nk,nkc->nc", bary, texture.st[faces])
    direct = surface_srgb(points, mesh, splats)
    assert np.abs(sample_texture(texture.image, st) - direct).mean() < 6.0 / 255.0
    # and it is more faithful than the per-point colours interpolated across each face
    corner = vertex_colors(mesh, splats)
    per_point = srgb_from_linear(np.einsum("nk,nkc->nc", bary, corner[mesh.faces[faces]]))
    assert np.abs(sample_texture(texture.image, st) - direct).mean() < np.abs(per_point - direct).mean()

    with pytest.raises(SceneError, match="set_surface_color"):
        scene.set_surface_texture("table", texture.st, texture.image)
    with scene.edit(example_copy.parent / "edit_texture.usda"):
        scene.set_surface_color("table", corner)
        with pytest.raises(InvalidDataError, match="one per triangle corner"):
            scene.set_surface_texture("table", texture.st[:-1], texture.image)
        image_file = scene.set_surface_texture("table", texture.st, texture.image)
    assert image_file == example_copy.parent / "assets" / "edit_texture" / "table.png" and image_file.is_file()
    reread = SceneGraph.open(example_copy.parent / "edit_texture.usda")
    st_back, image_back = reread.get_surface_texture("table")
    np.testing.assert_allclose(st_back, texture.st, atol=1e-6)
    assert np.array_equal(image_back, texture.image)
    np.testing.assert_allclose(reread.get_surface_color("table"), np.clip(corner, 0, 1), atol=1e-6)
    geom = reread.stage.GetPrimAtPath("/World/Objects/table/Geom")
    material = UsdShade.MaterialBindingAPI(geom).ComputeBoundMaterial()[0]
    surface = UsdShade.Shader(reread.stage.GetPrimAtPath(material.GetPath().AppendChild("Surface")))
    source = surface.GetInput("diffuseColor").GetConnectedSources()[0][0].source
    assert UsdShade.Shader(source.GetPrim()).GetIdAttr().Get() == "UsdUVTexture"
    assert reread.get_surface_texture("mug") is None
    with reread.edit(example_copy.parent / "edit_colour.usda"):  # a later layer colours it by displayColor again
        reader = UsdShade.Shader(reread.stage.GetPrimAtPath(material.GetPath().AppendChild("DisplayColor")))
        surface.GetInput("diffuseColor").ConnectToSource(reader.GetOutput("result"))
        assert reread.get_surface_texture("table") is None
        surface.GetInput("diffuseColor").ConnectToSource(UsdShade.Shader(source.GetPrim()).GetOutput("rgb"))
        UsdGeom.PrimvarsAPI(geom).GetPrimvar("st").SetIndices(list(range(len(mesh.faces))))  # stale coordinates
        with pytest.raises(SceneError, match="primvars:st has"):
            reread.get_surface_texture("table")


def test_export_glb_carries_the_baked_texture(example_copy: Path, tmp_path: Path) -> None:
    import trimesh

    from holousd.render._bake import bake_texture, vertex_colors

    scene = SceneGraph.open(example_copy)
    mesh, splats = scene.get_mesh("table"), scene.get_gaussians("table")
    texture = bake_texture(mesh, splats)
    edited = example_copy.parent / "edit_texture.usda"
    with scene.edit(edited):
        scene.set_surface_color("table", vertex_colors(mesh, splats))
        scene.set_surface_texture("table", texture.st, texture.image)
    out = tmp_path / "glb"
    assert main(["export", str(edited), "--glb", str(out)]) == 0
    table = trimesh.load(out / "table.glb", force="mesh", process=False)
    assert table.visual.kind == "texture"
    assert np.array_equal(np.asarray(table.visual.material.baseColorTexture.convert("RGB")), texture.image)
    world = scene.get_pose("table").apply(mesh.points)
    corners = np.concatenate([world[mesh.faces].reshape(-1, 3), texture.st.reshape(-1, 2)], axis=1)
    loaded = np.concatenate([table.vertices[:, [0, 2, 1]] * [1, -1, 1], table.visual.uv], axis=1)  # back to Z-up
    ours = {tuple(v) for v in np.round(corners, 4)}
    theirs = {tuple(v) for v in np.round(loaded, 4)}
    assert theirs == ours  # every corner's point and texture coordinate, nothing else
    assert len(table.faces) == len(mesh.faces)
    # The sim export stands alone: no link to the texture's image file; the colour reads displayColor again.
    sim = tmp_path / "sim" / "sim.usda"
    assert main(["export", str(edited), "--sim", str(sim)]) == 0
    stage = Usd.Stage.Open(str(sim))
    assets = [a.GetPath() for p in stage.Traverse() for a in p.GetAttributes()
              if a.GetTypeName() == Sdf.ValueTypeNames.Asset and a.Get() is not None]  # fmt: skip
    assert assets == []
    geom = stage.GetPrimAtPath("/World/Objects/table/Geom")
    assert not UsdGeom.PrimvarsAPI(geom).HasPrimvar("st") and UsdGeom.PrimvarsAPI(geom).HasPrimvar("displayColor")
    material = UsdShade.MaterialBindingAPI(geom).ComputeBoundMaterial()[0]
    surface = UsdShade.Shader(stage.GetPrimAtPath(material.GetPath().AppendChild("Surface")))
    source = surface.GetInput("diffuseColor").GetConnectedSources()[0][0].source
    reader = UsdShade.Shader(source.GetPrim())
    assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float3" and reader.GetInput("varname").Get() == "displayColor"
