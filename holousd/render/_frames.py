"""Observed frames for appearance fitting, and an adapter from other frame containers."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from holousd._errors import InvalidDataError
from holousd.render._camera import Camera

__all__ = ["Frame", "as_frames"]


@dataclass(kw_only=True)
class Frame:
    """One observed image with its camera."""

    image: np.ndarray
    """[H, W, 3] float RGB in [0, 1]."""
    camera: Camera
    """The camera that took it (OpenCV convention, same H, W)."""
    mask: np.ndarray | None = None
    """Optional [H, W] mask: bool / float foreground, or integer instance ids (0 = none)."""

    def __post_init__(self) -> None:
        image = np.asarray(self.image)
        if image.dtype == np.uint8:
            image = image.astype(np.float32) / 255.0
        image = np.asarray(image, dtype=np.float32)
        if image.ndim != 3 or image.shape[2] != 3:
            raise InvalidDataError(f"Frame.image must be [H, W, 3], got {list(image.shape)}")
        if not np.all(np.isfinite(image)):
            raise InvalidDataError("Frame.image contains NaN or infinite values")
        if (image.shape[0], image.shape[1]) != (self.camera.height, self.camera.width):
            raise InvalidDataError(
                f"Frame.image is {image.shape[1]}x{image.shape[0]} but its camera is "
                f"{self.camera.width}x{self.camera.height}"
            )
        self.image = image
        if self.mask is not None:
            mask = np.asarray(self.mask)
            if mask.shape != image.shape[:2]:
                raise InvalidDataError(
                    f"Frame.mask must be [{image.shape[0]}, {image.shape[1]}], got {list(mask.shape)}"
                )
            self.mask = mask

    @property
    def instance_mask(self) -> bool:
        """True when the mask holds integer instance ids rather than a foreground mask."""
        return self.mask is not None and self.mask.dtype.kind in "iu"


def _field(obj: object, names: tuple[str, ...]) -> object | None:
    for name in names:
        value = getattr(obj, name, None)
        if value is not None:
            return value() if callable(value) else value
    return None


def as_frames(frames: object) -> list[Frame]:
    """Turn supported frame containers into a list of :class:`Frame`.

    Accepted:
        - a sequence of :class:`Frame`;
        - a sequence of tuples ``(image [H, W, 3], K [3, 3], cam_to_world [4, 4])`` or with a fourth item, the
          mask ``[H, W]`` (or None);
        - any object (e.g. ``holousd.io.Observations``) with attributes or no-argument methods
          ``images`` (or ``frames``/``rgb``): [F, H, W, 3] array or sequence of images (uint8 or float in [0, 1]);
          ``intrinsics`` (or ``K``): [F, 3, 3] or one shared [3, 3];
          ``cam_to_world`` (or ``poses``/``c2w``): [F, 4, 4] OpenCV camera-to-world;
          optional ``masks`` (or ``instance_masks``): [F, H, W] or None.
    """
    if isinstance(frames, Sequence) and not isinstance(frames, str | bytes):
        out = []
        for i, item in enumerate(frames):
            if isinstance(item, Frame):
                out.append(item)
                continue
            if not isinstance(item, tuple | list) or len(item) not in (3, 4):
                raise InvalidDataError(
                    f"frame {i}: expected a Frame or a tuple (image, K, cam_to_world[, mask]), "
                    f"got {type(item).__name__}"
                )
            image = np.asarray(item[0])
            if image.ndim != 3:
                raise InvalidDataError(f"frame {i}: image must be [H, W, 3], got {list(image.shape)}")
            camera = Camera.from_intrinsics(item[1], item[2], width=image.shape[1], height=image.shape[0])
            out.append(Frame(image=image, camera=camera, mask=item[3] if len(item) == 4 else None))
        if not out:
            raise InvalidDataError("no frames given: appearance fitting needs at least one observed image")
        return out
    images = _field(frames, ("images", "frames", "rgb"))
    intrinsics = _field(frames, ("intrinsics", "K"))
    poses = _field(frames, ("cam_to_world", "poses", "c2w"))
    if images is None or intrinsics is None or poses is None:
        raise InvalidDataError(
            f"{type(frames).__name__}: not a frame container; give a list of (image, K, cam_to_world[, mask]) "
            "or an object with images, intrinsics and cam_to_world (or poses)"
        )
    masks = _field(frames, ("masks", "instance_masks"))
    count = len(images)
    intrinsics = np.asarray(intrinsics, dtype=np.float64)
    if intrinsics.shape == (3, 3):
        intrinsics = np.broadcast_to(intrinsics, (count, 3, 3))
    poses = np.asarray(poses, dtype=np.float64)
    if len(intrinsics) != count or len(poses) != count or (masks is not None and len(masks) != count):
        raise InvalidDataError(
            f"{type(frames).__name__}: {count} images but {len(intrinsics)} intrinsics, {len(poses)} poses"
            + (f", {len(masks)} masks" if masks is not None else "")
        )
    return as_frames([(images[i], intrinsics[i], poses[i], None if masks is None else masks[i]) for i in range(count)])
