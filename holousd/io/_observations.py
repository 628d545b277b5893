"""The ``Observations`` type: every later stage reads captures through it.

Conventions (also in FORMAT.md):

- Poses are camera-to-world [4, 4] matrices in the OpenCV camera convention: camera x right, y down, z forward
  (the viewing direction). World coordinates are metres with Z up. ``p_world = pose @ [p_cam, 1]``.
- Intrinsics are [3, 3] pinhole matrices ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels, OpenCV pixel
  convention: the centre of pixel (u, v) (column u, row v) sits at image coordinates (u, v).
- Instance masks are integer images: 0 = background (room shell), 1..N = objects.
- Depth is z-depth along the optical axis (not distance along the ray). ``depth_kind`` says whether it is
  ``'metric'`` (metres) or ``'relative'`` (monocular priors: valid up to an unknown scale and shift).
  0 marks pixels without a depth value.
- Normals are unit vectors in the OpenCV camera frame of their frame ([H, W, 3]); (0, 0, 0) marks pixels
  without a normal.

Frames are loaded lazily: an ``Observations`` holds one small loader per frame and channel, so a 1000-frame
capture never sits in memory; ``obs.rgb(i)`` reads frame ``i`` when asked.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from holousd._errors import HolousdError

__all__ = ["DEPTH_KINDS", "CaptureCheck", "Frame", "LazyArray", "Observations", "ObservationsError"]

DEPTH_KINDS = ("metric", "relative")
"""Allowed values of ``Observations.depth_kind``."""

_ROTATION_TOL = 1e-3
"""Largest deviation of R^T R from I (and of det R from 1) accepted for a rigid pose."""


_FAR_PLANE_MIN_SHARE = 1e-3
"""Share of all depth pixels that must sit at the capture's maximum depth for it to count as a far plane."""
_FAR_PLANE_GAP = 0.9
"""The deepest other depth value must lie below this fraction of the maximum (a far plane stands apart)."""


class ObservationsError(HolousdError):
    """Observations are missing, unreadable or inconsistent (message names the file or frame and the fix)."""


@dataclass(kw_only=True)
class CaptureCheck:
    """What :meth:`Observations.validate` found besides errors: the depth pixels that carry no measurement.

    Depth pixels that are 0 (no value), NaN / infinite, or at the capture's far plane (a renderer's or sensor's
    constant maximum written where nothing was hit) are not measurements. They are counted here and ignored by
    :meth:`Observations.with_valid_depth`; a capture with no valid depth pixel at all is fitted from its masks.
    """

    frames: int = 0
    """Frames checked."""
    depth_pixels: int = 0
    """Depth pixels over all frames (0 without depth or when pixels were not read)."""
    zero_depth: int = 0
    """Pixels with depth 0 (no value)."""
    nonfinite_depth: int = 0
    """Pixels with NaN or infinite depth."""
    far_plane_depth: int = 0
    """Pixels at the far plane (see :attr:`far_plane_m`)."""
    far_plane_m: float | None = None
    """Depth of the detected far plane (the constant maximum), or None when there is none."""

    @property
    def invalid_depth(self) -> int:
        """Depth pixels that carry no measurement (zero, non-finite or far plane)."""
        return self.zero_depth + self.nonfinite_depth + self.far_plane_depth

    @property
    def valid_depth(self) -> int:
        """Depth pixels that carry a measurement."""
        return self.depth_pixels - self.invalid_depth

    @property
    def warnings(self) -> list[str]:
        """One line per finding worth telling the user (empty when the depth is clean or absent)."""
        if self.depth_pixels == 0:
            return []
        if self.valid_depth <= 0:
            return [f"depth: none of the {self.depth_pixels} depth pixels holds a measurement (all zero, NaN or at a "
                    "far plane); the capture counts as one without depth (holousd reconstruct --depth)"]  # fmt: skip
        if self.nonfinite_depth == 0 and self.far_plane_depth == 0:
            return []
        parts = []
        if self.far_plane_depth:
            parts.append(f"{self.far_plane_depth} at the far plane ({self.far_plane_m:g} m, nothing was hit there)")
        if self.nonfinite_depth:
            parts.append(f"{self.nonfinite_depth} NaN or infinite")
        share = 100.0 * (self.far_plane_depth + self.nonfinite_depth) / self.depth_pixels
        return [f"depth: ignoring {' and '.join(parts)} depth pixels ({share:.1f}% of {self.depth_pixels}); "
                "write 0 where a pixel has no depth to silence this"]  # fmt: skip


class LazyArray:
    """A per-frame array that is read only when :meth:`load` is called.

    Args:
        read: Function returning the array (it raises :class:`ObservationsError` naming the file on failure).
        source: Where the array comes from (a file path, ``video.mp4#frame 12`` or ``<memory>``), for messages.
    """

    __slots__ = ("_read", "source")

    def __init__(self, read: Callable[[], np.ndarray], source: str) -> None:
        self._read = read
        self.source = source
        """Human-readable origin of the array."""

    @classmethod
    def of(cls, array: np.ndarray) -> LazyArray:
        """Wrap an in-memory array."""
        array = np.asarray(array)
        return cls(lambda: array, "<memory>")

    def load(self) -> np.ndarray:
        """Read and return the array."""
        return self._read()

    def __repr__(self) -> str:
        return f"LazyArray({self.source})"


@dataclass(kw_only=True)
class Frame:
    """One loaded frame of an :class:`Observations`."""

    index: int
    """Position of the frame in the observations."""
    frame_id: str
    """Frame id (file stem or video frame number)."""
    rgb: np.ndarray
    """[H, W, 3] uint8 colour image."""
    mask: np.ndarray | None
    """[H, W] int32 instance ids (0 = background), or None."""
    depth: np.ndarray | None
    """[H, W] float32 z-depth (metres when metric; 0 = no value), or None."""
    normal: np.ndarray | None
    """[H, W, 3] float32 unit normals in the OpenCV camera frame ((0, 0, 0) = no value), or None."""
    intrinsics: np.ndarray
    """[3, 3] pinhole intrinsics, pixels."""
    pose: np.ndarray
    """[4, 4] camera-to-world matrix (OpenCV camera, world Z up, metres)."""


def _lazy_list(values: object, n: int | None, what: str) -> list[LazyArray] | None:
    if values is None:
        return None
    if isinstance(values, np.ndarray):
        return [LazyArray.of(v) for v in values]
    out = []
    for v in values:  # type: ignore[attr-defined]
        out.append(v if isinstance(v, LazyArray) else LazyArray.of(np.asarray(v)))
    if n is not None and len(out) != n:
        raise ObservationsError(f"Observations.{what}: {len(out)} entries for {n} frames; give one per frame")
    return out


class Observations:
    """A capture of a static scene: frames, cameras, instance masks and optional depth and normals.

    Args:
        rgb: Per-frame colour images: an [N, H, W, 3] uint8 array, or a sequence of [H, W, 3] arrays or
            :class:`LazyArray` (lazy loading).
        intrinsics: [N, 3, 3] pinhole intrinsics in pixels (or one [3, 3] shared by all frames).
        poses: [N, 4, 4] camera-to-world matrices, OpenCV camera convention (x right, y down, z forward),
            world Z up, metres.
        width: Image width in pixels.
        height: Image height in pixels.
        masks: Per-frame [H, W] integer instance masks (0 = background, 1..N objects), or None.
        depth: Per-frame [H, W] z-depth (0 = no value), or None.
        normals: Per-frame [H, W, 3] unit normals in the OpenCV camera frame, or None.
        frame_ids: One unique id per frame (default: ``000000``, ``000001``, ...).
        depth_kind: ``'metric'`` (metres) or ``'relative'`` (monocular prior, unknown scale and shift); required
            when depth is given.
        instance_names: Optional names of the instance ids, ``{1: 'table', ...}``; when given, every id must
            appear in some mask and masks may hold no other id.
        root: Folder or file the observations were read from (for messages), or None.
        camera_file: File the intrinsics and poses were read from (for messages), or None.
        metadata: Format-specific extras kept for writers (e.g. the MonoSDF ``scale_mat``).
    """

    def __init__(
        self,
        *,
        rgb: Sequence[np.ndarray | LazyArray] | np.ndarray,
        intrinsics: np.ndarray,
        poses: np.ndarray,
        width: int,
        height: int,
        masks: Sequence[np.ndarray | LazyArray] | np.ndarray | None = None,
        depth: Sequence[np.ndarray | LazyArray] | np.ndarray | None = None,
        normals: Sequence[np.ndarray | LazyArray] | np.ndarray | None = None,
        frame_ids: Sequence[str] | None = None,
        depth_kind: str | None = None,
        instance_names: dict[int, str] | None = None,
        root: str | os.PathLike[str] | None = None,
        camera_file: str | os.PathLike[str] | None = None,
        metadata: dict | None = None,
    ) -> None:
        self._rgb = _lazy_list(rgb, None, "rgb") or []
        n = len(self._rgb)
        self._masks = _lazy_list(masks, n, "masks")
        self._depth = _lazy_list(depth, n, "depth")
        self._normals = _lazy_list(normals, n, "normals")
        intrinsics = np.asarray(intrinsics, dtype=np.float64)
        if intrinsics.shape == (3, 3):
            intrinsics = np.broadcast_to(intrinsics, (n, 3, 3)).copy()
        self.intrinsics = intrinsics
        """[N, 3, 3] pinhole intrinsics, pixels."""
        self.poses = np.asarray(poses, dtype=np.float64)
        """[N, 4, 4] camera-to-world matrices (OpenCV camera, world Z up, metres)."""
        self.width = int(width)
        """Image width, pixels."""
        self.height = int(height)
        """Image height, pixels."""
        self.frame_ids = [str(f) for f in frame_ids] if frame_ids is not None else [f"{i:06d}" for i in range(n)]
        """One unique id per frame."""
        if depth is not None and depth_kind is None:
            raise ObservationsError("Observations: depth given without depth_kind; pass 'metric' or 'relative'")
        if depth_kind is not None and depth_kind not in DEPTH_KINDS:
            raise ObservationsError(f"Observations: depth_kind must be one of {DEPTH_KINDS}, got {depth_kind!r}")
        self.depth_kind = depth_kind if depth is not None else None
        """'metric' (metres), 'relative' (monocular prior) or None without depth."""
        self.instance_names = {int(k): str(v) for k, v in instance_names.items()} if instance_names else None
        """Names of the instance ids (``{1: 'table'}``), or None when not known."""
        self.root = Path(root) if root is not None else None
        """Where the observations were read from, or None."""
        self.camera_file = Path(camera_file) if camera_file is not None else None
        """File the intrinsics and poses were read from, or None."""
        self.metadata = dict(metadata) if metadata else {}
        """Format-specific extras (e.g. ``{'scale_mat': [4, 4] array}`` from MonoSDF data)."""

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_frames(cls, frames: Sequence[Frame], **kwargs: object) -> Observations:
        """Build in-memory observations from loaded :class:`Frame` objects (``kwargs`` as in the constructor)."""
        if not frames:
            raise ObservationsError("Observations.from_frames: no frames given; give at least one")
        h, w = frames[0].rgb.shape[:2]

        def channel(name: str) -> list[np.ndarray] | None:
            values = [getattr(f, name) for f in frames]
            return None if any(v is None for v in values) else values

        return cls(
            rgb=[f.rgb for f in frames],
            intrinsics=np.stack([f.intrinsics for f in frames]),
            poses=np.stack([f.pose for f in frames]),
            width=w,
            height=h,
            masks=channel("mask"),
            depth=channel("depth"),
            normals=channel("normal"),
            frame_ids=[f.frame_id for f in frames],
            **kwargs,  # type: ignore[arg-type]
        )

    # ------------------------------------------------------------------ access
    def __len__(self) -> int:
        return len(self._rgb)

    def __repr__(self) -> str:
        extras = [
            name
            for name, on in (("masks", self.has_masks), ("depth", self.has_depth), ("normals", self.has_normals))
            if on
        ]
        return (
            f"Observations({len(self)} frames, {self.width}x{self.height}, "
            f"{'+'.join(['rgb', *extras])}, root={str(self.root) if self.root else None!r})"
        )

    @property
    def has_masks(self) -> bool:
        """True when every frame has an instance mask."""
        return self._masks is not None

    @property
    def has_depth(self) -> bool:
        """True when every frame has depth (see ``depth_kind``)."""
        return self._depth is not None

    @property
    def has_normals(self) -> bool:
        """True when every frame has a normal map."""
        return self._normals is not None

    def _check_index(self, i: int) -> int:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame index {i} out of range for {n} frames")
        return i % n

    def rgb(self, i: int) -> np.ndarray:
        """Frame ``i``'s [H, W, 3] uint8 colour image."""
        return self._rgb[self._check_index(i)].load()

    def mask(self, i: int) -> np.ndarray | None:
        """Frame ``i``'s [H, W] int32 instance mask (0 = background), or None without masks."""
        return None if self._masks is None else self._masks[self._check_index(i)].load()

    def depth(self, i: int) -> np.ndarray | None:
        """Frame ``i``'s [H, W] float32 z-depth (0 = no value), or None without depth."""
        return None if self._depth is None else self._depth[self._check_index(i)].load()

    def normal(self, i: int) -> np.ndarray | None:
        """Frame ``i``'s [H, W, 3] float32 camera-frame normals, or None without normals."""
        return None if self._normals is None else self._normals[self._check_index(i)].load()

    def source(self, i: int, channel: str) -> str:
        """Where frame ``i``'s ``channel`` ('rgb', 'mask', 'depth', 'normal') is read from."""
        lists = {"rgb": self._rgb, "mask": self._masks, "depth": self._depth, "normal": self._normals}
        values = lists[channel]
        return "<none>" if values is None else values[self._check_index(i)].source

    def frame(self, i: int) -> Frame:
        """Load every channel of frame ``i``."""
        i = self._check_index(i)
        return Frame(
            index=i,
            frame_id=self.frame_ids[i],
            rgb=self.rgb(i),
            mask=self.mask(i),
            depth=self.depth(i),
            normal=self.normal(i),
            intrinsics=self.intrinsics[i].copy(),
            pose=self.poses[i].copy(),
        )

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)

    def subset(self, indices: Sequence[int]) -> Observations:
        """Observations of the frames at ``indices`` (still lazy)."""
        idx = [self._check_index(int(i)) for i in indices]

        def pick(values: list[LazyArray] | None) -> list[LazyArray] | None:
            return None if values is None else [values[i] for i in idx]

        return Observations(
            rgb=pick(self._rgb) or [],
            intrinsics=self.intrinsics[idx],
            poses=self.poses[idx],
            width=self.width,
            height=self.height,
            masks=pick(self._masks),
            depth=pick(self._depth),
            normals=pick(self._normals),
            frame_ids=[self.frame_ids[i] for i in idx],
            depth_kind=self.depth_kind,
            instance_names=self.instance_names,
            root=self.root,
            camera_file=self.camera_file,
            metadata=self.metadata,
        )

    # ------------------------------------------------------------------ validation
    def _where(self, i: int | None = None, channel: str | None = None) -> str:
        if i is not None and channel is not None:
            src = self.source(i, channel)
            if src != "<memory>":
                return f"{src} (frame {i}, id {self.frame_ids[i]!r})"
        source = self.camera_file if (i is not None and self.camera_file is not None) else self.root
        base = str(source) if source is not None else "<observations>"
        return base if i is None else f"{base}: frame {i} (id {self.frame_ids[i]!r})"

    def validate(self, *, pixels: bool = True) -> CaptureCheck:
        """Check the observations and raise :class:`ObservationsError` at the first problem.

        Checks: at least one frame; array shapes; unique frame ids; finite intrinsics with positive focal
        lengths and the principal point inside the image; finite, rigid camera-to-world poses (orthonormal
        rotation with determinant +1, last row 0 0 0 1). With ``pixels`` (default) every frame is also read:
        files exist and decode, every image has the declared size, colour frames are not empty (a single
        colour), masks are integer images, depth has the image's size and metric depth is not negative, normals
        are finite unit vectors, and the instance ids seen in the masks are exactly 1..N (or exactly the ids of
        ``instance_names``). Depth pixels without a measurement (0, NaN / infinite, a far plane) are no error:
        they are counted in the returned :class:`CaptureCheck` (pass it to :meth:`with_valid_depth`).

        Args:
            pixels: Also read and check every frame (slow for long captures; one frame in memory at a time).

        Returns:
            Counts of the depth pixels that carry no measurement (all zero when ``pixels`` is False).
        """
        n = len(self)
        where = self._where()
        if n == 0:
            raise ObservationsError(f"{where}: no frames; a capture needs at least one image")
        if self.width <= 0 or self.height <= 0:
            raise ObservationsError(f"{where}: image size {self.width}x{self.height} is empty; give width/height > 0")
        if self.intrinsics.shape != (n, 3, 3):
            raise ObservationsError(
                f"{where}: intrinsics have shape {list(self.intrinsics.shape)}, expected [{n}, 3, 3] (one per frame)"
            )
        if self.poses.shape != (n, 4, 4):
            raise ObservationsError(
                f"{where}: poses have shape {list(self.poses.shape)}, expected [{n}, 4, 4] (one per frame)"
            )
        if len(self.frame_ids) != n:
            raise ObservationsError(f"{where}: {len(self.frame_ids)} frame ids for {n} frames; give one id per frame")
        if len(set(self.frame_ids)) != n:
            dup = sorted({f for f in self.frame_ids if self.frame_ids.count(f) > 1})[:3]
            raise ObservationsError(f"{where}: duplicate frame ids {dup}; frame ids must be unique")
        for i in range(n):
            self._check_camera(i)
        check = CaptureCheck(frames=n)
        if pixels:
            self._check_pixels(check)
        return check

    def with_valid_depth(self, check: CaptureCheck) -> Observations:
        """These observations with the depth pixels ``check`` found invalid set to 0 (no value) as frames load;
        without depth when no pixel holds a measurement (the fit then carves the masks)."""
        if self._depth is None or check.depth_pixels == 0:
            return self
        if check.valid_depth <= 0:
            return self._replace(depth=None)
        far = check.far_plane_m

        def clean(lazy: LazyArray) -> LazyArray:
            def read() -> np.ndarray:
                depth = np.asarray(lazy.load(), dtype=np.float32)
                bad = ~np.isfinite(depth)
                if far is not None:
                    bad |= depth >= np.float32(far) * np.float32(1.0 - 1e-6)
                return np.where(bad, np.float32(0.0), depth) if bad.any() else depth

            return LazyArray(read, lazy.source)

        return self._replace(depth=[clean(d) for d in self._depth])

    def with_depth(self, depth: Sequence[np.ndarray | LazyArray], kind: str, prior: str | None = None) -> Observations:
        """The same capture with another depth channel (one [H, W] z-depth per frame, 0 = no value) of ``kind``
        'metric' or 'relative'; ``prior`` names the depth prior that estimated it (kept as
        ``metadata['depth_prior']``: the fit treats estimated depth as the noisier thing it is)."""
        if len(depth) != len(self):
            raise ObservationsError(f"{self.root or '<observations>'}: with_depth needs {len(self)} depth maps, got "
                                    f"{len(depth)}")  # fmt: skip
        metadata = {k: v for k, v in self.metadata.items() if k != "depth_prior"}
        if prior is not None:
            metadata["depth_prior"] = prior
        return self._replace(depth=list(depth), depth_kind=kind, metadata=metadata)

    def with_poses(self, poses: np.ndarray) -> Observations:
        """The same capture with other [N, 4, 4] camera-to-world poses (e.g. those s1_fit aligned)."""
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != (len(self), 4, 4):
            raise ObservationsError(f"{self.root or '<observations>'}: with_poses needs {len(self)} 4x4 poses, got "
                                    f"an array of shape {list(poses.shape)}")  # fmt: skip
        if not np.all(np.isfinite(poses)):
            raise ObservationsError(f"{self.root or '<observations>'}: with_poses got NaN or infinite poses")
        return self._replace(poses=poses)

    def _replace(self, **changes: object) -> Observations:
        fields = dict(rgb=self._rgb, intrinsics=self.intrinsics, poses=self.poses, width=self.width,
                      height=self.height, masks=self._masks, depth=self._depth, normals=self._normals,
                      frame_ids=self.frame_ids, depth_kind=self.depth_kind, instance_names=self.instance_names,
                      root=self.root, camera_file=self.camera_file, metadata=self.metadata)  # fmt: skip
        fields.update(changes)
        if fields["depth"] is None:
            fields["depth_kind"] = None
        return Observations(**fields)  # type: ignore[arg-type]

    def _check_camera(self, i: int) -> None:
        where = self._where(i)
        k = self.intrinsics[i]
        if not np.all(np.isfinite(k)):
            raise ObservationsError(f"{where}: intrinsics contain NaN or infinite values; fix the camera file")
        if k[0, 0] <= 0 or k[1, 1] <= 0:
            raise ObservationsError(f"{where}: focal lengths fx={k[0, 0]}, fy={k[1, 1]} must be positive pixels")
        if not np.allclose(k[2], [0.0, 0.0, 1.0]) or abs(k[0, 1]) > 1e-9 or abs(k[1, 0]) > 1e-9:
            raise ObservationsError(
                f"{where}: intrinsics {k.tolist()} are not a pinhole matrix [[fx,0,cx],[0,fy,cy],[0,0,1]]"
            )
        if not (-0.5 <= k[0, 2] <= self.width - 0.5 and -0.5 <= k[1, 2] <= self.height - 0.5):
            raise ObservationsError(
                f"{where}: principal point ({k[0, 2]}, {k[1, 2]}) lies outside the {self.width}x{self.height} image; "
                "check that intrinsics match the image resolution"
            )
        pose = self.poses[i]
        if not np.all(np.isfinite(pose)):
            raise ObservationsError(f"{where}: camera pose contains NaN or infinite values; fix or drop this frame")
        if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
            raise ObservationsError(f"{where}: camera pose last row is {pose[3].tolist()}, expected [0, 0, 0, 1]")
        rot = pose[:3, :3]
        err = float(np.abs(rot.T @ rot - np.eye(3)).max())
        det = float(np.linalg.det(rot))
        if err > _ROTATION_TOL:
            raise ObservationsError(
                f"{where}: camera pose is not rigid (rotation has scale or shear, |R^T R - I| = {err:.3g}); "
                "give camera-to-world poses in metres with an orthonormal rotation"
            )
        if abs(det - 1.0) > _ROTATION_TOL:
            raise ObservationsError(
                f"{where}: camera pose rotation has determinant {det:.3g} (a reflection); convert the poses to a "
                "right-handed OpenCV camera convention"
            )

    def _check_pixels(self, check: CaptureCheck) -> None:
        seen: set[int] = set()
        pixels: dict[int, int] = {}  # instance id -> mask pixels over all frames
        first: dict[int, int] = {}  # instance id -> first frame it appears in
        tops: list[tuple[float, int, float]] = []  # per depth frame: (max, pixels at max, deepest value below it)
        size = (self.height, self.width)
        for i in range(len(self)):
            rgb = self.rgb(i)
            if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
                raise ObservationsError(
                    f"{self._where(i, 'rgb')}: colour image has shape {list(rgb.shape)} {rgb.dtype}, "
                    "expected [H, W, 3] uint8"
                )
            if rgb.shape[:2] != size:
                raise ObservationsError(
                    f"{self._where(i, 'rgb')}: image is {rgb.shape[1]}x{rgb.shape[0]}, the capture declares "
                    f"{self.width}x{self.height}; resize the image or fix width/height"
                )
            if rgb.size == 0 or np.all(rgb == rgb.reshape(-1, 3)[0]):
                raise ObservationsError(
                    f"{self._where(i, 'rgb')}: empty frame (every pixel is {rgb.reshape(-1, 3)[0].tolist()}); "
                    "drop the frame or fix the export"
                )
            if self._masks is not None:
                mask = self.mask(i)
                assert mask is not None
                where = self._where(i, "mask")
                if mask.ndim != 2 or mask.shape != size:
                    raise ObservationsError(
                        f"{where}: mask has shape {list(mask.shape)}, expected [{self.height}, {self.width}] "
                        "(one instance id per pixel, same size as the image)"
                    )
                if mask.dtype.kind not in "iu":
                    raise ObservationsError(f"{where}: mask has dtype {mask.dtype}; instance ids must be integers")
                if mask.size and int(mask.min()) < 0:
                    raise ObservationsError(f"{where}: mask has negative ids; use 0 for background and 1..N")
                ids, counts = np.unique(mask, return_counts=True)
                for k, c in zip(ids.tolist(), counts.tolist(), strict=True):
                    seen.add(int(k))
                    pixels[int(k)] = pixels.get(int(k), 0) + int(c)
                    first.setdefault(int(k), i)
            if self._depth is not None:
                depth = self.depth(i)
                assert depth is not None
                where = self._where(i, "depth")
                if depth.shape != size:
                    raise ObservationsError(
                        f"{where}: depth has shape {list(depth.shape)}, expected [{self.height}, {self.width}]"
                    )
                if depth.dtype.kind not in "fiu":
                    raise ObservationsError(f"{where}: depth has dtype {depth.dtype}; depth must be numbers")
                finite = np.isfinite(depth)
                values = depth[finite & (depth != 0)]
                if self.depth_kind == "metric" and values.size and float(values.min()) < 0:
                    raise ObservationsError(
                        f"{where}: metric depth has negative values (min {float(values.min()):.3g}); depth is z along "
                        "the OpenCV optical axis, positive in front of the camera: flip its sign, write 0 where unknown"
                    )
                check.depth_pixels += int(depth.size)
                check.nonfinite_depth += int(depth.size - finite.sum())
                check.zero_depth += int((finite & (depth == 0)).sum())
                if values.size:
                    top = float(values.max())
                    at_top = values >= top * (1.0 - 1e-6)
                    below = values[~at_top]
                    tops.append((top, int(at_top.sum()), float(below.max()) if below.size else 0.0))
            if self._normals is not None:
                normal = self.normal(i)
                assert normal is not None
                where = self._where(i, "normal")
                if normal.shape != (*size, 3):
                    raise ObservationsError(
                        f"{where}: normals have shape {list(normal.shape)}, expected [{self.height}, {self.width}, 3]"
                    )
                if not np.all(np.isfinite(normal)):
                    raise ObservationsError(f"{where}: normals contain NaN or infinite values; write (0, 0, 0)")
                length = np.linalg.norm(normal, axis=-1)
                bad = (length > 1e-6) & (np.abs(length - 1.0) > 0.05)
                if np.any(bad):
                    raise ObservationsError(
                        f"{where}: {int(bad.sum())} normals are not unit length; normalise them (or (0, 0, 0) = none)"
                    )
        if self._masks is not None:
            self._check_instance_ids(seen - {0}, pixels, first)
        if tops and self.depth_kind == "metric":
            _find_far_plane(tops, check)


    def _check_instance_ids(self, seen: set[int], pixels: dict[int, int], first: dict[int, int]) -> None:
        where = self._where()
        if self.instance_names is not None:
            declared = set(self.instance_names) - {0}
            never = sorted(declared - seen)
            if never:
                names = [self.instance_names[i] for i in never[:5]]
                raise ObservationsError(
                    f"{where}: instance ids {never[:5]} ({', '.join(names)}) are declared but never appear in any "
                    "mask; remove them from the instance list or fix the masks"
                )
            unknown = sorted(seen - declared)
            if unknown:  # the rule (FORMAT.md): a declared instance list is complete; nothing is guessed
                k = unknown[0]
                more = f" (and ids {unknown[1:6]})" if len(unknown) > 1 else ""
                raise ObservationsError(
                    f"{self._where(first[k], 'mask')}: instance id {k}{more} is not in the capture's instance list "
                    f"({pixels[k]} pixels over the masks); add it to the instance list or set those mask pixels to "
                    "0 (background)"
                )
            return
        if seen:
            never = sorted(set(range(1, max(seen) + 1)) - seen)
            if never:
                raise ObservationsError(
                    f"{where}: instance ids {never[:5]} never appear in any mask (ids must be 1..{max(seen)} with "
                    "no gaps); renumber the masks"
                )


def _find_far_plane(tops: list[tuple[float, int, float]], check: CaptureCheck) -> None:
    """A far plane is one constant maximum depth shared by many pixels and standing well apart from every
    other depth value of the capture (renderers write it where a ray hit nothing; sensors where out of range)."""
    far = max(t[0] for t in tops)
    same = [t for t in tops if t[0] >= far * (1.0 - 1e-6)]
    count = sum(t[1] for t in same)
    deepest_other = max([t[2] for t in same] + [t[0] for t in tops if t[0] < far * (1.0 - 1e-6)])
    if count >= max(16, _FAR_PLANE_MIN_SHARE * check.depth_pixels) and deepest_other < _FAR_PLANE_GAP * far:
        check.far_plane_m = far
        check.far_plane_depth = count
