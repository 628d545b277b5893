"""Camera poses aligned against the capture's depth (holousd.geometry._poses) and used by s1_fit only when the
depth says they are clearly better than the capture's; on hard/stack rendered small (24 frames at 96x72)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from holousd._errors import HolousdError
from holousd.cli import main
from holousd.geometry import Views
from holousd.geometry._poses import PoseConfig, refine_poses, rotation_matrix, spread_corrections
from holousd.io import Observations
from holousd.stages import _fit, _observe
from holousd.synth._sensor import SENSORS, SensorModel
from holousd.usd import SceneGraph
from tests.test_fit import TEST_CONFIG
from tests.test_sensor import _stack_capture


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> Observations:
    obs, _ = _stack_capture(tmp_path_factory.mktemp("stack"))
    return obs


def _views(obs: Observations, poses: np.ndarray) -> Views:
    labels = np.stack([obs.mask(i) for i in range(len(obs))]).astype(np.int32)
    depth = np.stack([obs.depth(i) for i in range(len(obs))]).astype(np.float32)
    return Views(intrinsics=obs.intrinsics, poses=poses.copy(), labels=labels, depth=depth)


def _errors(poses: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Mean error of the frames' poses relative to each other (every pair three frames apart): of the
    translation (m) and of the rotation (deg). What the scene's place as a whole does is no error: no capture
    says where that is."""
    t, r = [], []
    for a in range(len(poses) - 3):
        b = a + 3
        e = np.linalg.inv(np.linalg.inv(truth[a]) @ truth[b]) @ np.linalg.inv(poses[a]) @ poses[b]
        t.append(np.linalg.norm(e[:3, 3]))
        r.append(np.degrees(np.arccos(np.clip((np.trace(e[:3, :3]) - 1) / 2, -1, 1))))
    return float(np.mean(t)), float(np.mean(r))


# a weak tracker / structure from motion: about 1 cm and 0.6 deg off per frame
WEAK = SensorModel(name="weak", jitter_m=0.006, jitter_deg=0.5, drift_m=0.001, drift_deg=0.1)


def test_poses_a_weak_tracker_gave_are_brought_back_by_the_depth(stack: Observations) -> None:
    obs = stack
    truth = np.asarray(obs.poses)
    given = WEAK.poses(truth, 3)
    found = refine_poses(_views(obs, given))
    assert found.applied and found.ratio < 0.2
    (t0, r0), (t1, r1) = _errors(given, truth), _errors(found.poses, truth)
    assert r0 > 0.8 and r1 < r0 / 4, (r0, r1)  # 1.07 -> 0.17 deg
    assert t0 > 0.01 and t1 < t0 / 1.5, (t0, t1)  # 1.5 -> 0.7 cm


def test_right_poses_and_poses_as_good_as_the_depth_are_kept(stack: Observations) -> None:
    obs = stack
    truth = np.asarray(obs.poses)
    exact = refine_poses(_views(obs, truth))
    assert not exact.applied and exact.ratio > 0.5
    assert np.array_equal(exact.poses, truth)
    # a phone: its tracker's error is as small as its depth's own (a noise field per frame, holes, steps)
    phone = SENSORS["phone"]
    views = _views(obs, phone.poses(truth, 0))
    views.depth = np.stack([phone.depth(views.depth[i], 0, i) for i in range(len(obs))])
    kept = refine_poses(views)
    assert not kept.applied and kept.ratio > 0.5, kept.ratio  # 0.91
    assert np.array_equal(kept.poses, views.poses)
    # asked to use them anyway, it does, and they are worse: the depth's errors are aligned, not the poses'
    forced = refine_poses(views, PoseConfig(max_ratio=np.inf))
    assert forced.applied and _errors(forced.poses, truth)[1] > _errors(views.poses, truth)[1]


def test_corrections_spread_to_frames_not_read() -> None:
    base = np.stack([np.eye(4)] * 9)
    for f in range(9):
        base[f, :3, :3] = rotation_matrix(np.radians([30.0, 10.0 * f, 45.0]))  # turned: the order of turns matters
        base[f, :3, 3] = (0.1 * f, 0.0, 1.0)
    read = np.array([0, 4, 8])
    turn = rotation_matrix(np.radians([0.0, 0.0, 2.0]))
    refined = base[read].copy()
    refined[:, :3, :3] = turn @ refined[:, :3, :3]  # the same correction on every read frame: drift
    refined[:, 1, 3] += 0.03
    out = spread_corrections(read, base[read], refined, base)
    assert np.allclose(out[read], refined)
    for f in (2, 5):  # the frames between get that correction, turned about their own centres
        assert np.allclose(out[f, :3, :3], turn @ base[f, :3, :3])
        assert np.allclose(out[f, :3, 3], base[f, :3, 3] + [0, 0.03, 0])
    # one read frame's own jitter is not carried to its neighbours in full
    jitter = base[read].copy()
    jitter[1, 1, 3] += 0.03
    out = spread_corrections(read, base[read], jitter, base)
    assert 0 < out[3, 1, 3] - base[3, 1, 3] < 0.015


def test_fit_uses_and_records_aligned_poses_and_later_stages_see_them(
    stack: Observations, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    obs = stack
    truth = np.asarray(obs.poses)
    weak = obs.with_poses(WEAK.poses(truth, 3))
    result = _fit.fit(_observe.run(weak, tmp_path / "weak"), weak, TEST_CONFIG)
    assert result.poses is not None and result.poses.applied
    fitted = SceneGraph.open(tmp_path / "weak" / "10_fit.usda")
    cameras = fitted.get_cameras()
    used = np.stack([c.cam_to_world for c in cameras])
    assert _errors(used, truth)[1] < _errors(weak.poses, truth)[1] / 3
    move = np.stack([c.pose_move for c in cameras])
    assert np.allclose(move, used[:, :3, 3] - weak.poses[:, :3, 3], atol=1e-9) and np.all(np.abs(move).max(1) > 0)
    for camera, given in zip(cameras, weak.poses, strict=True):  # the turn recorded undoes to the capture's pose
        turned = rotation_matrix(np.radians(camera.pose_turn_deg)) @ given[:3, :3]
        assert np.allclose(turned, camera.cam_to_world[:3, :3], atol=1e-9)
    observed = SceneGraph.open(tmp_path / "weak" / "00_observe.usda").get_cameras()
    assert np.allclose(np.stack([c.cam_to_world for c in observed]), weak.poses)  # the capture's poses stay below
    assert np.allclose(_fit.observations_as_fitted(weak, fitted).poses, used)
    assert main(["info", str(tmp_path / "weak" / "10_fit.usda")]) == 0
    assert "24 cameras, poses aligned against the depth by s1_fit: moved median" in capsys.readouterr().out
    assert main(["info", str(tmp_path / "weak" / "10_fit.usda"), "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)["cameras"]
    assert np.allclose([c["pose_move_m"] for c in listed], move)
    # exact poses: nothing is written over the cameras and the stages after see the capture as it is
    exact = _fit.fit(_observe.run(obs, tmp_path / "exact"), obs, TEST_CONFIG)
    assert exact.poses is not None and not exact.poses.applied
    layer = SceneGraph.open(tmp_path / "exact" / "10_fit.usda").root_layer
    assert not any("Cameras" in str(p) for p in _authored_paths(layer))
    assert _fit.observations_as_fitted(obs, SceneGraph.open(tmp_path / "exact" / "10_fit.usda")) is obs
    assert main(["info", str(tmp_path / "exact" / "10_fit.usda")]) == 0
    assert "24 cameras, at the capture's poses" in capsys.readouterr().out
    # off: not even looked at; on: used though they would not be in auto
    off = _fit.fit(_observe.run(weak, tmp_path / "off"), weak, replace(TEST_CONFIG, refine_poses="off"))
    assert off.poses is None
    assert SceneGraph.open(tmp_path / "off" / "10_fit.usda").get_cameras()[0].pose_move.tolist() == [0, 0, 0]
    forced = _fit.fit(_observe.run(obs, tmp_path / "on"), obs, replace(TEST_CONFIG, refine_poses="on"))
    assert forced.poses is not None and forced.poses.applied
    # a scene whose aligned cameras are not the capture's frames is refused, not rendered from the wrong poses
    with pytest.raises(HolousdError, match="not the 23 frames"):
        _fit.observations_as_fitted(weak.subset(range(23)), fitted)
    with pytest.raises(HolousdError, match="refine_poses"):
        _fit.fit(_observe.run(weak, tmp_path / "bad"), weak, replace(TEST_CONFIG, refine_poses="yes"))


def _authored_paths(layer) -> list:  # noqa: ANN001
    paths = []
    layer.Traverse("/", paths.append)
    return paths


def test_with_poses_refuses_the_wrong_shape_and_nan(stack: Observations) -> None:
    with pytest.raises(HolousdError, match="with_poses needs 24 4x4 poses"):
        stack.with_poses(np.eye(4)[None])
    with pytest.raises(HolousdError, match="NaN"):
        stack.with_poses(np.full((24, 4, 4), np.nan))


def test_nothing_to_align_keeps_the_poses(stack: Observations) -> None:
    views = _views(stack, np.asarray(stack.poses))
    views.depth = np.zeros_like(views.depth)  # no depth anywhere: no pair, no correspondence
    found = refine_poses(views, PoseConfig(max_ratio=np.inf))
    assert found.pairs == 0 and not found.applied and found.ratio == 1.0
    assert np.array_equal(found.poses, stack.poses)
