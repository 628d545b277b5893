"""Appearance fitting and the appearance stage transform, frames adapter, metrics, and the render CLI."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

from holousd import InvalidDataError, MeshData, Pose, SceneError, SceneGraph
from holousd.eval import psnr, ssim, ssim_torch
from holousd.render import Camera, FitConfig, Frame, SceneRenderer, as_frames, look_at, render_textured
from holousd.stages import AppearanceConfig, appearance, fit_appearance

if TYPE_CHECKING:
    pass


def _quad(size: float = 1.0) -> MeshData:
    h = size / 2
    return MeshData(points=[[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], faces=[[0, 1, 2], [0, 2, 3]])


def _camera(eye: tuple[float, float, float], size: int = 48) -> Camera:
    return Camera(fx=50.0, fy=50.0, cx=size / 2, cy=size / 2, width=size, height=size,
                  cam_to_world=look_at(np.array(eye), np.zeros(3), up=np.array([0.0, 1.0, 0.0])))  # fmt: skip


def _texture(_: np.ndarray, points: np.ndarray, __: np.ndarray) -> np.ndarray:
    x, y = points[:, 0], points[:, 1]
    return np.stack([0.5 + 0.3 * np.sin(2 * np.pi * x / 0.5), 0.5 + 0.3 * np.cos(2 * np.pi * y / 0.4),
                     0.4 + 0.2 * np.sin(2 * np.pi * (x + y) / 0.6)], axis=1)  # fmt: skip


def _frames(cams: list[Camera], mesh: MeshData) -> list[Frame]:
    frames = []
    for cam in cams:
        image, label = render_textured([mesh], cam, _texture, background=(0.0, 0.0, 0.0))
        frames.append(Frame(image=image, camera=cam, mask=(label + 1).astype(np.int32)))  # instance id 1
    return frames


def test_textured_quad_is_reproduced_on_a_held_out_view(tmp_path: Path) -> None:
    mesh = _quad(0.8)
    scene = SceneGraph.create(tmp_path / "scene.usda")
    scene.add_object("card", instance_id=1)
    scene.set_mesh("card", mesh)
    scene.save()
    train = _frames([_camera(e) for e in [(0.0, 0.0, 1.6), (0.4, 0.1, 1.5), (-0.3, 0.3, 1.5), (0.1, -0.4, 1.5)]], mesh)
    test = _frames([_camera((0.2, 0.2, 1.55))], mesh)
    config = AppearanceConfig(layer="appearance.usda", spacing_px=1.5, fit=FitConfig(iterations=250, seed=1))
    result = fit_appearance(scene, train, config)
    assert result.layer == tmp_path / "appearance.usda" and result.layer.is_file()
    assert 200 < result.counts["card"] < 5000  # area / (spacing x footprint)^2
    assert result.budgets["card"].observed_area == pytest.approx(0.64)
    image = SceneRenderer(scene, background=(0.0, 0.0, 0.0)).render(test[0].camera).color.numpy()
    assert psnr(image, test[0].image) > 30.0
    # the stage wrote its own layer over the input and recorded its provenance
    reopened = SceneGraph.open(tmp_path / "appearance.usda")
    assert reopened.node_info("card").provenance == "appearance"
    assert reopened.stage.GetRootLayer().subLayerPaths[0].endswith("scene.usda")
    assert len(reopened.get_gaussians("card")) == result.counts["card"]
    assert SceneGraph.open(tmp_path / "scene.usda").stage.GetPrimAtPath("/World/Objects/card/Splats").IsValid() is False
    # the mesh carries the colour too (displayColor and a UsdPreviewSurface reading it) for tools without splats
    baked = reopened.get_surface_color("card")
    from holousd.render._bake import linear_from_srgb

    expected = linear_from_srgb(_texture(None, mesh.points, None))  # the texture at the four corners
    assert baked is not None and baked.shape == (4, 3)
    np.testing.assert_allclose(baked, expected, atol=0.12)
    assert np.ptp(baked, axis=0).max() > 0.1  # not one flat colour
    from pxr import UsdShade

    geom = reopened.stage.GetPrimAtPath("/World/Objects/card/Geom")
    material, _ = UsdShade.MaterialBindingAPI(geom).ComputeBoundMaterial()
    shader = material.ComputeSurfaceSource()[0]
    assert shader.GetIdAttr().Get() == "UsdPreviewSurface"
    texture = UsdShade.Shader(shader.GetInput("diffuseColor").GetConnectedSources()[0][0].source.GetPrim())
    assert texture.GetIdAttr().Get() == "UsdUVTexture"  # the baked texture; displayColor stays as the fallback
    # The texture carries the pattern the four per-point colours cannot: sampled anywhere on the card it gives the
    # captured colour, far closer than the per-point colours interpolated across the faces.
    from holousd.render._bake import sample_texture

    st, texels = reopened.get_surface_texture("card")
    rng = np.random.default_rng(1)
    faces = rng.integers(0, len(mesh.faces), 400)
    bary = rng.dirichlet(np.ones(3), 400)
    points = np.einsum("nk,nkc->nc", bary, mesh.points[mesh.faces[faces]])
    truth = _texture(None, points, None)
    textured = sample_texture(texels, np.einsum("nk,nkc->nc", bary, st[faces]))
    per_point = np.einsum("nk,nkc->nc", bary, _texture(None, mesh.points, None)[mesh.faces[faces]])
    assert np.abs(textured - truth).mean() < 0.5 * np.abs(per_point - truth).mean()
    assert np.abs(textured - truth).mean() < 0.05
    from holousd.usd._validate import _usd_validators

    shading = [i for i in _usd_validators(reopened.stage) if "/World/Looks" in i.where]
    assert not shading, shading  # varname is a string (UsdPreviewSurface 2.5): OpenUSD's Sdr check passes
    assert SceneGraph.open(tmp_path / "scene.usda").get_surface_color("card") is None  # the layer below unchanged


def test_stage_run_refines_existing_splats_and_keeps_them_bound(tmp_path: Path) -> None:
    mesh = _quad(0.8)
    scene = SceneGraph.create(tmp_path / "scene.usda")
    scene.add_object("card", instance_id=1, pose=Pose(translation=[0.0, 0.0, 0.1]))
    scene.set_mesh("card", mesh)
    scene.save()
    cams = [_camera((0.0, 0.0, 1.7)), _camera((0.3, 0.0, 1.6))]
    frames = [(f.image, f.camera.K, f.camera.cam_to_world, f.mask) for f in _frames(cams, MeshData(
        points=mesh.points + [0.0, 0.0, 0.1], faces=mesh.faces))]  # fmt: skip
    first = appearance.run(scene, frames, AppearanceConfig(layer="s1.usda", spacing_px=3, fit=FitConfig(iterations=5)))
    before = first.get_gaussians("card")
    refined = appearance.run(first, frames, AppearanceConfig(layer="s3.usda", reinitialize=False,
                                                           fit=FitConfig(iterations=5)))  # fmt: skip
    after = refined.get_gaussians("card")
    assert len(after) == len(before) and after.bound
    np.testing.assert_array_equal(after.face_index, before.face_index)
    assert np.all(after.barycentric >= 0) and np.allclose(after.barycentric.sum(1), 1.0, atol=1e-5)
    assert not np.array_equal(after.sh_coeffs, before.sh_coeffs)
    assert refined.path == tmp_path / "s3.usda"


def test_stage_reports_bad_inputs(tmp_path: Path) -> None:
    scene = SceneGraph.create(tmp_path / "scene.usda")
    scene.add_object("card", instance_id=1)
    scene.save()
    frame = (np.zeros((8, 8, 3)), np.array([[8.0, 0, 4], [0, 8.0, 4], [0, 0, 1]]), np.eye(4))
    with pytest.raises(SceneError, match="no node with a mesh"):
        appearance.run(scene, [frame])
    with pytest.raises(InvalidDataError, match="unknown nodes"):
        appearance.run(scene, [frame], AppearanceConfig(nodes=["ghost"]))
    with pytest.raises(InvalidDataError, match="no frames"):
        appearance.run(scene, [])


def test_frames_adapter_accepts_observation_like_objects() -> None:
    class Observations:
        images = np.zeros((2, 6, 8, 3), dtype=np.uint8) + 255
        intrinsics = np.array([[8.0, 0, 4], [0, 8.0, 3], [0, 0, 1]])

        def cam_to_world(self) -> np.ndarray:
            return np.stack([np.eye(4)] * 2)

        masks = np.ones((2, 6, 8), dtype=np.int32)

    frames = as_frames(Observations())
    assert len(frames) == 2 and frames[0].image.dtype == np.float32 and frames[0].image.max() == 1.0
    assert frames[1].camera.width == 8 and frames[1].camera.cy == 3.0 and frames[0].instance_mask
    with pytest.raises(InvalidDataError, match="not a frame container"):
        as_frames(object())
    with pytest.raises(InvalidDataError, match=r"image must be \[H, W, 3\]"):
        as_frames([(np.zeros((4, 4)), np.eye(3), np.eye(4))])
    with pytest.raises(InvalidDataError, match="mask"):
        as_frames([(np.zeros((4, 4, 3)), np.eye(3), np.eye(4), np.zeros((3, 3)))])


def test_metrics() -> None:
    import torch

    rng = np.random.default_rng(0)
    ref = rng.random((40, 50, 3))
    noisy = np.clip(ref + rng.normal(0, 0.05, ref.shape), 0, 1)
    mse = np.mean((noisy - ref) ** 2)
    assert psnr(noisy, ref) == pytest.approx(10 * np.log10(1 / mse))
    assert psnr(ref, ref) == float("inf") and ssim(ref, ref) == pytest.approx(1.0)
    torch_value = float(ssim_torch(torch.as_tensor(noisy), torch.as_tensor(ref)))
    assert torch_value == pytest.approx(ssim(noisy, ref), abs=1e-6)
    from holousd.eval import lpips

    assert lpips(noisy, ref, weights=None) is None
    with pytest.raises(InvalidDataError, match="same shape"):
        psnr(ref, ref[:, :10])


def test_render_cli_writes_frames_and_video_and_follows_simulated_poses(tmp_path: Path) -> None:
    from pxr import Gf, Usd, UsdGeom

    from holousd.cli import main
    from holousd.render import initial_bound_splats, splat_budget

    scene = SceneGraph.create(tmp_path / "scene.usda")
    scene.add_object("card", instance_id=1)
    mesh = _quad(0.5)
    scene.set_mesh("card", mesh)
    splats = initial_bound_splats(mesh, splat_budget(mesh, Pose(), [], min_splats=400, max_splats=400))
    scene.set_gaussians("card", splats)
    scene.save()
    # a "simulation layer": time-sampled translate on the object's Xform
    scene.push_layer(tmp_path / "sim.usda")
    stage = scene.stage
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(2)
    ops = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Objects/card")).GetOrderedXformOps()
    for t in range(3):
        ops[0].Set(Gf.Vec3d(0.0, 0.0, -0.5 * t), Usd.TimeCode(t))
    scene.save()
    out = tmp_path / "render"
    code = main(["render", str(tmp_path / "sim.usda"), "--out", str(out), "--frames", "3", "--resolution", "40x32"])
    assert code == 0
    pngs = sorted(out.glob("frame_*.png"))
    assert len(pngs) == 3 and (out / "render.mp4").stat().st_size > 0
    from PIL import Image

    images = [np.asarray(Image.open(p)) for p in pngs]
    assert images[0].shape == (32, 40, 3)
    coverage = [int((img.astype(int).sum(-1) < 700).sum()) for img in images]  # non-white pixels
    assert coverage[0] > coverage[1] > coverage[2]  # the card falls away from the camera
    assert main(["render", str(tmp_path / "sim.usda"), "--out", str(out), "--cameras", "observed"]) == 2
