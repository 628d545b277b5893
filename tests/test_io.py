"""Observations I/O: round trips through every format, lazy loading, validation errors, camera decomposition."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import holousd
from holousd.io import Observations, ObservationsError, decompose_projection, detect_format, load, write

W, H, N = 24, 16, 4


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return q if np.linalg.det(q) > 0 else -q


def _observations(seed: int = 0) -> Observations:
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    rgb = np.stack(
        [np.stack([(u * 9 + 20 * i) % 256, (v * 13) % 256, np.full_like(u, 60 + 30 * i)], -1) for i in range(N)]
    ).astype(np.uint8)  # smooth images (video codecs)
    masks = np.zeros((N, H, W), np.int32)
    masks[:, 2:8, 3:10] = 1
    masks[:, 9:14, 12:20] = 2
    depth = rng.uniform(0.5, 4.0, (N, H, W)).astype(np.float32)
    normals = rng.normal(size=(N, H, W, 3))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    k = np.array([[20.0, 0.0, (W - 1) / 2], [0.0, 21.0, (H - 1) / 2], [0.0, 0.0, 1.0]])
    poses = np.stack([np.eye(4)] * N)
    for i in range(N):
        poses[i, :3, :3] = _rotation(rng)
        poses[i, :3, 3] = rng.uniform(-2, 2, 3)
    return Observations(
        rgb=rgb,
        masks=masks,
        depth=depth,
        normals=normals.astype(np.float32),
        intrinsics=k,
        poses=poses,
        width=W,
        height=H,
        depth_kind="metric",
        instance_names={1: "table", 2: "mug"},
    )


@pytest.mark.parametrize("fmt", ["native", "nerfstudio", "monosdf", "video"])
def test_round_trip(tmp_path: Path, fmt: str) -> None:
    obs = _observations()
    obs.validate()
    write(obs, tmp_path, format=fmt)
    assert detect_format(tmp_path) == fmt
    back = load(tmp_path)
    back.validate()
    assert len(back) == N and (back.width, back.height) == (W, H)
    np.testing.assert_allclose(back.poses, obs.poses, atol=1e-5)
    np.testing.assert_allclose(back.intrinsics, obs.intrinsics, atol=1e-6)
    assert back.depth_kind == "metric" and back.instance_names == {1: "table", 2: "mug"}
    for i in range(N):
        if fmt == "video":
            assert np.abs(back.rgb(i).astype(int) - obs.rgb(i)).mean() < 6
        else:
            np.testing.assert_array_equal(back.rgb(i), obs.rgb(i))
        np.testing.assert_array_equal(back.mask(i), obs.mask(i))
        np.testing.assert_allclose(back.depth(i), obs.depth(i), atol=6e-4)
        np.testing.assert_allclose(back.normal(i), obs.normal(i), atol=0.02)


def test_writers_are_deterministic(tmp_path: Path) -> None:
    for fmt in ("native", "monosdf"):
        write(_observations(), tmp_path / f"a_{fmt}", format=fmt)
        write(_observations(), tmp_path / f"b_{fmt}", format=fmt)
        for a in sorted((tmp_path / f"a_{fmt}").rglob("*")):
            if a.is_file():
                b = tmp_path / f"b_{fmt}" / a.relative_to(tmp_path / f"a_{fmt}")
                assert a.read_bytes() == b.read_bytes(), a


def test_frames_load_lazily(tmp_path: Path) -> None:
    write(_observations(), tmp_path)
    (tmp_path / "rgb" / "000002.png").unlink()
    obs = load(tmp_path)  # opening reads only the manifest
    assert obs.rgb(0).shape == (H, W, 3)
    with pytest.raises(ObservationsError, match=r"000002\.png: file is missing"):
        obs.rgb(2)
    with pytest.raises(ObservationsError, match=r"000002\.png"):
        obs.validate()
    sub = obs.subset([0, 1])
    sub.validate()
    assert sub.frame_ids == ["000000", "000001"]


def test_monosdf_decomposition_recovers_camera() -> None:
    rng = np.random.default_rng(3)
    k = np.array([[300.0, 0.0, 160.0], [0.0, 310.0, 120.0], [0.0, 0.0, 1.0]])
    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = _rotation(rng), rng.uniform(-3, 3, 3)
    p = 2.5 * (k @ np.linalg.inv(c2w)[:3, :4])  # projection matrices are defined up to scale
    k2, c2w2 = decompose_projection(-p)
    np.testing.assert_allclose(k2, k, atol=1e-8)
    np.testing.assert_allclose(c2w2, c2w, atol=1e-8)


def test_monosdf_scale_mat_gives_metric_poses(tmp_path: Path) -> None:
    obs = _observations()
    obs.metadata["scale_mat"] = np.diag([3.0, 3.0, 3.0, 1.0])  # normalised -> world: scale 3, then shift
    obs.metadata["scale_mat"][:3, 3] = [0.5, -1.0, 2.0]
    write(obs, tmp_path, format="monosdf")
    with np.load(tmp_path / "cameras.npz") as cams:
        scale = cams["scale_mat_1"]
        _, normalised = decompose_projection((cams["world_mat_1"] @ scale)[:3])
    np.testing.assert_allclose(normalised[:3, 3] * 3.0 + [0.5, -1.0, 2.0], obs.poses[1, :3, 3], atol=1e-6)
    np.testing.assert_allclose(load(tmp_path).poses[1], obs.poses[1], atol=1e-6)
    np.testing.assert_allclose(load(tmp_path).depth(0), obs.depth(0), atol=1e-5)


# ---------------------------------------------------------------------- validation errors
def _with(obs: Observations, **changes: object) -> Observations:
    kwargs = dict(
        rgb=[obs.rgb(i) for i in range(len(obs))],
        masks=[obs.mask(i) for i in range(len(obs))],
        intrinsics=obs.intrinsics,
        poses=obs.poses.copy(),
        width=obs.width,
        height=obs.height,
        instance_names=obs.instance_names,
    )
    kwargs.update(changes)
    return Observations(**kwargs)  # type: ignore[arg-type]


def test_validate_rejects_bad_poses() -> None:
    obs = _observations()
    poses = obs.poses.copy()
    poses[2, 0, 3] = np.nan
    with pytest.raises(ObservationsError, match=r"frame 2 .*NaN"):
        _with(obs, poses=poses).validate(pixels=False)
    poses = obs.poses.copy()
    poses[1, :3, :3] *= 1.5
    with pytest.raises(ObservationsError, match=r"frame 1 .*not rigid"):
        _with(obs, poses=poses).validate(pixels=False)
    poses = obs.poses.copy()
    poses[0, :3, 0] *= -1
    with pytest.raises(ObservationsError, match="reflection"):
        _with(obs, poses=poses).validate(pixels=False)
    with pytest.raises(ObservationsError, match=r"expected \[4, 4, 4\]"):
        _with(obs, poses=obs.poses[:3]).validate()


def test_validate_rejects_bad_frames_and_masks() -> None:
    obs = _observations()
    masks = [obs.mask(i) for i in range(N)]
    with pytest.raises(ObservationsError, match=r"mask has shape \[16, 23\]"):
        _with(obs, masks=[m[:, :-1] for m in masks]).validate()
    with pytest.raises(ObservationsError, match=r"ids \[2\] \(mug\) are declared but never appear"):
        _with(obs, masks=[np.where(m == 2, 0, m) for m in masks]).validate()
    with pytest.raises(ObservationsError, match=r"ids \[2\] never appear .* renumber"):
        _with(obs, masks=[np.where(m == 2, 3, m) for m in masks], instance_names=None).validate()
    rgb = [obs.rgb(i) for i in range(N)]
    rgb[3] = np.zeros_like(rgb[3])
    with pytest.raises(ObservationsError, match="frame 3 .*empty frame"):
        _with(obs, rgb=rgb).validate()
    with pytest.raises(ObservationsError, match="image is 24x16, the capture declares 30x16"):
        _with(obs, width=30, intrinsics=obs.intrinsics).validate()
    with pytest.raises(ObservationsError, match="no frames"):
        Observations(rgb=[], intrinsics=np.zeros((0, 3, 3)), poses=np.zeros((0, 4, 4)), width=W, height=H).validate()


def test_malformed_native(tmp_path: Path) -> None:
    write(_observations(), tmp_path)
    (tmp_path / "masks" / "000001.png").write_bytes(b"not a png")
    with pytest.raises(ObservationsError, match=r"000001\.png: cannot be decoded .*corrupt"):
        load(tmp_path).validate()
    manifest = json.loads((tmp_path / "observations.json").read_text())
    manifest["frames"][2]["camera_to_world"] = [[1.0, 0.0, 0.0]]
    (tmp_path / "observations.json").write_text(json.dumps(manifest))
    with pytest.raises(ObservationsError, match=r"observations\.json: frames\[2\]: camera_to_world has shape \[1, 3\]"):
        load(tmp_path)
    (tmp_path / "observations.json").write_text("{ truncated")
    with pytest.raises(ObservationsError, match=r"observations\.json: .*not valid JSON"):
        load(tmp_path)
    assert issubclass(ObservationsError, holousd.HolousdError)


def test_malformed_nerfstudio(tmp_path: Path) -> None:
    write(_observations(), tmp_path, format="nerfstudio")
    data = json.loads((tmp_path / "transforms.json").read_text())
    data["frames"][1]["transform_matrix"][1][3] = float("nan")
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    with pytest.raises(ObservationsError, match=r"transforms\.json: frame 1 .*NaN"):
        load(tmp_path).validate()
    (tmp_path / "instance_mask" / "frame_000003.png").unlink()
    with pytest.raises(ObservationsError, match=r"instance_mask: no instance mask for frame '000003'"):
        load(tmp_path)
    data["k1"] = 0.1
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    with pytest.raises(ObservationsError, match="distortion k1=0.1 .*undistort"):
        load(tmp_path)


def test_malformed_monosdf(tmp_path: Path) -> None:
    write(_observations(), tmp_path, format="monosdf")
    (tmp_path / "000002_depth.npy").unlink()
    with pytest.raises(ObservationsError, match=r"000002_depth\.npy: file is missing \(3 of 4"):
        load(tmp_path)
    (tmp_path / "cameras.npz").write_bytes(b"PK garbage")
    with pytest.raises(ObservationsError, match=r"cameras\.npz: cannot be read .*corrupt"):
        load(tmp_path)
    with open(tmp_path / "cameras.npz", "wb") as fh:
        np.savez(fh, world_mat_0=np.eye(4), scale_mat_0=np.eye(4))
    with pytest.raises(ObservationsError, match=r"no 'world_mat_1' for image 1"):
        load(tmp_path)


def test_malformed_video_and_detection(tmp_path: Path) -> None:
    write(_observations(), tmp_path / "v", format="video")
    data = json.loads((tmp_path / "v" / "cameras.json").read_text())
    data["frames"][3]["video_frame"] = 50
    (tmp_path / "v" / "cameras.json").write_text(json.dumps(data))
    obs = load(tmp_path / "v" / "video.mp4")
    with pytest.raises(ObservationsError, match=r"video\.mp4: video has 4 frames but cameras\.json asks for frame 50"):
        obs.rgb(3)
    (tmp_path / "v" / "video.mp4").write_bytes(b"\x00" * 100)
    with pytest.raises(ObservationsError, match=r"video\.mp4: cannot be opened as a video"):
        load(tmp_path / "v").rgb(0)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ObservationsError, match="not a capture holousd recognises"):
        load(tmp_path / "empty")
    with pytest.raises(ObservationsError, match="no such folder"):
        load(tmp_path / "missing")
