"""The native layout (``observations.json`` + per-frame files) and the video layout (a video + ``cameras.json``).

Both share one manifest schema, documented in FORMAT.md; the video layout reads colour from the video file
(decoded with PyAV) instead of per-frame images.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm import tqdm

from holousd.io._files import (
    lazy,
    read_depth_png,
    read_json,
    read_mask,
    read_normal_png,
    read_npy,
    read_rgb,
    write_json,
    write_npy,
    write_png,
)
from holousd.io._observations import LazyArray, Observations, ObservationsError

__all__ = [
    "MANIFEST",
    "VIDEO_MANIFEST",
    "VIDEO_SUFFIXES",
    "encode_depth_png",
    "encode_normal_png",
    "read_native",
    "read_video",
    "write_native",
    "write_video",
]

MANIFEST = "observations.json"
"""File name of the native manifest."""
VIDEO_MANIFEST = "cameras.json"
"""File name of the side file of the video layout."""
VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v")
"""Video file extensions the video layout recognises."""
_FORMAT_TAG = "holousd-observations"
_VIDEO_TAG = "holousd-video"
_VERSION = 1
DEPTH_PNG_SCALE = 1000.0
"""Stored units per metre of 16-bit depth PNGs the writers produce (millimetres)."""


def encode_depth_png(depth: np.ndarray, scale: float = DEPTH_PNG_SCALE) -> np.ndarray:
    """[H, W] metres -> [H, W] uint16 (value * scale, rounded); depth beyond the 16-bit range becomes 0 (none)."""
    stored = np.rint(np.asarray(depth, dtype=np.float64) * scale)
    stored[(stored > 65535) | ~np.isfinite(stored) | (stored < 0)] = 0
    return stored.astype(np.uint16)


def encode_normal_png(normal: np.ndarray) -> np.ndarray:
    """[H, W, 3] unit normals -> [H, W, 3] uint8 ((n + 1) / 2 * 255); (0, 0, 0) normals become black (none)."""
    normal = np.asarray(normal, dtype=np.float64)
    valid = np.linalg.norm(normal, axis=-1, keepdims=True) > 1e-6
    encoded = np.clip(np.rint((normal + 1.0) * 127.5), 1, 255).astype(np.uint8)
    return np.where(valid, encoded, 0).astype(np.uint8)


def _matrix(value: object, shape: tuple[int, int], where: str, what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ObservationsError(f"{where}: {what} is not a numeric matrix; write it as nested lists") from exc
    if arr.shape != shape:
        raise ObservationsError(f"{where}: {what} has shape {list(arr.shape)}, expected {list(shape)}")
    return arr


def _read_manifest(path: Path, tag: str) -> dict:
    data = read_json(path, "capture manifest")
    if data.get("format") != tag:
        raise ObservationsError(
            f"{path}: 'format' is {data.get('format')!r}, expected {tag!r}; is this the right manifest?"
        )
    if int(data.get("version", 0)) > _VERSION:
        raise ObservationsError(
            f"{path}: manifest version {data.get('version')} is newer than this holousd reads ({_VERSION}); "
            "upgrade holousd"
        )
    for key in ("width", "height", "frames"):
        if key not in data:
            raise ObservationsError(f"{path}: manifest has no {key!r}; see holousd/io/FORMAT.md")
    if not isinstance(data["frames"], list) or not data["frames"]:
        raise ObservationsError(f"{path}: manifest lists no frames; a capture needs at least one")
    return data


def _parse(path: Path, data: dict, rgb: list[LazyArray]) -> Observations:
    root = path.parent
    frames = data["frames"]
    n = len(frames)
    depth_info = data.get("depth")
    scale = float(depth_info.get("scale", DEPTH_PNG_SCALE)) if depth_info else DEPTH_PNG_SCALE
    shared_k = data.get("intrinsics")
    intrinsics = np.zeros((n, 3, 3))
    poses = np.zeros((n, 4, 4))
    channels: dict[str, list[LazyArray]] = {"mask": [], "depth": [], "normal": []}
    for i, frame in enumerate(frames):
        where = f"{path}: frames[{i}]"
        if not isinstance(frame, dict):
            raise ObservationsError(f"{where} is not an object; see holousd/io/FORMAT.md")
        k = frame.get("intrinsics", shared_k)
        if k is None:
            raise ObservationsError(f"{where} has no 'intrinsics' and the manifest has no shared ones")
        intrinsics[i] = _matrix(k, (3, 3), where, "intrinsics")
        if "camera_to_world" not in frame:
            raise ObservationsError(f"{where} has no 'camera_to_world' pose")
        poses[i] = _matrix(frame["camera_to_world"], (4, 4), where, "camera_to_world")
        for key in channels:
            name = frame.get(key)
            if name is None:
                continue
            file = root / name
            if key == "mask":
                channels[key].append(lazy(read_mask, file))
            elif key == "depth":
                channels[key].append(
                    lazy(read_npy, file) if file.suffix == ".npy" else lazy(read_depth_png, file, scale)
                )
            else:
                channels[key].append(lazy(_read_normal, file))
    for key, values in channels.items():
        if values and len(values) != n:
            raise ObservationsError(
                f"{path}: {len(values)} of {n} frames have a {key!r} file; give one for every frame or none"
            )
    if channels["depth"] and not depth_info:
        raise ObservationsError(f"{path}: frames have depth but the manifest has no 'depth': {{'kind': ...}} entry")
    instances = data.get("instances")
    return Observations(
        rgb=rgb,
        intrinsics=intrinsics,
        poses=poses,
        width=int(data["width"]),
        height=int(data["height"]),
        masks=channels["mask"] or None,
        depth=channels["depth"] or None,
        normals=channels["normal"] or None,
        frame_ids=[str(f.get("id", f"{i:06d}")) for i, f in enumerate(frames)],
        depth_kind=depth_info.get("kind") if depth_info and channels["depth"] else None,
        instance_names={int(k): v for k, v in instances.items()} if instances else None,
        root=root,
        camera_file=path,
    )


def _read_normal(path: Path) -> np.ndarray:
    if path.suffix == ".npy":
        return read_npy(path).astype(np.float32)
    return read_normal_png(path)


def read_native(folder: Path) -> Observations:
    """Read a native capture folder (``observations.json`` + per-frame files)."""
    path = Path(folder) / MANIFEST
    data = _read_manifest(path, _FORMAT_TAG)
    rgb = []
    for i, frame in enumerate(data["frames"]):
        if not isinstance(frame, dict) or "rgb" not in frame:
            raise ObservationsError(f"{path}: frames[{i}] has no 'rgb' image path")
        rgb.append(lazy(read_rgb, path.parent / frame["rgb"]))
    return _parse(path, data, rgb)


def _manifest(obs: Observations, tag: str) -> dict:
    shared = bool(np.allclose(obs.intrinsics, obs.intrinsics[0]))
    data: dict = {
        "format": tag,
        "version": _VERSION,
        "convention": "camera_to_world: OpenCV camera (x right, y down, z forward), world Z up, metres",
        "width": obs.width,
        "height": obs.height,
    }
    if shared:
        data["intrinsics"] = obs.intrinsics[0].tolist()
    if obs.has_depth:
        metric = obs.depth_kind == "metric"
        data["depth"] = {
            "kind": obs.depth_kind,
            "encoding": "png16" if metric else "npy",
            "scale": DEPTH_PNG_SCALE if metric else 1.0,
        }
    if obs.has_normals:
        data["normals"] = {"frame": "camera", "encoding": "png8"}
    if obs.instance_names:
        data["instances"] = {str(k): v for k, v in sorted(obs.instance_names.items())}
    return data


def _frame_entries(obs: Observations, i: int, shared: bool) -> dict:
    entry: dict = {"id": obs.frame_ids[i]}
    if not shared:
        entry["intrinsics"] = obs.intrinsics[i].tolist()
    entry["camera_to_world"] = obs.poses[i].tolist()
    return entry


def _write_side_channels(obs: Observations, folder: Path, i: int, entry: dict, stem: str) -> None:
    if obs.has_masks:
        mask = obs.mask(i)
        assert mask is not None
        if mask.size and int(mask.max()) > 65535:
            raise ObservationsError(f"frame {obs.frame_ids[i]}: instance id {int(mask.max())} does not fit 16 bits")
        entry["mask"] = f"masks/{stem}.png"
        write_png(folder / entry["mask"], mask.astype(np.uint16))
    if obs.has_depth:
        depth = obs.depth(i)
        assert depth is not None
        if obs.depth_kind == "metric":
            entry["depth"] = f"depth/{stem}.png"
            write_png(folder / entry["depth"], encode_depth_png(depth))
        else:
            entry["depth"] = f"depth/{stem}.npy"
            write_npy(folder / entry["depth"], depth.astype(np.float32))
    if obs.has_normals:
        normal = obs.normal(i)
        assert normal is not None
        entry["normal"] = f"normals/{stem}.png"
        write_png(folder / entry["normal"], encode_normal_png(normal))


def _safe_stem(frame_id: str, i: int) -> str:
    ok = frame_id and all(c.isalnum() or c in "-_." for c in frame_id) and not frame_id.startswith(".")
    return frame_id if ok else f"{i:06d}"


def write_native(obs: Observations, folder: Path, *, progress: bool = False) -> Path:
    """Write ``obs`` as a native capture folder; returns the manifest path.

    Colour and masks are PNG (masks 16-bit), metric depth 16-bit PNG in millimetres, relative depth float32
    ``.npy``, normals 8-bit PNG.
    """
    folder = Path(folder)
    data = _manifest(obs, _FORMAT_TAG)
    shared = "intrinsics" in data
    frames = []
    for i in tqdm(range(len(obs)), desc=f"write {folder.name}", unit="frame", disable=not progress):
        stem = _safe_stem(obs.frame_ids[i], i)
        entry = _frame_entries(obs, i, shared)
        entry["rgb"] = f"rgb/{stem}.png"
        write_png(folder / entry["rgb"], obs.rgb(i))
        _write_side_channels(obs, folder, i, entry, stem)
        frames.append(entry)
    data["frames"] = frames
    write_json(folder / MANIFEST, data)
    return folder / MANIFEST


# ---------------------------------------------------------------------- video
class _VideoDecoder:
    """Decodes frames of one video on demand; sequential access is cheap, going backwards reopens the file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._container = None
        self._frames = None
        self._next = 0

    def _open(self) -> None:
        import av

        if not self.path.is_file():
            raise ObservationsError(f"{self.path}: video file is missing; restore it next to {VIDEO_MANIFEST}")
        self.close()
        try:
            self._container = av.open(str(self.path))
            stream = self._container.streams.video[0]
        except (av.error.FFmpegError, IndexError, OSError) as exc:
            raise ObservationsError(f"{self.path}: cannot be opened as a video ({exc}); is the file corrupt?") from exc
        self._frames = self._container.decode(stream)
        self._next = 0

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
        self._container = None
        self._frames = None

    def frame(self, index: int) -> np.ndarray:
        import av

        if self._frames is None or index < self._next:
            self._open()
        try:
            while True:
                decoded = next(self._frames)  # type: ignore[arg-type]
                self._next += 1
                if self._next - 1 == index:
                    return decoded.to_ndarray(format="rgb24")
        except StopIteration:
            count = self._next
            self.close()
            raise ObservationsError(
                f"{self.path}: video has {count} frames but {VIDEO_MANIFEST} asks for frame {index}; "
                "fix video_frame in the side file"
            ) from None
        except av.error.FFmpegError as exc:
            self.close()
            raise ObservationsError(
                f"{self.path}: decoding frame {index} failed ({exc}); is the file corrupt?"
            ) from exc


def find_video(folder: Path) -> Path | None:
    """The single video file in ``folder`` (None when there is none)."""
    videos = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in VIDEO_SUFFIXES and p.is_file())
    return videos[0] if len(videos) == 1 else (videos[0] if videos else None)


def read_video(path: Path) -> Observations:
    """Read the video layout: ``path`` is the folder (or the video file) with ``cameras.json`` beside it."""
    path = Path(path)
    folder = path.parent if path.is_file() else path
    manifest = folder / VIDEO_MANIFEST
    if path.is_file() and not manifest.is_file():
        raise ObservationsError(
            f"{path}: a video needs its side file {VIDEO_MANIFEST} beside it (camera intrinsics and poses per frame, "
            "instance mask files): holousd does not estimate poses or masks from the video alone; write them as "
            "holousd/io/FORMAT.md describes (video layout)"
        )
    data = _read_manifest(manifest, _VIDEO_TAG)
    video = folder / data["video"] if "video" in data else path if path.is_file() else None
    if video is None:
        raise ObservationsError(f"{manifest}: no 'video' entry naming the video file")
    decoder = _VideoDecoder(video)
    width, height = int(data["width"]), int(data["height"])

    def read(k: int) -> np.ndarray:
        image = decoder.frame(k)
        if image.shape[0] - height in (0, 1) and image.shape[1] - width in (0, 1):
            image = image[:height, :width]  # writers pad odd sizes by one pixel for yuv420p
        return image

    rgb = []
    for i, frame in enumerate(data["frames"]):
        index = frame.get("video_frame", i) if isinstance(frame, dict) else i
        if not isinstance(index, int) or index < 0:
            raise ObservationsError(f"{manifest}: frames[{i}].video_frame must be a non-negative integer")
        rgb.append(LazyArray(lambda k=index: read(k), f"{video}#frame {index}"))
    return _parse(manifest, data, rgb)


def write_video(obs: Observations, folder: Path, *, fps: float = 30.0, crf: int = 18, progress: bool = False) -> Path:
    """Write ``obs`` as the video layout: ``video.mp4`` (H.264, lossy) + ``cameras.json`` + per-frame side files.

    Args:
        obs: Observations to write.
        folder: Output folder.
        fps: Frame rate of the video, frames per second.
        crf: H.264 constant rate factor (0 = best, 51 = worst).
        progress: Show a progress bar on stderr.

    Returns:
        The path of ``cameras.json``.
    """
    import av

    from holousd._atomic import atomic_path

    folder = Path(folder)
    data = _manifest(obs, _VIDEO_TAG)
    data["video"] = "video.mp4"
    shared = "intrinsics" in data
    frames = []
    width, height = obs.width + obs.width % 2, obs.height + obs.height % 2  # yuv420p needs even sizes
    with atomic_path(folder / "video.mp4") as tmp:
        with av.open(str(tmp), mode="w", format="mp4") as container:
            stream = container.add_stream("libx264", rate=int(round(fps)))
            stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
            stream.options = {"crf": str(crf), "preset": "medium"}
            stream.codec_context.thread_count = 1  # deterministic bytes
            for i in tqdm(range(len(obs)), desc=f"write {folder.name}", unit="frame", disable=not progress):
                rgb = obs.rgb(i)
                if rgb.shape[:2] != (height, width):
                    rgb = np.pad(rgb, ((0, height - rgb.shape[0]), (0, width - rgb.shape[1]), (0, 0)), mode="edge")
                for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")):
                    container.mux(packet)
                entry = _frame_entries(obs, i, shared)
                entry["video_frame"] = i
                _write_side_channels(obs, folder, i, entry, _safe_stem(obs.frame_ids[i], i))
                frames.append(entry)
            for packet in stream.encode():
                container.mux(packet)
    data["frames"] = frames
    if (width, height) != (obs.width, obs.height):
        data["note"] = f"video padded to {width}x{height} (even size); frames are cropped to {obs.width}x{obs.height}"
    write_json(folder / VIDEO_MANIFEST, data)
    return folder / VIDEO_MANIFEST
