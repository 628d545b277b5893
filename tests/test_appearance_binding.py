"""Gaussians on a mesh: posing, the splat-count rule and the USD round trip of every splat attribute."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from holousd import InvalidDataError, MeshData, Pose, SceneGraph
from holousd.render import (
    Camera,
    SceneRenderer,
    initial_bound_splats,
    look_at,
    splat_budget,
    splats_in_world,
)

if TYPE_CHECKING:
    pass


def _quad(size: float = 1.0) -> MeshData:
    h = size / 2
    return MeshData(points=[[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], faces=[[0, 1, 2], [0, 2, 3]])


def _top_camera(width: int = 64, height: int = 64, dist: float = 2.0) -> Camera:
    pose = look_at(np.array([0.0, 0.0, dist]), np.zeros(3), up=np.array([0.0, 1.0, 0.0]))
    return Camera(fx=60.0, fy=60.0, cx=width / 2, cy=height / 2, width=width, height=height, cam_to_world=pose)


def _textured_splats(mesh: MeshData, count: int, seed: int = 0):  # noqa: ANN202
    budget = splat_budget(mesh, Pose(), [], min_splats=count, max_splats=count, seed=seed)
    splats = initial_bound_splats(mesh, budget, seed=seed)
    rng = np.random.default_rng(seed)
    splats.sh_coeffs = rng.normal(0.0, 1.0, splats.sh_coeffs.shape).astype(np.float32)
    return splats


def test_bound_splats_follow_the_pose_exactly() -> None:
    mesh = _quad()
    splats = _textured_splats(mesh, 300)
    rest_c, rest_r, rest_s = splats_in_world(splats, Pose(), mesh)
    pose = Pose(
        translation=[0.3, -1.2, 2.0], orientation=Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_quat()
    )
    moved_c, moved_r, moved_s = splats_in_world(splats, pose, mesh)
    np.testing.assert_allclose(moved_c, pose.apply(rest_c), atol=1e-9)
    np.testing.assert_allclose(moved_r, pose.rotation_matrix() @ rest_r, atol=1e-9)
    np.testing.assert_allclose(moved_s, rest_s)
    # flat along the face normal, centred on the face
    assert np.all(rest_s[:, 2] <= 1.001e-3 * rest_s[:, :2].max(axis=1))
    np.testing.assert_allclose(rest_r[:, :, 2], np.tile([0.0, 0.0, 1.0], (300, 1)), atol=1e-9)
    assert np.abs(rest_c[:, 2]).max() < 1e-9 and np.abs(rest_c[:, :2]).max() <= 0.5


def test_moving_an_object_shifts_its_rendered_splats_by_the_projected_motion(tmp_path: Path) -> None:
    scene = SceneGraph.create(tmp_path / "scene.usda")
    scene.add_object("card", instance_id=1)
    mesh = _quad(0.5)
    scene.set_mesh("card", mesh)
    scene.set_gaussians("card", _textured_splats(mesh, 2000))
    scene.save()
    cam = _top_camera()
    before = SceneRenderer(scene, background=(0.0, 0.0, 0.0)).render(cam).color
    shift_px = 6  # along image x; depth of the card is 2 m, so the motion is 6 * 2 / 60 m along world x
    with scene.edit(tmp_path / "edit_move.usda"):
        scene.set_pose("card", Pose(translation=[shift_px * 2.0 / 60.0, 0.0, 0.0]))
    after = SceneRenderer(scene, background=(0.0, 0.0, 0.0)).render(cam).color
    assert float(before.sum()) > 100.0
    diff = (after[:, shift_px:] - before[:, :-shift_px]).abs().max()
    assert float(diff) < 2e-3, float(diff)
    assert float((after - before).abs().max()) > 0.1  # it did move


def test_splat_count_follows_area_and_footprint() -> None:
    mesh = _quad(1.0)
    near = splat_budget(mesh, Pose(), [_top_camera(dist=2.0)], spacing_px=1.0, max_splats=10**6)
    far = splat_budget(mesh, Pose(), [_top_camera(dist=4.0)], spacing_px=1.0, max_splats=10**6)
    big = splat_budget(_quad(2.0), Pose(), [_top_camera(dist=4.0)], spacing_px=1.0, max_splats=10**6)
    # the 1 m quad at 2 m fills (60 / 2)^2 = 900 px^2; footprint 2 / 60 m per pixel -> 900 splats at 1 px spacing
    assert near.count == pytest.approx(900, rel=0.03)
    assert far.count == pytest.approx(near.count / 4, rel=0.03)
    assert big.count == pytest.approx(near.count, rel=0.05)  # 4x the area at 2x the distance
    assert near.observed_area == pytest.approx(1.0)
    unseen = splat_budget(mesh, Pose(translation=[0.0, 0.0, 5.0]), [_top_camera()], min_splats=10)
    assert unseen.count == 10 and unseen.observed_area == 0.0
    with pytest.raises(InvalidDataError, match="spacing_px"):
        splat_budget(mesh, Pose(), [], spacing_px=0.0)


def test_usd_round_trip_keeps_every_splat_attribute(tmp_path: Path) -> None:
    scene = SceneGraph.create(tmp_path / "scene.usda")
    scene.add_object("card", instance_id=1)
    mesh = _quad()
    scene.set_mesh("card", mesh)
    splats = _textured_splats(mesh, 500, seed=3)
    splats.normal_offset = np.linspace(-1e-3, 1e-3, 500).astype(np.float32)
    scene.set_gaussians("card", splats)
    scene.save()
    back = SceneGraph.open(tmp_path / "scene.usda").get_gaussians("card")
    for name in ("positions", "orientations", "scales", "opacities", "sh_coeffs", "face_index", "barycentric",
                 "normal_offset", "in_plane_rotation", "in_plane_scale"):  # fmt: skip
        np.testing.assert_array_equal(getattr(back, name), getattr(splats, name), err_msg=name)


def test_splats_bound_to_another_mesh_are_rejected() -> None:
    splats = _textured_splats(_quad(), 50)
    tiny = MeshData(points=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]])
    splats.face_index[:] = 1
    with pytest.raises(InvalidDataError, match="face_index"):
        splats_in_world(splats, Pose(), tiny)


def test_sh_degree_one_is_view_dependent() -> None:
    import torch

    from holousd.render import sh_to_rgb

    sh = torch.zeros(1, 4, 3)
    sh[0, 3, 0] = 1.0  # red channel: -C1 * x
    left = sh_to_rgb(sh, torch.tensor([[-1.0, 0.0, 0.0]]))
    right = sh_to_rgb(sh, torch.tensor([[1.0, 0.0, 0.0]]))
    assert float(left[0, 0]) == pytest.approx(0.5 + 0.4886025, abs=1e-6)
    assert float(right[0, 0]) == pytest.approx(0.5 - 0.4886025, abs=1e-6)
    assert float(left[0, 1]) == pytest.approx(0.5, abs=1e-6)
