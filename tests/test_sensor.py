"""Sensor models of ``holousd synth --sensor``: each channel's defects are those documented, seeded, and the
ground truth stays exact."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from holousd.io import load
from holousd.synth import SENSORS, SensorModel, SynthConfig, generate_suite, sensor_model

PHONE = SENSORS["phone"]


def _step_depth(h: int = 120, w: int = 160) -> np.ndarray:
    """A wall at 2 m with a box face at 1 m in the middle (one depth jump all round)."""
    z = np.full((h, w), 2.0, np.float32)
    z[40:80, 50:110] = 1.0
    return z


def test_clean_sensor_changes_nothing() -> None:
    clean = sensor_model("clean")
    assert clean.clean and not PHONE.clean
    z = _step_depth()
    mask = (z < 1.5).astype(np.int32)
    rgb = np.full((*z.shape, 3), 120, np.uint8)
    poses = np.repeat(np.eye(4)[None], 5, 0)
    assert np.array_equal(clean.depth(z, 0, 0), z)
    assert np.array_equal(clean.mask(mask, 0, 0), mask)
    assert np.array_equal(clean.rgb(rgb, None, np.ones(3), 0, 0), rgb)
    assert np.array_equal(clean.poses(poses, 0), poses)


def test_depth_noise_holes_edges_and_range_follow_the_model() -> None:
    z = _step_depth()
    out = PHONE.depth(z, seed=3, frame=7)
    assert out.dtype == np.float32 and out.shape == z.shape
    assert np.array_equal(out, PHONE.depth(z, seed=3, frame=7))  # seeded
    assert not np.array_equal(out, PHONE.depth(z, seed=3, frame=8))  # a new draw per frame
    missing = float((out == 0).mean())
    assert 0.04 < missing < 0.12, missing  # dropouts 2% + holes 3% + removed edge pixels
    # away from the edge, the error's spread is the model's sigma at 2 m (plus the smooth bias field)
    far = (ndimage.distance_transform_edt(z > 1.5) > 4) & (out > 0)
    err = out[far] - 2.0
    sigma = PHONE.noise_m + PHONE.noise_rel * 2.0 + PHONE.noise_quad * 4.0
    assert 0.8 * sigma < err.std() < 1.6 * sigma, (err.std(), sigma)
    assert abs(float(np.median(err))) < 0.01
    # along the depth jump: mostly removed, the few kept lie between the two surfaces (flying pixels)
    coarse = np.repeat(np.repeat(z[1::2, 1::2], 2, axis=0), 2, axis=1)  # what the half-resolution sensor sees
    edge = ndimage.maximum_filter(coarse, 3) - ndimage.minimum_filter(coarse, 3) > 0.5
    kept = out[edge][out[edge] > 0]
    assert (out[edge] == 0).mean() > 0.7
    assert np.all((kept > 0.9) & (kept < 2.1))
    # out of range: nothing nearer than min_range
    near = np.full_like(z, 0.1)
    assert not np.any(PHONE.depth(near, 0, 0))


def test_segmenter_masks_move_boundaries_by_a_few_pixels_only() -> None:
    z = _step_depth()
    truth = np.where(z < 1.5, 1, 0).astype(np.int32)
    truth[90:110, 20:40] = 2
    model = SensorModel(name="t", mask_boundary_px=2.0, mask_grow_shrink=0.3)  # no fragments, no misses
    changed = np.zeros(truth.shape, bool)
    for frame in range(20):
        noisy = model.mask(truth, seed=1, frame=frame)
        assert set(np.unique(noisy)) <= {0, 1, 2}
        changed |= noisy != truth
    assert changed.any()
    boundary_distance = np.minimum(ndimage.distance_transform_edt(truth == 0), ndimage.distance_transform_edt(truth))
    assert boundary_distance[changed].max() <= 2.0 + 1.0 + 1.0  # warp + one pixel grown or shrunk (+ rounding)
    # a segmenter that loses the object in every frame
    lost = SensorModel(name="t", mask_miss=1.0).mask(truth, 0, 0)
    assert not np.any(lost)
    frag = SensorModel(name="t", fragments=5.0).mask(truth, 0, 2)
    assert set(np.unique(frag)) <= {0, 1, 2} and (frag != truth).any()


def test_tracker_poses_drift_and_jitter_by_millimetres_and_tenths_of_a_degree() -> None:
    rng = np.random.default_rng(0)
    poses = np.repeat(np.eye(4)[None], 100, 0)
    poses[:, :3, 3] = rng.uniform(-2, 2, (100, 3))
    noisy = PHONE.poses(poses, seed=4)
    assert np.array_equal(noisy, PHONE.poses(poses, seed=4))
    dt = np.linalg.norm(noisy[:, :3, 3] - poses[:, :3, 3], axis=1)
    cos = (np.einsum("nij,nij->n", noisy[:, :3, :3], poses[:, :3, :3]) - 1) / 2
    deg = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    assert 0.001 < np.median(dt) < 0.02 and dt.max() < 0.05, dt
    assert 0.05 < np.median(deg) < 1.0 and deg.max() < 2.0, deg
    for p in noisy:  # still rigid
        assert np.allclose(p[:3, :3] @ p[:3, :3].T, np.eye(3), atol=1e-9)


def test_colour_exposure_white_balance_noise_and_blur() -> None:
    gains = PHONE.exposures(100, seed=2)
    assert gains.shape == (100, 3)
    assert np.all(np.abs(np.log(gains)) <= PHONE.exposure_max + 0.1 + 1e-9)
    assert np.log(gains).std() > 0.02  # the exposure changes over the capture
    flat = np.full((60, 80, 3), 128, np.uint8)
    out = PHONE.rgb(flat, None, np.ones(3), seed=0, frame=0)
    assert 1.0 < float(np.abs(out.astype(float) - 128).mean()) < 10.0  # noise, not a new image
    brighter = PHONE.rgb(flat, None, np.full(3, 1.3), seed=0, frame=0)
    assert abs(float(brighter.mean()) - 128 * 1.3) < 3.0
    stripes = np.zeros((60, 80, 3), np.uint8)
    stripes[:, ::8] = 255
    flow = np.zeros((60, 80, 2))
    flow[..., 0] = 60.0  # 60 px to the next frame -> 3 px of blur along x
    blurred = SensorModel(name="t", blur=0.05).rgb(stripes, flow, np.ones(3), 0, 0)
    assert blurred[:, 1::8].mean() > 20 and blurred[:, ::8].mean() < 200  # spread along the motion
    assert np.array_equal(SensorModel(name="t", blur=0.05).rgb(stripes, flow * 0, np.ones(3), 0, 0), stripes)


def test_a_phone_capture_has_the_defects_and_exact_ground_truth(tmp_path: Path) -> None:
    config = SynthConfig(frames=8, width=64, height=48, progress=False, sensor="phone")
    generate_suite("hard", tmp_path / "phone", config, scenes=["stack"])
    generate_suite("hard", tmp_path / "clean", SynthConfig(frames=8, width=64, height=48, progress=False),
                   scenes=["stack"])  # fmt: skip
    noisy, clean = load(tmp_path / "phone" / "stack"), load(tmp_path / "clean" / "stack")
    noisy.validate()
    assert not noisy.has_normals and clean.has_normals
    graph = json.loads((tmp_path / "phone" / "stack" / "gt" / "graph.json").read_text())
    assert graph["capture"]["sensor"]["name"] == "phone"
    truth = np.array(json.loads((tmp_path / "phone" / "stack" / "gt" / "cameras.json").read_text())["poses"])
    assert np.allclose(truth, clean.poses, atol=1e-6)  # the true path is the clean capture's
    off = np.linalg.norm(noisy.poses[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert 0 < off.max() < 0.05
    d_noisy, d_clean = noisy.depth(3), clean.depth(3)
    assert (d_noisy == 0).mean() > (d_clean == 0).mean()
    both = (d_noisy > 0) & (d_clean > 0)
    assert 0 < float(np.median(np.abs(d_noisy[both] - d_clean[both]))) < 0.03
    # the ground truth is that of the clean capture, byte for byte
    for name in ("scene.usda", "meshes/background.ply"):
        assert (tmp_path / "phone" / "stack" / "gt" / name).read_bytes() == (
            tmp_path / "clean" / "stack" / "gt" / name
        ).read_bytes()


def test_unknown_sensor_is_refused_before_anything_is_written(tmp_path: Path) -> None:
    from holousd._errors import HolousdError

    with pytest.raises(HolousdError, match="unknown sensor 'kinect'.*clean, phone, lidar"):
        generate_suite("hard", tmp_path / "x", SynthConfig(frames=2, width=32, height=24, progress=False,
                                                           sensor="kinect"), scenes=["stack"])  # fmt: skip
    assert not (tmp_path / "x" / "stack").exists()


def _stack_capture(tmp_path: Path):  # noqa: ANN202 - (Observations, Views)
    """hard/stack rendered small (24 frames at 96x72, exact masks and depth) and its frames as Views."""
    from holousd.geometry import Views

    generate_suite("hard", tmp_path, SynthConfig(frames=24, width=96, height=72, progress=False), scenes=["stack"])
    obs = load(tmp_path / "stack")
    labels = np.stack([obs.mask(i) for i in range(len(obs))]).astype(np.int32)
    depth = np.stack([obs.depth(i) for i in range(len(obs))]).astype(np.float32)
    return obs, Views(intrinsics=obs.intrinsics, poses=obs.poses, labels=labels, depth=depth)


def test_label_consensus_repairs_fragments_and_lost_objects_and_leaves_exact_masks(tmp_path: Path) -> None:
    from holousd.geometry import Views, label_consensus

    obs, views = _stack_capture(tmp_path)
    truth, depth = views.labels.copy(), views.depth
    labels, _, stats = label_consensus(views)
    assert (labels != truth).mean() < 0.002, stats  # exact masks: only a few boundary pixels move
    assert stats.checked > 0.3 * (depth > 0).sum()  # most pixels are seen by two neighbours away from their edges
    # a segmenter's failures: object 1 lost in frame 10, a blob labelled 2 on the room in frame 12
    noisy = truth.copy()
    lost = noisy[10] == 1
    noisy[10][lost] = 0
    room = np.argwhere(truth[12] == 0)
    r, c = room[len(room) // 2]
    blob = np.zeros_like(truth[12], bool)
    blob[max(0, r - 2) : r + 3, max(0, c - 2) : c + 3] = True
    blob &= truth[12] == 0
    noisy[12][blob] = 2
    fixed, _, stats = label_consensus(Views(intrinsics=obs.intrinsics, poses=obs.poses, labels=noisy, depth=depth))
    assert lost.sum() > 20 and blob.sum() > 5
    assert (fixed[10][lost] == 1).mean() > 0.7, stats  # most of it: pixels on its edges get no vote
    assert (fixed[12][blob] == 2).mean() < 0.2, stats
    assert stats.relabelled >= 0.7 * lost.sum()


def test_bench_runs_each_sensor_side_by_side_and_refuses_what_it_cannot_do(tmp_path: Path) -> None:
    from holousd._errors import HolousdError
    from holousd.cli import main
    from holousd.eval._bench_suite import BenchSuiteConfig, run_bench, summary_table

    with pytest.raises(HolousdError, match="unknown sensor 'kinect'"):
        run_bench(tmp_path / "a", BenchSuiteConfig(sensors=["clean", "kinect"]))
    with pytest.raises(HolousdError, match="--sensor generates captures; with --data"):
        run_bench(tmp_path / "b", BenchSuiteConfig(sensors=["phone"], data=tmp_path))
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    assert main(["bench", "--out", str(tmp_path / "c"), "--sensor", "clean,kinect"]) != 0

    def run(preset: str, parents: list[tuple[str, str | None]]) -> dict:
        objects = [{"name": f"o{i}", "recon": None if recon is None else f"o{i}", "parent_gt": gt,
                    "parent_recon": recon} for i, (gt, recon) in enumerate(parents)]  # fmt: skip
        return {"preset": preset, "scene": "s", "wall_s": 10.0, "peak_mem_mb": 100.0, "objects": objects,
                "eval": {"geometry": {"scene": {"f1": 90.0, "chamfer_cm": 1.0}}, "render": {"psnr": 30.0, "ssim": 0.9},
                         "physics": {"or_pct": 100.0, "stable_pct": 100.0}, "objects": objects}}  # fmt: skip

    runs = [run("fast", [("a", "a"), ("b", "b")]), run("fast[phone]", [("a", "a"), ("b", "a"), ("c", None)])]
    payload = {"suite": "hard", "presets": ["fast", "fast[phone]"], "runs": runs}
    rows = [line.split(" | ") for line in summary_table([payload]).splitlines()[2:4]]
    assert rows[0][1] == "fast" and rows[0][9] == "100"  # support %
    assert rows[1][1] == "fast[phone]" and rows[1][9] == "50"  # one of the two recovered objects on its parent


def test_an_instance_extent_ignores_points_no_other_frame_confirms() -> None:
    from holousd.geometry import confirmed_points

    rng = np.random.default_rng(0)
    box = [rng.uniform([0, 0, 0.7], [0.08, 0.08, 0.8], (300, 3)) for _ in range(4)]  # a mug seen in 4 frames
    fragment = rng.uniform([1.0, -1.7, 0.0], [1.02, -1.68, 0.02], (12, 3))  # a segmenter's blob on the floor
    cloud = np.concatenate([*box, fragment])
    frame = np.concatenate([np.full(300, i) for i in range(4)] + [np.full(12, 2)])
    kept = confirmed_points(cloud, frame, 0.02)
    assert len(kept) == 1200 and kept.min(axis=0)[2] >= 0.7
    # an object seen in one frame only keeps all its points
    assert len(confirmed_points(box[0], np.zeros(300, int), 0.02)) == 300


def test_an_instance_extent_drops_a_fragment_two_frames_share_that_the_others_see_as_the_room(tmp_path: Path) -> None:
    from holousd.geometry import confirmed_points, object_points

    obs, views = _stack_capture(tmp_path)
    labels, depth = views.labels.copy(), views.depth
    ids, counts = np.unique(labels[labels > 0], return_counts=True)
    k = int(ids[np.argmin(counts)])  # the smallest object: a few hundred points, as a mug on a phone's depth
    frames = [i for i in range(len(obs)) if (labels[i] == k).sum() > 0]

    def cloud() -> tuple[np.ndarray, np.ndarray]:
        pts = [views.backproject(i, (views.labels[i] == k) & (depth[i] > 0)) for i in frames]
        return np.concatenate(pts), np.concatenate([np.full(len(p), i) for i, p in zip(frames, pts, strict=True)])

    clean, frame = cloud()
    kept = object_points(clean, frame, 0.02, views, k, range(len(obs)))
    assert len(kept) >= 0.99 * len(clean)  # exact masks: the object's points stay
    # a segmenter's blob on the room, the same spot of the wall in two neighbouring frames that see the object
    a, b = frames[len(frames) // 2], frames[len(frames) // 2 + 1]
    room = np.argwhere((labels[a] == 0) & (depth[a] > 0))
    pixel = np.zeros(labels[a].shape, bool)
    pixel[tuple(room[len(room) // 3])] = True
    spot = views.backproject(a, pixel)
    for i in (a, b):
        row, col, _, valid = views.project(i, spot)
        assert valid.all()
        views.labels[i][max(0, row[0] - 1) : row[0] + 2, max(0, col[0] - 1) : col[0] + 2] = k
    noisy, frame = cloud()
    assert len(noisy) > len(clean) + 6
    assert len(confirmed_points(noisy, frame, 0.02)) >= len(clean) + 6  # the two frames confirm each other
    kept = object_points(noisy, frame, 0.02, views, k, range(len(obs)))
    lo, hi = clean.min(axis=0) - 0.04, clean.max(axis=0) + 0.04
    assert np.all((kept >= lo) & (kept <= hi))  # the fragment is gone: the other frames see the wall there
    assert len(kept) >= 0.99 * len(clean)
