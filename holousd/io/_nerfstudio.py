"""nerfstudio ``transforms.json`` captures with an ``instance_mask/`` folder (the layout HoloScene's data uses).

nerfstudio poses are camera-to-world in the OpenGL camera convention (x right, y up, z backward) and its rays
go through pixel centres at ``u + 0.5``; holousd uses OpenCV (x right, y down, z forward, centres at ``u``).
Reading converts both: ``c2w_cv = c2w_gl @ diag(1, -1, -1, 1)`` and ``cx_cv = cx_ns - 0.5``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm import tqdm

from holousd.io._files import lazy, read_depth_png, read_json, read_mask, read_npy, read_rgb, write_json, write_png
from holousd.io._native import _read_normal, _safe_stem, encode_depth_png, encode_normal_png
from holousd.io._observations import Observations, ObservationsError

__all__ = ["TRANSFORMS", "read_nerfstudio", "write_nerfstudio"]

TRANSFORMS = "transforms.json"
"""File name of the nerfstudio camera file."""
_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])
_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
_MASK_DIR = "instance_mask"


def _intrinsics(source: dict, fallback: dict, where: str) -> tuple[np.ndarray, int, int]:
    def get(key: str) -> float:
        value = source.get(key, fallback.get(key))
        if value is None:
            raise ObservationsError(f"{where}: no {key!r} (per frame or at the top level); nerfstudio needs it")
        return float(value)

    k = np.array([[get("fl_x"), 0.0, get("cx") - 0.5], [0.0, get("fl_y"), get("cy") - 0.5], [0.0, 0.0, 1.0]])
    for key in _DISTORTION:
        value = source.get(key, fallback.get(key, 0.0))
        if value and abs(float(value)) > 1e-9:
            raise ObservationsError(
                f"{where}: lens distortion {key}={value} is not supported; undistort the images first "
                "(ns-process-data does) and set the coefficients to 0"
            )
    return k, int(get("w")), int(get("h"))


def _find_mask(root: Path, image: str) -> Path | None:
    stem = Path(image).stem
    for suffix in (".png", ".npy"):
        candidate = root / _MASK_DIR / f"{stem}{suffix}"
        if candidate.exists():
            return candidate
    return None


def read_nerfstudio(folder: Path) -> Observations:
    """Read a nerfstudio capture: ``transforms.json``, images, optional ``instance_mask/<image stem>.png``,
    depth (``depth_file_path``, 16-bit PNG scaled by ``depth_unit_scale_factor``, default 0.001 = millimetres)
    and normals (``normal_file_path``, holousd extension: 8-bit PNG or ``.npy``, camera frame OpenCV).
    """
    folder = Path(folder)
    path = folder / TRANSFORMS
    data = read_json(path, "nerfstudio transforms.json")
    frames = data.get("frames")
    if not isinstance(frames, list) or not frames:
        raise ObservationsError(f"{path}: no 'frames' list; a capture needs at least one frame")
    model = data.get("camera_model", "OPENCV")
    if model not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE"):
        raise ObservationsError(f"{path}: camera_model {model!r} is not supported; give a pinhole/OPENCV capture")
    scale = 1.0 / float(data.get("depth_unit_scale_factor", 1e-3))
    extra = data.get("holousd", {}) if isinstance(data.get("holousd"), dict) else {}
    n = len(frames)
    intrinsics, poses = np.zeros((n, 3, 3)), np.zeros((n, 4, 4))
    rgb, masks, depth, normals, ids = [], [], [], [], []
    width = height = None
    for i, frame in enumerate(frames):
        where = f"{path}: frames[{i}]"
        if not isinstance(frame, dict) or "file_path" not in frame or "transform_matrix" not in frame:
            raise ObservationsError(f"{where} needs 'file_path' and 'transform_matrix'")
        intrinsics[i], w, h = _intrinsics(frame, data, where)
        if width is None:
            width, height = w, h
        elif (w, h) != (width, height):
            raise ObservationsError(f"{where}: size {w}x{h} differs from the first frame's {width}x{height}")
        try:
            gl = np.asarray(frame["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ObservationsError(f"{where}: transform_matrix is not a numeric 4x4 matrix") from exc
        if gl.shape == (3, 4):
            gl = np.vstack([gl, [0.0, 0.0, 0.0, 1.0]])
        if gl.shape != (4, 4):
            raise ObservationsError(f"{where}: transform_matrix has shape {list(gl.shape)}, expected [4, 4]")
        poses[i] = gl @ _GL_TO_CV
        rgb.append(lazy(read_rgb, folder / frame["file_path"]))
        stem = Path(frame["file_path"]).stem
        ids.append(stem.removeprefix("frame_") or stem)
        mask = _find_mask(folder, frame["file_path"])
        masks.append(lazy(read_mask, mask) if mask else None)
        if "depth_file_path" in frame:
            file = folder / frame["depth_file_path"]
            depth.append(lazy(read_npy, file) if file.suffix == ".npy" else lazy(read_depth_png, file, scale))
        if "normal_file_path" in frame:
            normals.append(lazy(_read_normal, folder / frame["normal_file_path"]))
    present = [m is not None for m in masks]
    if any(present) and not all(present):
        missing = ids[present.index(False)]
        raise ObservationsError(
            f"{folder / _MASK_DIR}: no instance mask for frame {missing!r} ({sum(present)} of {n} frames have one); "
            f"add {_MASK_DIR}/{missing}.png or remove the folder"
        )
    for name, values in (("depth_file_path", depth), ("normal_file_path", normals)):
        if values and len(values) != n:
            raise ObservationsError(f"{path}: {len(values)} of {n} frames have {name!r}; give it for all or none")
    instances = extra.get("instances")
    return Observations(
        rgb=rgb,
        intrinsics=intrinsics,
        poses=poses,
        width=width or 0,
        height=height or 0,
        masks=masks if all(present) else None,
        depth=depth or None,
        normals=normals or None,
        frame_ids=ids,
        depth_kind=extra.get("depth_kind", "metric") if depth else None,
        instance_names={int(k): v for k, v in instances.items()} if instances else None,
        root=folder,
        camera_file=path,
    )


def write_nerfstudio(obs: Observations, folder: Path, *, progress: bool = False) -> Path:
    """Write ``obs`` as a nerfstudio capture (``images/``, ``instance_mask/``, ``depth/``, ``normals/``).

    Returns:
        The path of ``transforms.json``.
    """
    folder = Path(folder)
    if obs.has_depth and obs.depth_kind != "metric":
        raise ObservationsError(
            f"{folder}: nerfstudio depth is metric; write relative (monocular) depth in the native or monosdf format"
        )
    data: dict = {"camera_model": "OPENCV", "w": obs.width, "h": obs.height}
    shared = bool(np.allclose(obs.intrinsics, obs.intrinsics[0]))
    if shared:
        k = obs.intrinsics[0]
        data.update(fl_x=k[0, 0], fl_y=k[1, 1], cx=k[0, 2] + 0.5, cy=k[1, 2] + 0.5)
    data.update(k1=0.0, k2=0.0, p1=0.0, p2=0.0)
    if obs.has_depth:
        data["depth_unit_scale_factor"] = 1e-3
    extra: dict = {"depth_kind": obs.depth_kind} if obs.has_depth else {}
    if obs.instance_names:
        extra["instances"] = {str(k): v for k, v in sorted(obs.instance_names.items())}
    if extra:
        data["holousd"] = extra
    frames = []
    for i in tqdm(range(len(obs)), desc=f"write {folder.name}", unit="frame", disable=not progress):
        stem = f"frame_{_safe_stem(obs.frame_ids[i], i)}"
        entry: dict = {"file_path": f"images/{stem}.png", "transform_matrix": (obs.poses[i] @ _GL_TO_CV).tolist()}
        if not shared:
            k = obs.intrinsics[i]
            entry.update(fl_x=k[0, 0], fl_y=k[1, 1], cx=k[0, 2] + 0.5, cy=k[1, 2] + 0.5)
        write_png(folder / entry["file_path"], obs.rgb(i))
        if obs.has_masks:
            write_png(folder / _MASK_DIR / f"{stem}.png", obs.mask(i).astype(np.uint16))  # type: ignore[union-attr]
        if obs.has_depth:
            entry["depth_file_path"] = f"depth/{stem}.png"
            write_png(folder / entry["depth_file_path"], encode_depth_png(obs.depth(i)))  # type: ignore[arg-type]
        if obs.has_normals:
            entry["normal_file_path"] = f"normals/{stem}.png"
            write_png(folder / entry["normal_file_path"], encode_normal_png(obs.normal(i)))  # type: ignore[arg-type]
        frames.append(entry)
    data["frames"] = frames
    write_json(folder / TRANSFORMS, data)
    return folder / TRANSFORMS
