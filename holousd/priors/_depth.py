"""Depth for captures that have none: depth priors, found the way completion proposers are.

A capture from a camera without a depth sensor (a phone video, a photo sweep with structure-from-motion poses) has
colour, instance masks and camera poses only. The fit then carves each object from its masks alone (a visual
hull: every concavity and every side no silhouette shows comes out solid), and nothing tells it where the floor
is. A depth prior gives such a capture a depth channel before any stage reads it:

``stereo`` (built in, no weights)
    metric depth from the colour frames and the capture's poses by multi-view plane-sweep stereo
    (:mod:`holousd.geometry._stereo`): kept only where the frames agree (textured surfaces, object edges), 0
    elsewhere, so the fit treats it as a depth sensor with holes.
``learned`` (built in, needs weights)
    a monocular depth network the user saved (``torch.export.save`` or TorchScript), loaded from ``weights=PATH``;
    never downloaded. It takes a [1, 3, H, W] float RGB tensor in [0, 1] and returns [1, 1, H, W] (or [1, H, W],
    [H, W]) depth; ``output=inverse`` for a metric network that predicts inverse depth; ``kind=relative``
    (default: valid up to a scale and shift per frame, which the fit solves for) or ``kind=metric``.
``anchor=stereo`` (any relative prior)
    the prior's depth put on the ``stereo`` depth of the same frame (a scale and shift per frame,
    :class:`AnchoredDepthPrior`): dense metric depth, where stereo alone has it on textured pixels only.
plug-ins
    a factory registered under the entry-point group ``holousd.depth`` (``[project.entry-points."holousd.depth"]
    my_depth = "my_package:make_prior"``), called with the options the user gives; it returns an object with a
    ``name``, a ``kind`` ('metric' or 'relative') and ``estimate(obs, i) -> [H, W] float32`` (0 = no value).

:func:`with_depth_prior` returns the capture with the prior's depth as its depth channel (estimated once per frame,
the frames the fit reads up front with a progress bar, others when a stage asks).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from holousd._errors import HolousdError
from holousd.priors._api import group_entry_points, plugin_factory, plugin_names

if TYPE_CHECKING:
    from holousd.io import Observations

__all__ = [
    "DEPTH_ENTRY_POINT_GROUP",
    "AnchoredDepthPrior",
    "DepthPrior",
    "LearnedDepthPrior",
    "StereoDepthPrior",
    "available_depth_priors",
    "make_depth_prior",
    "with_depth_prior",
]

DEPTH_ENTRY_POINT_GROUP = "holousd.depth"
"""Entry-point group under which depth-prior plug-ins register a factory."""


@runtime_checkable
class DepthPrior(Protocol):
    """Depth for one frame of a capture: ``estimate(obs, i)`` returns [H, W] float32 z-depth (0 = no value),
    metres when ``kind`` is 'metric', up to an unknown scale and shift per frame when it is 'relative'."""

    name: str
    kind: str

    def estimate(self, obs: Observations, i: int) -> np.ndarray: ...


class StereoDepthPrior:
    """Metric depth by multi-view plane-sweep stereo (:mod:`holousd.geometry._stereo`); options are
    :class:`~holousd.geometry._stereo.StereoConfig` fields (``near``, ``far``, ``window``, ``min_ncc``, ...)."""

    name = "stereo"
    kind = "metric"

    def __init__(self, **options: Any) -> None:
        from holousd.geometry._stereo import StereoConfig

        known = {f.name: f.type for f in fields(StereoConfig)}
        unknown = sorted(set(options) - set(known))
        if unknown:
            raise HolousdError(f"depth prior 'stereo': unknown option {unknown[0]!r}; options: {', '.join(known)}")
        try:
            values = {k: (int(v) if known[k] == "int" else float(v)) for k, v in options.items()}
        except (TypeError, ValueError):
            raise HolousdError(f"depth prior 'stereo': options must be numbers, got {options}") from None
        self.config = StereoConfig(**values)
        c = self.config
        if c.window < 3 or c.window % 2 == 0:
            raise HolousdError(f"depth prior 'stereo': window {c.window} must be odd and at least 3")
        if not 0 < c.near < c.far:
            raise HolousdError(f"depth prior 'stereo': need 0 < near < far, got {c.near}, {c.far}")
        if not (3 <= c.min_planes <= c.max_planes and c.neighbours >= 1 and c.best_of in (1, 2) and c.max_side >= 16
                and c.step_px > 0 and c.chunk_pixels >= 1):  # fmt: skip
            raise HolousdError("depth prior 'stereo': need 3 <= min_planes <= max_planes, neighbours >= 1, best_of 1 "
                               "or 2, max_side >= 16, step_px > 0 and chunk_pixels >= 1")  # fmt: skip
        self._raw: dict[int, np.ndarray] = {}
        self._pool: list[int] | None = None
        self._neighbours: dict[int, list[int]] = {}
        self._obs: Observations | None = None
        self._scale = 1.0
        self._size = (0, 0)
        self._intrinsics: np.ndarray | None = None

    def prepare(self, obs: Observations, frames: Sequence[int], progress: bool = False) -> None:
        """Sweep ``frames`` (neighbours drawn from them) before any is asked for, with a progress bar."""
        self._bind(obs, frames)
        todo = [int(i) for i in frames if int(i) not in self._raw]
        bar = None
        if progress and todo:
            from tqdm import tqdm

            bar = tqdm(total=len(todo), desc="depth (stereo)", unit="frame", file=sys.stderr, leave=False)
        for i in todo:
            self._sweep(obs, i)
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()

    def _bind(self, obs: Observations, frames: Sequence[int] | None = None) -> None:
        if self._obs is not obs or (frames is not None and self._pool != [int(i) for i in frames]):
            self._obs = obs
            self._pool = [int(i) for i in frames] if frames is not None else list(range(len(obs)))
            self._raw.clear()
            self._neighbours.clear()
            longest = max(obs.width, obs.height)
            self._scale = min(1.0, self.config.max_side / longest)
            self._size = (max(1, round(obs.height * self._scale)), max(1, round(obs.width * self._scale)))
            k = np.array(obs.intrinsics, np.float64)
            if self._scale < 1.0:  # pixel centres at integers: u' = (u + 0.5) * s - 0.5
                sx, sy = self._size[1] / obs.width, self._size[0] / obs.height
                k[:, 0, 0] *= sx
                k[:, 1, 1] *= sy
                k[:, 0, 2] = (k[:, 0, 2] + 0.5) * sx - 0.5
                k[:, 1, 2] = (k[:, 1, 2] + 0.5) * sy - 0.5
            self._intrinsics = k

    def _small(self, image: np.ndarray, labels: bool = False) -> np.ndarray:
        """``image`` at the sweep's size: colour averaged over each new pixel's area, labels by nearest pixel."""
        h, w = self._size
        if (h, w) == image.shape[:2]:
            return image
        if labels:
            rows = np.minimum(((np.arange(h) + 0.5) * image.shape[0] / h).astype(int), image.shape[0] - 1)
            cols = np.minimum(((np.arange(w) + 0.5) * image.shape[1] / w).astype(int), image.shape[1] - 1)
            return image[np.ix_(rows, cols)]
        import torch
        import torch.nn.functional as F

        x = torch.from_numpy(np.ascontiguousarray(image[..., :3], dtype=np.float32)).permute(2, 0, 1)[None]
        return F.interpolate(x, size=(h, w), mode="area")[0].permute(1, 2, 0).numpy()

    def neighbours(self, obs: Observations, i: int) -> list[int]:
        """The frames frame ``i`` is swept against."""
        from holousd.geometry._stereo import stereo_neighbours

        self._bind(obs)
        if i not in self._neighbours:
            assert self._pool is not None
            pool = self._pool
            poses = np.concatenate([obs.poses[pool], obs.poses[i][None]])
            found = stereo_neighbours(poses, self.config, candidates=range(len(pool)))[-1]
            self._neighbours[i] = [pool[j] for j in found if pool[j] != i]
        return self._neighbours[i]

    def _sweep(self, obs: Observations, i: int) -> np.ndarray:
        from holousd.geometry._stereo import stereo_depth

        if i not in self._raw:
            near = self.neighbours(obs, i)
            images = {j: self._small(obs.rgb(j)) for j in [i, *near]}
            mask = obs.mask(i)
            labels = self._small(mask, labels=True) if mask is not None else None
            self._raw[i] = stereo_depth(i, images, self._intrinsics, obs.poses, near, self.config, labels).depth
        return self._raw[i]

    def estimate(self, obs: Observations, i: int) -> np.ndarray:
        """Frame ``i``'s depth, kept where at least ``min_agree`` of its neighbours' sweeps agree (at full size)."""
        from holousd.geometry._stereo import consistent

        self._bind(obs)
        near = self.neighbours(obs, i)
        depth = {i: self._sweep(obs, i)}
        for j in near:
            depth[j] = self._sweep(obs, j)
        kept = consistent(i, depth, self._intrinsics, obs.poses, near, self.config)
        if kept.shape == (obs.height, obs.width):
            return kept
        rows = np.minimum((np.arange(obs.height) * kept.shape[0] / obs.height).astype(int), kept.shape[0] - 1)
        cols = np.minimum((np.arange(obs.width) * kept.shape[1] / obs.width).astype(int), kept.shape[1] - 1)
        return kept[np.ix_(rows, cols)]


class LearnedDepthPrior:
    """A monocular depth network from ``weights`` (see the module docstring); never downloaded."""

    name = "learned"

    def __init__(self, weights: str | Path | None = None, device: str = "cpu", kind: str = "relative",
                 output: str = "depth") -> None:  # fmt: skip
        from holousd.priors._builtin import _load_model

        if weights is None:
            raise HolousdError("depth prior 'learned' needs weights=PATH (a saved depth network); holousd never "
                               "downloads a model")  # fmt: skip
        if kind not in ("relative", "metric"):
            raise HolousdError(f"depth prior 'learned': kind {kind!r}; choose 'relative' or 'metric'")
        if output not in ("depth", "inverse"):
            raise HolousdError(f"depth prior 'learned': output {output!r}; choose 'depth' or 'inverse'")
        if output == "inverse" and kind == "relative":
            raise HolousdError("depth prior 'learned': output=inverse needs kind=metric (a relative inverse depth "
                               "has its unknown shift on 1/depth, no scale and shift of depth undoes it)")  # fmt: skip
        path = Path(weights)
        if not path.is_file():
            raise HolousdError(f"{path}: no such weights file; give the saved depth network (torch.export.save)")
        self.weights = path
        self.model = _load_model(path, device)
        self.device = device
        self.kind = kind
        self.output = output

    def estimate(self, obs: Observations, i: int) -> np.ndarray:
        import torch

        rgb = obs.rgb(i)[..., :3]
        x = torch.from_numpy(np.ascontiguousarray(rgb, dtype=np.float32) / 255.0).permute(2, 0, 1)[None]
        with torch.no_grad():
            y = self.model(x.to(self.device))
        if isinstance(y, (tuple, list)):
            y = y[0]
        y = torch.as_tensor(y).detach().float().cpu()
        while y.dim() > 2 and y.shape[0] == 1:
            y = y[0]
        if tuple(y.shape) != (obs.height, obs.width):
            raise HolousdError(f"{self.weights}: the network returned shape {tuple(y.shape)} for a "
                               f"{obs.width}x{obs.height} frame; it must return [1, 1, H, W] depth")  # fmt: skip
        out = y.numpy().astype(np.float32)
        out = np.where(np.isfinite(out), out, 0.0)
        if self.output == "inverse":
            out = np.where(out > 1e-6, 1.0 / np.maximum(out, 1e-6), 0.0)
        return np.maximum(out, 0.0).astype(np.float32)


class AnchoredDepthPrior:
    """A relative prior made metric by the stereo depth of the same frame: per frame, the scale and shift that put
    the prior's depth on stereo's where both have one (least squares, then again on the 80% of those pixels that
    fit best), applied to every pixel. Dense metric depth where stereo alone has it on textured pixels only; a
    frame with fewer than ``min_pixels`` stereo pixels, or a fit with a non-positive scale, gets none."""

    kind = "metric"

    def __init__(self, inner: DepthPrior, stereo: StereoDepthPrior, min_pixels: int = 200) -> None:
        self.inner = inner
        self.stereo = stereo
        self.name = f"{inner.name}+stereo"
        self.min_pixels = int(min_pixels)

    def prepare(self, obs: Observations, frames: Sequence[int], progress: bool = False) -> None:
        self.stereo.prepare(obs, frames, progress)

    def estimate(self, obs: Observations, i: int) -> np.ndarray:
        relative = np.asarray(self.inner.estimate(obs, i), np.float64)
        metric = self.stereo.estimate(obs, i)
        sel = (metric > 0) & (relative > 0) & np.isfinite(relative)
        if np.count_nonzero(sel) < self.min_pixels:
            return np.zeros((obs.height, obs.width), np.float32)
        x, y = relative[sel], metric[sel].astype(np.float64)
        keep = np.ones(len(x), bool)
        for _ in range(2):
            a = np.stack([x[keep], np.ones(np.count_nonzero(keep))], 1)
            (scale, shift), *_ = np.linalg.lstsq(a, y[keep], rcond=None)
            residual = np.abs(scale * x + shift - y)
            keep = residual <= np.percentile(residual, 80)
        if scale <= 0:
            return np.zeros((obs.height, obs.width), np.float32)
        out = scale * relative + shift
        return np.where((relative > 0) & (out > 0), out, 0.0).astype(np.float32)


def _builtin() -> dict[str, Callable[..., Any]]:
    return {"stereo": StereoDepthPrior, "learned": LearnedDepthPrior}


def _entry_points() -> dict[str, Any]:
    return group_entry_points(DEPTH_ENTRY_POINT_GROUP)


def available_depth_priors() -> list[str]:
    """Names of the built-in depth priors, then the installed plug-ins'."""
    return plugin_names(_builtin(), _entry_points())


def make_depth_prior(name: str, **options: Any) -> DepthPrior:
    """The depth prior called ``name``: a built-in one, or a plug-in's factory called with ``options``.

    Raises:
        HolousdError: no prior has that name, the plug-in cannot be loaded, or it does not make a depth prior.
    """
    anchor = options.pop("anchor", None)
    if anchor not in (None, "none", "stereo"):
        raise HolousdError(f"depth prior {name!r}: anchor {anchor!r}; choose 'stereo' or 'none'")
    if anchor == "stereo":
        inner = make_depth_prior(name, **options)
        if inner.kind != "relative":
            raise HolousdError(f"depth prior {name!r}: anchor=stereo is for a relative prior; this one is "
                               f"{inner.kind}")  # fmt: skip
        return AnchoredDepthPrior(inner, StereoDepthPrior())
    factory = plugin_factory("depth prior", name, _builtin(), _entry_points(), DEPTH_ENTRY_POINT_GROUP)
    try:
        prior = factory(**options)
    except HolousdError:
        raise
    except TypeError as exc:
        raise HolousdError(f"depth prior {name!r}: bad options {sorted(options)} ({exc})") from None
    except Exception as exc:  # noqa: BLE001 - a plug-in's own failure: one line naming it
        raise HolousdError(f"depth prior {name!r}: its factory failed ({type(exc).__name__}: {exc})") from None
    if not isinstance(prior, DepthPrior) or getattr(prior, "kind", None) not in ("metric", "relative"):
        raise HolousdError(f"depth prior {name!r}: its factory returned {type(prior).__name__}, not a depth prior "
                           "(a name, a kind 'metric' or 'relative' and estimate(obs, i))")  # fmt: skip
    return prior


def with_depth_prior(obs: Observations, prior: DepthPrior, frames: Sequence[int] | None = None,
                     progress: bool = False) -> Observations:  # fmt: skip
    """``obs`` with ``prior``'s depth as its depth channel (and its kind; the capture's normals, if any, kept).
    ``frames`` are estimated now (the frames the fit reads), the rest when first read; each frame once."""
    from holousd.io._observations import LazyArray

    prepare = getattr(prior, "prepare", None)
    if frames is not None and callable(prepare):
        prepare(obs, list(frames), progress)
    cache: dict[int, np.ndarray] = {}

    def read(i: int) -> np.ndarray:
        if i not in cache:
            depth = np.asarray(prior.estimate(obs, i), dtype=np.float32)
            if depth.shape != (obs.height, obs.width):
                raise HolousdError(f"depth prior {prior.name!r}: frame {i} depth of shape {depth.shape}, expected "
                                   f"{(obs.height, obs.width)}")  # fmt: skip
            cache[i] = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
        return cache[i]

    if frames is not None and not callable(prepare) and progress:
        from tqdm import tqdm

        for i in tqdm(list(frames), desc=f"depth ({prior.name})", unit="frame", file=sys.stderr, leave=False):
            read(int(i))
    elif frames is not None:
        for i in frames:
            read(int(i))
    depth = [LazyArray((lambda i=i: read(i)), f"<depth prior {prior.name}: frame {obs.frame_ids[i]}>")
             for i in range(len(obs))]  # fmt: skip
    return obs.with_depth(depth, prior.kind, prior=prior.name)
