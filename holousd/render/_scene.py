"""Rendering a holousd scene's splats: every node's splats placed by its (possibly animated) pose."""

from __future__ import annotations

import os
import time as _time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from holousd._errors import InvalidDataError, SceneError
from holousd.render._binding import SH_C0, splats_in_world
from holousd.render._camera import Camera, look_at, orbit_cameras
from holousd.render._rasterize import RasterConfig, RenderResult, covariances_from_rotations, rasterize
from holousd.usd import SceneGraph

if TYPE_CHECKING:
    import torch

__all__ = [
    "SceneRenderer",
    "VideoResult",
    "observed_cameras",
    "render_video",
    "scene_orbit",
    "sh_to_rgb",
    "time_codes",
    "write_mp4",
    "write_png",
]

_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
       1.445305721320277, -0.5900435899266435)  # fmt: skip


def sh_to_rgb(sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Evaluate real SH radiance of degree <= 3: [N, K, 3] coefficients, [N, 3] unit view directions -> [N, 3].

    colour = 0.5 + sum_k Y_k(dir) c_k, clamped at 0 (the 3DGS convention; directions point from the camera to
    the splat, in the frame the coefficients are expressed in).
    """
    k = sh.shape[1]
    out = SH_C0 * sh[:, 0]
    if k >= 4:
        x, y, z = dirs[:, 0:1], dirs[:, 1:2], dirs[:, 2:3]
        out = out - _C1 * y * sh[:, 1] + _C1 * z * sh[:, 2] - _C1 * x * sh[:, 3]
        if k >= 9:
            xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
            out = (out + _C2[0] * xy * sh[:, 4] + _C2[1] * yz * sh[:, 5] + _C2[2] * (2 * zz - xx - yy) * sh[:, 6]
                   + _C2[3] * xz * sh[:, 7] + _C2[4] * (xx - yy) * sh[:, 8])  # fmt: skip
            if k >= 16:
                out = (out + _C3[0] * y * (3 * xx - yy) * sh[:, 9] + _C3[1] * xy * z * sh[:, 10]
                       + _C3[2] * y * (4 * zz - xx - yy) * sh[:, 11]
                       + _C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh[:, 12]
                       + _C3[4] * x * (4 * zz - xx - yy) * sh[:, 13] + _C3[5] * z * (xx - yy) * sh[:, 14]
                       + _C3[6] * x * (xx - 3 * yy) * sh[:, 15])  # fmt: skip
    return (out + 0.5).clamp_min(0.0)


@dataclass
class _NodeSplats:
    name: str
    centre: torch.Tensor  # [N, 3] object coordinates
    rot: torch.Tensor  # [N, 3, 3] object coordinates
    scales: torch.Tensor  # [N, 3]
    opacity: torch.Tensor  # [N]
    sh: torch.Tensor  # [N, K, 3]


class SceneRenderer:
    """Renders a scene's splats from any camera at any time code.

    Splats are loaded once (bound splats are re-derived from their node's mesh, so mesh edits show); at each
    render every node's pose is read at the requested time (edit layers and simulation layers apply).

    Args:
        scene: The scene.
        nodes: Node names to render (default: every node with splats).
        config: Rasteriser settings.
        background: RGB behind the splats.
        device: Torch device.
    """

    def __init__(
        self,
        scene: SceneGraph,
        *,
        nodes: list[str] | None = None,
        config: RasterConfig | None = None,
        background: tuple[float, float, float] = (1.0, 1.0, 1.0),
        device: str = "cpu",
    ) -> None:
        import torch

        from holousd.usd import Pose

        self.scene = scene
        self.config = config or RasterConfig()
        self.device = device
        self.background = torch.as_tensor(background, dtype=torch.float32, device=device)
        names = nodes if nodes is not None else [n.name for n in scene.nodes()]
        self._nodes: list[_NodeSplats] = []
        for name in names:
            try:
                splats = scene.get_gaussians(name)
            except SceneError:
                if nodes is not None:
                    raise
                continue
            mesh = None
            if splats.bound:
                try:
                    mesh = scene.get_mesh(name)
                except SceneError:
                    mesh = None  # fall back to the stored object-space splats
            centre, rot, scales = splats_in_world(splats, Pose(), mesh)
            t = lambda x: torch.tensor(np.array(x), dtype=torch.float32, device=device)  # noqa: E731
            self._nodes.append(
                _NodeSplats(name, t(centre), t(rot), t(scales), t(splats.opacities), t(splats.sh_coeffs))
            )
        if not self._nodes:
            raise SceneError(
                f"{scene.path or '<in-memory scene>'}: no node has Gaussian splats to render; "
                "fit appearance first (holousd.stages.appearance.run)"
            )

    @property
    def splat_count(self) -> int:
        """Total number of splats rendered."""
        return sum(len(n.opacity) for n in self._nodes)

    @property
    def node_names(self) -> list[str]:
        """Nodes that have splats."""
        return [n.name for n in self._nodes]

    def world_gaussians(self, camera: Camera, time: float | None = None) -> tuple[torch.Tensor, ...]:
        """World means [N, 3], covariances [N, 3, 3], opacities [N], colours [N, 3] at ``time``."""
        import torch

        parts = []
        cam_centre = torch.as_tensor(camera.center, dtype=torch.float32, device=self.device)
        for node in self._nodes:
            pose = self.scene.get_pose(node.name, time=time)
            rot = torch.as_tensor(pose.rotation_matrix(), dtype=torch.float32, device=self.device)
            trans = torch.as_tensor(pose.translation, dtype=torch.float32, device=self.device)
            means = node.centre @ rot.T + trans
            covs = covariances_from_rotations(rot @ node.rot, node.scales)
            if node.sh.shape[1] > 1:  # view directions in the node's frame
                dirs = (means - cam_centre) @ rot
                dirs = dirs / dirs.norm(dim=1, keepdim=True).clamp_min(1e-12)
            else:
                dirs = means
            parts.append((means, covs, node.opacity, sh_to_rgb(node.sh, dirs)))
        return tuple(torch.cat([p[i] for p in parts]) for i in range(4))

    def render(self, camera: Camera, time: float | None = None) -> RenderResult:
        """Render the scene from ``camera`` at time code ``time`` (None: default time)."""
        import torch

        with torch.no_grad():
            means, covs, opac, colors = self.world_gaussians(camera, time)
            return rasterize(means, covs, opac, colors, camera, self.config, background=self.background)


def to_uint8(image: torch.Tensor | np.ndarray) -> np.ndarray:
    """[H, W, C] float image in [0, 1] -> uint8."""
    arr = image.detach().cpu().numpy() if hasattr(image, "detach") else np.asarray(image)
    return (np.clip(arr, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_png(path: str | os.PathLike[str], image: np.ndarray) -> Path:
    """Write an [H, W, 3] float or uint8 image as PNG, atomically."""
    from PIL import Image

    from holousd._atomic import atomic_path

    arr = image if np.asarray(image).dtype == np.uint8 else to_uint8(image)
    with atomic_path(path) as tmp:
        Image.fromarray(np.asarray(arr)).save(tmp, format="PNG")
    return Path(path)


def write_mp4(path: str | os.PathLike[str], frames: list[np.ndarray], *, fps: int = 24) -> Path:
    """Encode uint8 [H, W, 3] frames as H.264 (libx264) or, when the PyAV wheel lacks it, MPEG-4 Part 2."""
    import av

    from holousd._atomic import atomic_path

    if not frames:
        raise InvalidDataError("write_mp4: no frames")
    codec = next((c for c in ("libx264", "h264", "mpeg4") if c in av.codecs_available), None)
    if codec is None:
        raise InvalidDataError("write_mp4: this PyAV build has no H.264 or MPEG-4 encoder; pip install -U av")
    h, w = frames[0].shape[:2]
    h2, w2 = h + h % 2, w + w % 2  # yuv420p needs even sizes
    with atomic_path(path) as tmp:
        with av.open(str(tmp), mode="w", format="mp4") as container:
            stream = container.add_stream(codec, rate=fps)
            stream.width, stream.height, stream.pix_fmt = w2, h2, "yuv420p"
            if codec != "mpeg4":
                stream.options = {"crf": "18"}
            else:
                stream.bit_rate = 4_000_000
            for frame in frames:
                padded = np.pad(frame, ((0, h2 - h), (0, w2 - w), (0, 0)), mode="edge")
                for packet in stream.encode(av.VideoFrame.from_ndarray(padded, format="rgb24")):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)
    return Path(path)


def _object_bounds(scene: SceneGraph) -> np.ndarray:
    pts = []
    for name in scene.objects() or [n.name for n in scene.nodes()]:
        try:
            mesh = scene.get_mesh(name)
        except SceneError:
            continue
        lo, hi = mesh.bounds
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        pts.append(scene.get_pose(name).apply(corners))
    if not pts:
        raise SceneError(f"{scene.path or '<in-memory scene>'}: no meshes to frame an orbit around")
    allp = np.concatenate(pts)
    return np.stack([allp.min(0), allp.max(0)])


def scene_orbit(
    scene: SceneGraph, count: int, *, width: int = 256, height: int = 256, fov_deg: float = 60.0,
    distance_factor: float = 2.2, elevation: float = 0.6, start_deg: float = -90.0,
) -> list[Camera]:  # fmt: skip
    """An orbit around the scene's objects (looking at their bounding-box centre), kept inside the room.

    Args:
        scene: The scene.
        count: Number of cameras.
        width: Image width, pixels.
        height: Image height, pixels.
        fov_deg: Horizontal field of view, degrees.
        distance_factor: Orbit radius as a multiple of the objects' horizontal bounding radius.
        elevation: Camera height above the centre as a fraction of the radius.
        start_deg: Azimuth of the first camera, degrees (-90: looking along +y).
    """
    box = _object_bounds(scene)
    centre = box.mean(0)
    radius = max(distance_factor * 0.5 * float(np.linalg.norm(box[1, :2] - box[0, :2])), 0.3)
    cams = orbit_cameras(centre, radius, elevation * radius, count, width=width, image_height=height,
                         fov_deg=fov_deg, start_deg=start_deg)  # fmt: skip
    try:  # keep cameras inside the background's bounds (a room seen from inside)
        bg = scene.get_mesh("background")
        lo, hi = scene.get_pose("background").apply(bg.bounds) if bg.points.size else (None, None)
    except (SceneError, InvalidDataError):
        lo = hi = None
    if lo is not None:
        margin = 0.15
        for cam in cams:
            eye = np.clip(cam.center, np.minimum(lo, hi) + margin, np.maximum(lo, hi) - margin)
            cam.cam_to_world = look_at(eye, centre)
    return cams


def observed_cameras(scene: SceneGraph, *, width: int | None = None, height: int | None = None) -> list[Camera]:
    """Cameras from the UsdGeom.Camera prims under /World/Cameras (one per prim, or per time sample).

    USD cameras look down -Z with +Y up; they are converted to the OpenCV convention. Intrinsics come from focal
    length, apertures and aperture offsets; the image size defaults to 256 pixels wide with the aperture's aspect.
    """
    from pxr import Usd, UsdGeom

    root = scene.stage.GetPrimAtPath("/World/Cameras")
    prims = [p for p in Usd.PrimRange(root) if p.IsA(UsdGeom.Camera)] if root else []
    if not prims:
        raise SceneError(
            f"{scene.path or '<in-memory scene>'}: no UsdGeom.Camera prims under /World/Cameras; "
            "use --cameras orbit, or add the observation cameras (stage s0_observe writes them)"
        )
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    cams = []
    for prim in prims:
        usd_cam = UsdGeom.Camera(prim)
        samples = UsdGeom.Xformable(prim).GetTimeSamples() or [None]
        for t in samples:
            code = Usd.TimeCode.Default() if t is None else Usd.TimeCode(t)
            gf = usd_cam.GetCamera(code)
            h_ap, v_ap = gf.horizontalAperture, gf.verticalAperture
            w = width or 256
            h = height or max(int(round(w * v_ap / h_ap)), 1)
            m = np.array(gf.transform).T  # Gf matrices are row-vector: transpose to column convention
            fx, fy = gf.focalLength / h_ap * w, gf.focalLength / v_ap * h
            cx = w / 2 + gf.horizontalApertureOffset / h_ap * w
            cy = h / 2 - gf.verticalApertureOffset / v_ap * h
            cams.append(Camera(fx=fx, fy=fy, cx=cx, cy=cy, width=w, height=h, cam_to_world=m @ flip))
    return cams


def time_codes(scene: SceneGraph, count: int) -> list[float | None]:
    """Time code of each of ``count`` frames: start + i within the stage's authored time range, else None."""
    stage = scene.stage
    if not stage.HasAuthoredTimeCodeRange():
        return [None] * count
    start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
    return [float(min(start + i, end)) for i in range(count)]


@dataclass(kw_only=True)
class VideoResult:
    """What :func:`render_video` wrote."""

    pngs: list[Path] = field(default_factory=list)
    """One PNG per frame."""
    mp4: Path | None = None
    """The video (None for a single frame)."""
    splats: int = 0
    """Splats rendered per frame."""
    seconds_per_frame: float = 0.0
    """Mean rasterisation wall time per frame, seconds."""


def render_video(
    scene: SceneGraph,
    out_dir: str | os.PathLike[str],
    *,
    cameras: str = "orbit",
    frames: int = 48,
    width: int = 256,
    height: int = 256,
    fps: int = 24,
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
    progress: bool = True,
) -> VideoResult:
    """Render frames of ``scene`` to ``out_dir/frame_XXXX.png`` and ``out_dir/render.mp4``.

    Frame i is rendered at time code i of the stage's time range (so simulated trajectories play back).

    Args:
        scene: The scene (its edit and simulation layers included).
        out_dir: Output folder.
        cameras: 'orbit' (around the objects) or 'observed' (the /World/Cameras prims, cycled if fewer).
        frames: Number of frames.
        width: Image width, pixels.
        height: Image height, pixels (observed cameras keep their aspect if only the width is meaningful).
        fps: Video frame rate.
        background: RGB behind the splats.
        progress: Show a progress bar on stderr.
    """
    if frames < 1:
        raise InvalidDataError(f"render: --frames must be >= 1, got {frames}")
    if cameras == "orbit":
        cams = scene_orbit(scene, frames, width=width, height=height)
    elif cameras == "observed":
        observed = observed_cameras(scene, width=width, height=height)
        cams = [observed[i % len(observed)] for i in range(frames)]
    else:
        raise InvalidDataError(f"render: --cameras must be 'orbit' or 'observed', got {cameras!r}")
    renderer = SceneRenderer(scene, background=background)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    result = VideoResult(splats=renderer.splat_count)
    images = []
    from tqdm import tqdm

    elapsed = 0.0
    for i, (cam, t) in enumerate(
        tqdm(list(zip(cams, time_codes(scene, frames), strict=True)), desc="render", unit="frame", disable=not progress)
    ):
        started = _time.perf_counter()
        image = to_uint8(renderer.render(cam, t).color)
        elapsed += _time.perf_counter() - started
        images.append(image)
        result.pngs.append(write_png(out_dir / f"frame_{i:04d}.png", image))
    result.seconds_per_frame = elapsed / frames
    if frames > 1:
        result.mp4 = write_mp4(out_dir / "render.mp4", images, fps=fps)
    return result
