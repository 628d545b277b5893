"""Sensor models for ``holousd synth --sensor``: what a real capture does to the renderer's perfect frames.

A clean synth capture has exact metric depth and normals on every pixel, instance masks that match the geometry to
the pixel and exact camera poses. A real one has none of that. A :class:`SensorModel` turns each rendered frame
(and the camera path) into what a device and the usual capture software would give, channel by channel, every
random choice drawn from ``numpy.random.default_rng([seed, channel, frame])`` so that the same seed gives the same
capture:

depth (a time-of-flight / LiDAR depth map, as ARKit or a depth camera writes it)
    1. resolution: sampled on a grid ``depth_stride`` times coarser than the colour image and repeated
       (nearest), so edges are blocky and off by up to a pixel;
    2. edges: a pixel whose 3x3 neighbourhood spans a depth jump (more than ``edge_jump`` of its depth) mixes
       foreground and background returns; the device's filter removes most of them (depth 0) and lets
       ``flying_keep`` of them through at a random depth between the two (flying pixels);
    3. noise: Gaussian, sigma = ``noise_m + noise_rel * z + noise_quad * z^2`` per pixel, plus a smooth
       per-frame error field (multipath, calibration) of ``bias_rel`` of the depth;
    4. holes: isolated dropouts (``dropout``) and blobs (``hole_area`` of the image, dark or shiny surfaces);
    5. range: nothing nearer than ``min_range_m`` or farther than ``max_range_m`` (0 there);
    6. quantisation: ``quant_m`` steps at 1 m, growing with z^2 (disparity steps).
masks (a video segmenter, e.g. a SAM-style tracker)
    boundaries moved by a smooth random displacement of up to ``mask_boundary_px``; each object, per frame,
    grown or shrunk by a pixel with probability ``mask_grow_shrink``; small false fragments (``fragments`` per
    frame on average, blobs of 2-5 px radius labelled with an object of that frame); an object lost for a frame
    with probability ``mask_miss`` (its pixels read as room).
poses (a visual-inertial tracker)
    a random-walk drift (``drift_m``, ``drift_deg`` per frame, world frame, about the camera centre) plus
    per-frame jitter (``jitter_m``, ``jitter_deg``).
colour (a phone camera in video mode)
    motion blur along each pixel's true image motion to the next frame (``blur`` of it, at most 8 px);
    auto-exposure (a per-frame gain, random walk of ``exposure_step`` in log, within ``exposure_max``) and white
    balance (per-channel gains, random walk of ``wb_step``); shot and read noise (variance
    ``shot * I + read``, I in [0, 1]); 8-bit quantisation.
normals
    absent (``normals=False``): devices do not measure them.
no depth sensor
    ``has_depth=False``: no depth channel at all (a phone or camera video without LiDAR; ``video``).

The capture's ground truth (``gt/``) stays exact; ``gt/graph.json`` records the sensor's parameters and
``gt/cameras.json`` the true camera poses, so that pose errors can be measured.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy import ndimage

from holousd.geometry._poses import rotation_matrix as _rotation

__all__ = ["SENSORS", "SensorModel", "sensor_model"]


@dataclass(frozen=True, kw_only=True)
class SensorModel:
    """A seeded model of a capture device's defects (see the module docstring for what each field does)."""

    name: str
    """Name of the model ('clean', 'phone', 'lidar' or a user's)."""
    # depth
    depth_stride: int = 1
    edge_jump: float = 0.04
    flying_keep: float = 0.0
    noise_m: float = 0.0
    noise_rel: float = 0.0
    noise_quad: float = 0.0
    bias_rel: float = 0.0
    dropout: float = 0.0
    hole_area: float = 0.0
    min_range_m: float = 0.0
    max_range_m: float = float("inf")
    quant_m: float = 0.0
    # masks
    mask_boundary_px: float = 0.0
    mask_grow_shrink: float = 0.0
    fragments: float = 0.0
    mask_miss: float = 0.0
    # poses
    drift_m: float = 0.0
    drift_deg: float = 0.0
    jitter_m: float = 0.0
    jitter_deg: float = 0.0
    # colour
    blur: float = 0.0
    exposure_step: float = 0.0
    exposure_max: float = 0.0
    wb_step: float = 0.0
    shot: float = 0.0
    read: float = 0.0
    # channels the device gives at all
    normals: bool = True
    has_depth: bool = True

    @property
    def clean(self) -> bool:
        """Whether the model changes nothing (the renderer's exact frames)."""
        return self == SensorModel(name=self.name)

    def to_dict(self) -> dict:
        """The parameters, for ``gt/graph.json``."""
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in asdict(self).items()}

    # ---- poses -------------------------------------------------------------------------------------------------

    def poses(self, poses: np.ndarray, seed: int) -> np.ndarray:
        """The tracker's [F, 4, 4] camera-to-world poses for the true ``poses`` (OpenCV cameras)."""
        out = np.array(poses, dtype=np.float64, copy=True)
        if not (self.drift_m or self.drift_deg or self.jitter_m or self.jitter_deg):
            return out
        rng = np.random.default_rng([seed, 31])
        n = len(out)
        drift_t = np.cumsum(rng.normal(0.0, self.drift_m, (n, 3)), axis=0)
        drift_r = np.cumsum(rng.normal(0.0, np.radians(self.drift_deg), (n, 3)), axis=0)
        jit_t = rng.normal(0.0, self.jitter_m, (n, 3))
        jit_r = rng.normal(0.0, np.radians(self.jitter_deg), (n, 3))
        for i in range(n):
            rot = _rotation(drift_r[i] + jit_r[i])
            out[i, :3, :3] = rot @ out[i, :3, :3]
            out[i, :3, 3] += drift_t[i] + jit_t[i]
        return out

    # ---- depth -------------------------------------------------------------------------------------------------

    def depth(self, depth: np.ndarray, seed: int, frame: int) -> np.ndarray:
        """The device's [H, W] float32 depth (0 = no value) for the true z-depth of one frame."""
        z = np.asarray(depth, dtype=np.float64)
        if self.clean:
            return z.astype(np.float32)
        rng = np.random.default_rng([seed, 37, frame])
        h, w = z.shape
        valid = z > 0
        if self.depth_stride > 1:
            s = self.depth_stride
            coarse = z[s // 2 :: s, s // 2 :: s]
            z = np.repeat(np.repeat(coarse, s, axis=0), s, axis=1)
            z = np.pad(z, ((0, max(0, h - z.shape[0])), (0, max(0, w - z.shape[1]))), mode="edge")[:h, :w]
            valid = z > 0
        big = np.where(valid, z, np.inf)
        lo = ndimage.minimum_filter(big, size=3, mode="nearest")
        hi = ndimage.maximum_filter(np.where(valid, z, 0.0), size=3, mode="nearest")
        edge = valid & (np.isfinite(lo)) & ((hi - lo) > self.edge_jump * np.maximum(z, 1e-6))
        out = z.copy()
        if np.any(edge):
            keep = rng.random(edge.shape) < self.flying_keep
            t = rng.random(edge.shape)
            flying = np.where(np.isfinite(lo), lo, 0.0) * (1 - t) + hi * t
            out = np.where(edge & keep, flying, out)
            out = np.where(edge & ~keep, 0.0, out)
        sigma = self.noise_m + self.noise_rel * out + self.noise_quad * out**2
        out = out + rng.normal(0.0, 1.0, out.shape) * sigma
        if self.bias_rel:
            out = out * (1.0 + self.bias_rel * _smooth_field(rng, (h, w), 0.15 * max(h, w)))
        if self.dropout:
            out[rng.random(out.shape) < self.dropout] = 0.0
        if self.hole_area:
            field = _smooth_field(rng, (h, w), 0.03 * max(h, w))
            out[field > np.quantile(field, 1.0 - self.hole_area)] = 0.0
        out[(out < self.min_range_m) | (out > self.max_range_m) | ~valid] = 0.0
        if self.quant_m:
            step = self.quant_m * np.maximum(out, 1e-6) ** 2
            out = np.where(out > 0, np.round(out / step) * step, 0.0)
        return out.astype(np.float32)

    # ---- masks -------------------------------------------------------------------------------------------------

    def mask(self, mask: np.ndarray, seed: int, frame: int) -> np.ndarray:
        """The segmenter's [H, W] int32 instance mask for the true one of one frame."""
        m = np.asarray(mask, dtype=np.int32)
        if self.clean:
            return m.copy()
        rng = np.random.default_rng([seed, 41, frame])
        h, w = m.shape
        out = m
        if self.mask_boundary_px:
            dx = _smooth_field(rng, (h, w), 0.05 * max(h, w))
            dy = _smooth_field(rng, (h, w), 0.05 * max(h, w))
            scale = self.mask_boundary_px / max(float(np.abs(dx).max()), float(np.abs(dy).max()), 1e-9)
            v, u = np.mgrid[0:h, 0:w]
            uu = np.clip(np.rint(u + dx * scale), 0, w - 1).astype(np.int64)
            vv = np.clip(np.rint(v + dy * scale), 0, h - 1).astype(np.int64)
            out = out[vv, uu]
        ids = [int(i) for i in np.unique(out) if i != 0]
        out = out.copy()
        for i in ids:
            r = rng.random()
            if r < self.mask_grow_shrink / 2:
                grown = ndimage.binary_dilation(out == i)
                out[grown] = i
            elif r < self.mask_grow_shrink:
                own = out == i
                lost = own & ~ndimage.binary_erosion(own)
                out[lost] = _nearest_other(out, lost, i)
        for i in ids:
            if rng.random() < self.mask_miss:
                out[out == i] = 0
        if ids and self.fragments:
            v, u = np.mgrid[0:h, 0:w]
            for _ in range(rng.poisson(self.fragments)):
                r = rng.uniform(2.0, 5.0)
                cu, cv = rng.uniform(0, w), rng.uniform(0, h)
                out[(u - cu) ** 2 + (v - cv) ** 2 <= r * r] = ids[int(rng.integers(len(ids)))]
        return out

    # ---- colour ------------------------------------------------------------------------------------------------

    def exposures(self, frames: int, seed: int) -> np.ndarray:
        """[F, 3] per-frame, per-channel gains (auto-exposure times white balance)."""
        rng = np.random.default_rng([seed, 43])
        log_gain = np.clip(np.cumsum(rng.normal(0.0, self.exposure_step, frames)), -self.exposure_max,
                           self.exposure_max)  # fmt: skip
        wb = np.cumsum(rng.normal(0.0, self.wb_step, (frames, 3)), axis=0)
        wb -= wb.mean(axis=1, keepdims=True)  # white balance keeps the brightness
        return np.exp(log_gain[:, None] + np.clip(wb, -0.1, 0.1))

    def rgb(self, rgb: np.ndarray, flow: np.ndarray | None, gain: np.ndarray, seed: int, frame: int) -> np.ndarray:
        """The camera's [H, W, 3] uint8 colour for one rendered frame.

        Args:
            rgb: [H, W, 3] uint8 rendered colour.
            flow: [H, W, 2] image motion (du, dv) of each pixel to the next frame, pixels, or None.
            gain: [3] this frame's gains (see :meth:`exposures`).
            seed: Capture seed.
            frame: Frame index.
        """
        if self.clean:
            return np.asarray(rgb, dtype=np.uint8).copy()
        rng = np.random.default_rng([seed, 47, frame])
        img = np.asarray(rgb, dtype=np.float64) / 255.0
        h, w = img.shape[:2]
        if self.blur and flow is not None:
            step = flow * self.blur
            length = np.linalg.norm(step, axis=-1, keepdims=True)
            step = np.where(length > 8.0, step * 8.0 / np.maximum(length, 1e-9), step)
            v, u = np.mgrid[0:h, 0:w].astype(np.float64)
            acc = np.zeros_like(img)
            taps = np.linspace(-0.5, 0.5, 7)
            for t in taps:
                uu = np.clip(np.rint(u + t * step[..., 0]), 0, w - 1).astype(np.int64)
                vv = np.clip(np.rint(v + t * step[..., 1]), 0, h - 1).astype(np.int64)
                acc += img[vv, uu]
            img = acc / len(taps)
        img = img * np.asarray(gain, dtype=np.float64)[None, None, :]
        if self.shot or self.read:
            sd = np.sqrt(self.shot * np.clip(img, 0.0, None) + self.read)
            img = img + rng.normal(0.0, 1.0, img.shape) * sd
        return np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)


def _smooth_field(rng: np.random.Generator, shape: tuple[int, int], sigma: float) -> np.ndarray:
    """A smooth random field of unit standard deviation (white noise blurred by a Gaussian of ``sigma`` px)."""
    field = ndimage.gaussian_filter(rng.normal(0.0, 1.0, shape), sigma=max(sigma, 0.5), mode="reflect")
    return field / max(float(field.std()), 1e-12)


def _nearest_other(mask: np.ndarray, where: np.ndarray, own: int) -> np.ndarray:
    """For the pixels ``where``, the label of the nearest pixel not labelled ``own``."""
    other = mask != own
    if not np.any(other):
        return np.zeros(int(where.sum()), dtype=mask.dtype)
    _, (iv, iu) = ndimage.distance_transform_edt(~other, return_indices=True)
    return mask[iv[where], iu[where]]


SENSORS: dict[str, SensorModel] = {
    "clean": SensorModel(name="clean"),
    # A phone with a LiDAR depth sensor (ARKit-style): a coarse, noisy depth map, a video segmenter, a VIO tracker.
    "phone": SensorModel(
        name="phone",
        depth_stride=2, edge_jump=0.04, flying_keep=0.15,
        noise_m=0.002, noise_rel=0.004, noise_quad=0.002, bias_rel=0.003,
        dropout=0.02, hole_area=0.03, min_range_m=0.15, max_range_m=5.0, quant_m=0.001,
        mask_boundary_px=2.0, mask_grow_shrink=0.3, fragments=0.3, mask_miss=0.02,
        drift_m=0.0005, drift_deg=0.03, jitter_m=0.0015, jitter_deg=0.1,
        blur=0.05, exposure_step=0.04, exposure_max=0.35, wb_step=0.01, shot=0.0004, read=2e-5,
        normals=False,
    ),  # fmt: skip
    # A depth camera (time of flight) on a tracked rig: full-resolution, less noisy depth, better poses.
    "lidar": SensorModel(
        name="lidar",
        depth_stride=1, edge_jump=0.04, flying_keep=0.05,
        noise_m=0.001, noise_rel=0.0015, noise_quad=0.0, bias_rel=0.001,
        dropout=0.01, hole_area=0.01, min_range_m=0.25, max_range_m=8.0, quant_m=0.0005,
        mask_boundary_px=1.0, mask_grow_shrink=0.2, fragments=0.2, mask_miss=0.01,
        drift_m=0.0002, drift_deg=0.01, jitter_m=0.0005, jitter_deg=0.03,
        blur=0.02, exposure_step=0.02, exposure_max=0.2, wb_step=0.005, shot=0.0002, read=1e-5,
        normals=False,
    ),  # fmt: skip
}
"""The built-in sensor models, by name."""
# The lidar's depth camera with poses from structure from motion or a tracker that lost track now and then: each
# frame off by about a centimetre and a degree (depth better than poses: what s1_fit's pose alignment is for).
SENSORS["sfm"] = replace(SENSORS["lidar"], name="sfm", drift_m=0.002, drift_deg=0.12, jitter_m=0.006, jitter_deg=0.4)
# A phone video without a depth sensor: the phone's colour, segmenter masks and tracker poses, no depth at all (what
# s1_fit's depth priors are for: multi-view stereo from the colour frames, or a monocular network).
SENSORS["video"] = replace(SENSORS["phone"], name="video", has_depth=False)


def sensor_model(name: str) -> SensorModel:
    """The built-in :class:`SensorModel` called ``name`` (a :class:`HolousdError` naming the choices otherwise)."""
    if name not in SENSORS:
        from holousd._errors import HolousdError

        raise HolousdError(f"unknown sensor {name!r}; choose one of {', '.join(SENSORS)}")
    return SENSORS[name]
