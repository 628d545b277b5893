"""The MonoSDF / ObjectSDF++ layout (preprocessed Replica and ScanNet++ scenes).

::

    cameras.npz          scale_mat_i, world_mat_i ([4, 4]) for frame i (i = position in sorted *_rgb.png)
    000000_rgb.png       colour
    000000_depth.npy     [H, W] depth (omnidata prior: relative; in the normalised frame of scale_mat)
    000000_normal.npy    [3, H, W] camera-frame normals stored as (n + 1) / 2
    segs/000000_segs.png instance masks (ObjectSDF++), remapped by instance_mapping.txt when present
    instance_mask/000000.png  (alternative mask folder)

``world_mat = K [R | t]`` projects metric world points; ``scale_mat`` maps the normalised (unit-sphere) frame to
the world. The reader decomposes ``P = world_mat @ scale_mat`` with an RQ decomposition into K and the
normalised camera-to-world pose, then applies ``scale_mat`` to get the metric pose (same result as decomposing
``world_mat`` directly). ``scale_mat`` is kept in ``obs.metadata['scale_mat']``.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
from tqdm import tqdm

from holousd.io._files import (
    lazy,
    read_json,
    read_mask,
    read_npy,
    read_rgb,
    write_json,
    write_npy,
    write_npz,
    write_png,
)
from holousd.io._observations import LazyArray, Observations, ObservationsError

__all__ = ["CAMERAS", "decompose_projection", "read_monosdf", "write_monosdf"]

CAMERAS = "cameras.npz"
"""File name of the MonoSDF camera archive."""
_SIDE = "holousd.json"


def decompose_projection(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split a [3, 4] projection ``P = K [R | t]`` into K ([3, 3], K[2, 2] = 1) and the camera-to-world [4, 4].

    RQ decomposition of ``P[:, :3]`` with signs fixed so that K has a positive diagonal (as
    ``cv2.decomposeProjectionMatrix``); the camera centre is the null vector of P.
    """
    from scipy.linalg import rq

    p = np.asarray(p, dtype=np.float64)
    m = p[:, :3]
    if np.linalg.det(m) < 0:
        p, m = -p, -m
    k, r = rq(m)
    signs = np.diag(np.sign(np.diag(k)))
    k, r = k @ signs, signs @ r
    center = -np.linalg.solve(m, p[:, 3])
    c2w = np.eye(4)
    c2w[:3, :3] = r.T
    c2w[:3, 3] = center
    return k / k[2, 2], c2w


def _read_cameras(path: Path, n: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    if not path.is_file():
        raise ObservationsError(f"{path}: camera file is missing; MonoSDF captures need cameras.npz")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: np.asarray(data[key]) for key in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise ObservationsError(f"{path}: cannot be read as a .npz archive ({exc}); is the file corrupt?") from exc
    scale_mats, world_mats = [], []
    for i in range(n):
        for key in (f"world_mat_{i}", f"scale_mat_{i}"):
            if key not in arrays:
                raise ObservationsError(
                    f"{path}: no {key!r} for image {i} ({n} *_rgb.png images); cameras.npz needs world_mat_i and "
                    "scale_mat_i for every image"
                )
        world, scale = arrays[f"world_mat_{i}"].astype(np.float64), arrays[f"scale_mat_{i}"].astype(np.float64)
        if world.shape not in ((4, 4), (3, 4)) or scale.shape != (4, 4):
            raise ObservationsError(f"{path}: world_mat_{i} / scale_mat_{i} have shapes {world.shape} / {scale.shape}")
        world_mats.append(world[:3, :4])
        scale_mats.append(scale)
    return scale_mats, world_mats


def _instance_mapping(folder: Path) -> dict[int, int] | None:
    path = folder / "instance_mapping.txt"
    if not path.is_file():
        return None
    raw: dict[int, int] = {}
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        parts = line.split(",")
        try:
            raw[int(parts[0])] = int(parts[-1])
        except (ValueError, IndexError) as exc:
            raise ObservationsError(f"{path}:{line_no}: expected 'label,semantic,instance' integers") from exc
    labels = sorted(set(raw.values()))  # the smallest is the background (ObjectSDF++ convention)
    return {k: labels.index(v) for k, v in raw.items()}


def _read_segs(path: Path, mapping: dict[int, int] | None) -> np.ndarray:
    mask = read_mask(path)
    if mapping is None:
        return mask
    out = np.zeros_like(mask)
    for value in np.unique(mask):
        if int(value) not in mapping:
            raise ObservationsError(f"{path}: label {int(value)} is not in instance_mapping.txt; add it")
        out[mask == value] = mapping[int(value)]
    return out


def _read_normal_chw(path: Path) -> np.ndarray:
    arr = read_npy(path).astype(np.float32)
    if arr.ndim != 3 or 3 not in (arr.shape[0], arr.shape[-1]):
        raise ObservationsError(f"{path}: normal array has shape {list(arr.shape)}, expected [3, H, W]")
    if arr.shape[0] == 3 and arr.shape[-1] != 3:
        arr = np.moveaxis(arr, 0, -1)
    normal = arr * 2.0 - 1.0
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    return np.where(length > 1e-3, normal / np.maximum(length, 1e-6), 0.0).astype(np.float32)


def _read_depth(path: Path, factor: float) -> np.ndarray:
    depth = read_npy(path).astype(np.float32)
    if depth.ndim == 3 and 1 in (depth.shape[0], depth.shape[-1]):
        depth = depth.reshape(depth.shape[1:] if depth.shape[0] == 1 else depth.shape[:2])
    return depth * np.float32(factor)


def read_monosdf(folder: Path) -> Observations:
    """Read a MonoSDF / ObjectSDF++ scene folder.

    Depth is ``'relative'`` (the omnidata monocular prior these layouts ship) unless a ``holousd.json`` side
    file written by :func:`write_monosdf` says ``'metric'``; metric depth is stored in the normalised frame and
    scaled back to metres here.
    """
    folder = Path(folder)
    images = sorted(folder.glob("*_rgb.png"))
    if not images:
        raise ObservationsError(f"{folder}: no *_rgb.png images; is this a MonoSDF / ObjectSDF++ scene folder?")
    n = len(images)
    prefixes = [p.name[: -len("_rgb.png")] for p in images]
    scale_mats, world_mats = _read_cameras(folder / CAMERAS, n)
    side = read_json(folder / _SIDE, "holousd side file") if (folder / _SIDE).is_file() else {}
    intrinsics, poses = np.zeros((n, 3, 3)), np.zeros((n, 4, 4))
    for i, (scale, world) in enumerate(zip(scale_mats, world_mats, strict=True)):
        if not (np.all(np.isfinite(world)) and np.all(np.isfinite(scale))):
            poses[i] = np.nan  # validate() reports it with the frame
            intrinsics[i] = np.eye(3)
            continue
        try:
            k, c2w_norm = decompose_projection(world @ scale)
        except np.linalg.LinAlgError as exc:
            raise ObservationsError(
                f"{folder / CAMERAS}: world_mat_{i} @ scale_mat_{i} is singular; it must be K [R | t] of a real camera"
            ) from exc
        s = np.cbrt(abs(np.linalg.det(scale[:3, :3])))
        c2w = c2w_norm.copy()
        c2w[:3, :3] = scale[:3, :3] @ c2w_norm[:3, :3] / s
        c2w[:3, 3] = scale[:3, :3] @ c2w_norm[:3, 3] + scale[:3, 3]
        intrinsics[i], poses[i] = k, c2w
    height, width = read_rgb(images[0]).shape[:2]
    depth_kind = side.get("depth_kind", "relative")
    depth_factor = float(np.cbrt(abs(np.linalg.det(scale_mats[0][:3, :3])))) if depth_kind == "metric" else 1.0

    def channel(pattern: str, reader: object, *args: object) -> list[LazyArray] | None:
        files = [folder / pattern.format(p) for p in prefixes]
        present = [f.is_file() for f in files]
        if not any(present):
            return None
        if not all(present):
            missing = files[present.index(False)]
            raise ObservationsError(
                f"{missing}: file is missing ({sum(present)} of {n} frames have one); restore it or remove the others"
            )
        return [lazy(reader, f, *args) for f in files]

    mapping = _instance_mapping(folder)
    masks = channel("segs/{}_segs.png", _read_segs, mapping) or channel("instance_mask/{}.png", read_mask)
    depth = channel("{}_depth.npy", _read_depth, depth_factor)
    instances = side.get("instances")
    return Observations(
        rgb=[lazy(read_rgb, p) for p in images],
        intrinsics=intrinsics,
        poses=poses,
        width=width,
        height=height,
        masks=masks,
        depth=depth,
        normals=channel("{}_normal.npy", _read_normal_chw),
        frame_ids=side["frame_ids"] if len(side.get("frame_ids", [])) == n else prefixes,
        depth_kind=depth_kind if depth else None,
        instance_names={int(k): v for k, v in instances.items()} if instances else None,
        root=folder,
        camera_file=folder / CAMERAS,
        metadata={"scale_mat": scale_mats[0]},
    )


def _normalisation(obs: Observations) -> np.ndarray:
    """scale_mat mapping a unit sphere around the cameras and what they see to the world."""
    if "scale_mat" in obs.metadata:
        return np.asarray(obs.metadata["scale_mat"], dtype=np.float64)
    centers = obs.poses[:, :3, 3]
    center = centers.mean(axis=0)
    reach = float(np.linalg.norm(centers - center, axis=1).max())
    if obs.has_depth and obs.depth_kind == "metric":
        depth = obs.depth(0)
        assert depth is not None
        reach += float(np.percentile(depth[depth > 0], 99)) if np.any(depth > 0) else 1.0
    else:
        reach = max(2.0 * reach, 1.0)
    scale = np.eye(4)
    scale[:3, :3] *= 1.1 * reach
    scale[:3, 3] = center
    return scale


def write_monosdf(obs: Observations, folder: Path, *, progress: bool = False) -> Path:
    """Write ``obs`` in the MonoSDF / ObjectSDF++ layout; returns the ``cameras.npz`` path.

    Masks go to ``segs/<id>_segs.png`` (16-bit) with an identity ``instance_mapping.txt``; depth is divided by
    the scale of ``scale_mat`` (the normalised frame MonoSDF trains in) and a ``holousd.json`` side file records
    its kind and the instance names.
    """
    folder = Path(folder)
    scale_mat = _normalisation(obs)
    s = float(np.cbrt(abs(np.linalg.det(scale_mat[:3, :3]))))
    cameras: dict[str, np.ndarray] = {}
    max_id = 0
    for i in tqdm(range(len(obs)), desc=f"write {folder.name}", unit="frame", disable=not progress):
        prefix = f"{i:06d}"
        k4 = np.eye(4)
        k4[:3, :3] = obs.intrinsics[i]
        cameras[f"scale_mat_{i}"] = scale_mat
        cameras[f"world_mat_{i}"] = k4 @ np.linalg.inv(obs.poses[i])
        write_png(folder / f"{prefix}_rgb.png", obs.rgb(i))
        if obs.has_depth:
            depth = obs.depth(i)
            assert depth is not None
            write_npy(
                folder / f"{prefix}_depth.npy", (depth / s if obs.depth_kind == "metric" else depth).astype(np.float32)
            )
        if obs.has_normals:
            normal = obs.normal(i)
            assert normal is not None
            write_npy(folder / f"{prefix}_normal.npy", np.moveaxis((normal + 1.0) / 2.0, -1, 0).astype(np.float32))
        if obs.has_masks:
            mask = obs.mask(i)
            assert mask is not None
            max_id = max(max_id, int(mask.max()) if mask.size else 0)
            write_png(folder / "segs" / f"{prefix}_segs.png", mask.astype(np.uint16))
    write_npz(folder / CAMERAS, cameras)
    if obs.has_masks:
        ids = sorted(set(range(max_id + 1)) | set(obs.instance_names or {}))
        from holousd._atomic import atomic_path

        with atomic_path(folder / "instance_mapping.txt") as tmp:
            tmp.write_text("".join(f"{k},{k},{k}\n" for k in ids))
    side: dict = {"format": "holousd-monosdf-side", "version": 1, "frame_ids": list(obs.frame_ids)}
    if obs.has_depth:
        side["depth_kind"] = obs.depth_kind
    if obs.instance_names:
        side["instances"] = {str(k): v for k, v in sorted(obs.instance_names.items())}
    write_json(folder / _SIDE, side)
    return folder / CAMERAS
