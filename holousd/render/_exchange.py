"""Gaussian-splat exchange: a scene's splats as standard 3DGS ``.ply`` files, in the world frame.

Most tools of the splat world (3DGS viewers, SuperSplat, nerfstudio, gsplat, Blender add-ons) read the layout of
the original 3D Gaussian Splatting code rather than UsdVol particle fields. One binary little-endian PLY per node
(``<node>.ply``) and one for the whole scene (``scene.ply``), every vertex a splat with float32 properties, in
this order:

- ``x, y, z``: world centre, metres; ``nx, ny, nz``: 0 (the layout carries them, nothing reads them);
- ``f_dc_0..2``: degree-0 SH coefficient per colour (colour = 0.5 + 0.28209 f_dc);
- ``f_rest_i``: the higher-degree coefficients, channel-major: ``f_rest_{c (K-1) + j}`` is coefficient ``j + 1``
  of colour ``c`` (K = (degree + 1)^2; none for degree 0);
- ``opacity``: the logit of the opacity (3DGS applies a sigmoid);
- ``scale_0..2``: natural logarithm of the standard deviations along the splat's axes, metres;
- ``rot_0..3``: unit rotation quaternion, w first.

Splats bound to a mesh are placed from the mesh as the renderer places them; the pose of each node (edit layers
included) takes them to the world, and the SH coefficients of degree >= 1 are rotated with it (a rotated object
shows the same view-dependent colour from the same side).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from holousd._errors import SceneError
from holousd.render._binding import splats_in_world
from holousd.render._scene import _C1, _C2, _C3
from holousd.usd import GaussianSplats, SceneGraph
from holousd.usd._export import write_node_files

__all__ = ["PlySplats", "export_ply", "rotate_sh", "sh_basis", "world_splats"]

_PROPERTIES_HEAD = ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2")
_PROPERTIES_TAIL = ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


def sh_basis(dirs: np.ndarray, k: int) -> np.ndarray:
    """[N, k] real SH basis of :func:`holousd.render.sh_to_rgb` at unit directions ``dirs`` [N, 3] (k <= 16)."""
    x, y, z = (np.asarray(dirs, np.float64)[:, i] for i in range(3))
    cols = [np.full_like(x, 0.28209479177387814)]
    if k >= 4:
        cols += [-_C1 * y, _C1 * z, -_C1 * x]
    if k >= 9:
        xx, yy, zz = x * x, y * y, z * z
        cols += [_C2[0] * x * y, _C2[1] * y * z, _C2[2] * (2 * zz - xx - yy), _C2[3] * x * z, _C2[4] * (xx - yy)]
        if k >= 16:
            cols += [_C3[0] * y * (3 * xx - yy), _C3[1] * x * y * z, _C3[2] * y * (4 * zz - xx - yy),
                     _C3[3] * z * (2 * zz - 3 * xx - 3 * yy), _C3[4] * x * (4 * zz - xx - yy),
                     _C3[5] * z * (xx - yy), _C3[6] * x * (xx - 3 * yy)]  # fmt: skip
    if k not in (1, 4, 9, 16):
        raise ValueError(f"SH coefficients per colour must be 1, 4, 9 or 16, got {k}")
    return np.stack(cols, axis=1)


def rotate_sh(sh: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """SH coefficients [N, K, 3] expressed in a frame turned by ``rotation`` [3, 3] (world = rotation @ object):
    the radiance seen along world direction d equals the original seen along ``rotation.T @ d``.

    Each band is rotation-closed, so per band the coefficients map linearly; the map is solved exactly by least
    squares over a fixed spread of directions."""
    sh = np.asarray(sh, np.float64)
    k = sh.shape[1]
    if k == 1 or np.allclose(rotation, np.eye(3)):
        return sh.copy()
    golden = np.pi * (3.0 - np.sqrt(5.0))
    i = np.arange(64) + 0.5
    z = 1.0 - 2.0 * i / 64
    r = np.sqrt(1.0 - z * z)
    dirs = np.stack([r * np.cos(golden * i), r * np.sin(golden * i), z], axis=1)  # [M, 3] world directions
    world = sh_basis(dirs, k)
    turned = sh_basis(dirs @ np.asarray(rotation, np.float64), k)  # rows: Y(R^T d)
    out = sh.copy()
    start = 1
    for band in range(1, int(round(np.sqrt(k)))):
        cols = slice(start, start + 2 * band + 1)
        mix, *_ = np.linalg.lstsq(world[:, cols], turned[:, cols], rcond=None)  # Y_w mix = Y_t
        out[:, cols, :] = np.einsum("ij,njc->nic", mix, sh[:, cols, :])
        start += 2 * band + 1
    return out


class PlySplats:
    """World-frame splats of one node, in the arrays of the 3DGS layout."""

    def __init__(self, centres: np.ndarray, quats_wxyz: np.ndarray, log_scales: np.ndarray,
                 opacity_logits: np.ndarray, sh: np.ndarray) -> None:  # fmt: skip
        self.centres = centres
        self.quats_wxyz = quats_wxyz
        self.log_scales = log_scales
        self.opacity_logits = opacity_logits
        self.sh = sh

    def __len__(self) -> int:
        return len(self.centres)

    @staticmethod
    def concatenate(parts: list[PlySplats]) -> PlySplats:
        k = max((p.sh.shape[1] for p in parts), default=1)
        padded = [np.concatenate([p.sh, np.zeros((len(p), k - p.sh.shape[1], 3))], axis=1) for p in parts]
        return PlySplats(*(np.concatenate([getattr(p, f) for p in parts]) if parts else np.zeros((0, n))
                           for f, n in (("centres", 3), ("quats_wxyz", 4), ("log_scales", 3))),
                         np.concatenate([p.opacity_logits for p in parts]) if parts else np.zeros(0),
                         np.concatenate(padded) if parts else np.zeros((0, 1, 3)))  # fmt: skip


def world_splats(scene: SceneGraph, name: str, time: float | None = None) -> PlySplats:
    """One node's splats in the world frame at ``time`` (default: the default time), in the 3DGS layout."""
    from scipy.spatial.transform import Rotation

    splats: GaussianSplats = scene.get_gaussians(name)
    pose = scene.get_pose(name, time)
    mesh = scene.get_mesh(name) if splats.bound else None
    centres, rotations, scales = splats_in_world(splats, pose, mesh)
    quats = Rotation.from_matrix(rotations).as_quat() if len(splats) else np.zeros((0, 4))  # x, y, z, w
    quats = np.concatenate([quats[:, 3:], quats[:, :3]], axis=1)
    quats *= np.where(quats[:, :1] < 0, -1.0, 1.0)  # w >= 0: one of the two quaternions of each rotation
    opacity = np.clip(splats.opacities.astype(np.float64), 1e-6, 1.0 - 1e-6)
    return PlySplats(centres=centres, quats_wxyz=quats, log_scales=np.log(np.maximum(scales, 1e-12)),
                     opacity_logits=np.log(opacity / (1.0 - opacity)),
                     sh=rotate_sh(splats.sh_coeffs, pose.rotation_matrix()))  # fmt: skip


def _ply_bytes(splats: PlySplats) -> bytes:
    k = splats.sh.shape[1]
    rest = [f"f_rest_{i}" for i in range(3 * (k - 1))]
    names = [*_PROPERTIES_HEAD, *rest, *_PROPERTIES_TAIL]
    n = len(splats)
    columns = [splats.centres, np.zeros((n, 3)), splats.sh[:, 0, :],
               np.transpose(splats.sh[:, 1:, :], (0, 2, 1)).reshape(n, -1),  # channel-major, as 3DGS writes it
               splats.opacity_logits.reshape(n, 1), splats.log_scales, splats.quats_wxyz]  # fmt: skip
    data = np.concatenate([np.asarray(c, np.float64).reshape(n, -1) for c in columns], axis=1).astype("<f4")
    assert data.shape[1] == len(names)
    header = ["ply", "format binary_little_endian 1.0", "comment holousd Gaussian splats (3DGS layout, world frame)",
              f"element vertex {n}", *(f"property float {p}" for p in names), "end_header"]  # fmt: skip
    return ("\n".join(header) + "\n").encode("ascii") + np.ascontiguousarray(data).tobytes()


def export_ply(scene: SceneGraph, out: str | os.PathLike[str], *, time: float | None = None) -> list[Path]:
    """Write every node's splats to ``out/<node>.ply`` and all of them to ``out/scene.ply`` (see the module
    docstring for the layout). Every file is written whole to a temporary name, then renamed.

    Returns:
        The files written, the scene's last.
    """
    parts: list[tuple[str, PlySplats]] = []
    for node in scene.nodes():
        try:
            parts.append((node.name, world_splats(scene, node.name, time)))
        except SceneError as exc:
            if "no Gaussian splats" in str(exc):
                continue  # a node without appearance (yet): nothing to exchange
            raise
    if not parts:
        raise SceneError(f"{scene.stage.GetRootLayer().identifier}: no node has Gaussian splats; run the appearance "
                         "stage (holousd reconstruct) before exporting splats")  # fmt: skip
    return write_node_files(out, [(name, _ply_bytes(splats)) for name, splats in parts],
                            _ply_bytes(PlySplats.concatenate([p for _, p in parts])), ".ply")  # fmt: skip
