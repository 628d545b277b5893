"""A small hand-built example scene: floor and wall, a table, a book, a mug stacked on it, a box beside the book.

It exercises every part of the scene graph (meshes, explicit convex decomposition, SDF grids, splats bound to
faces, physics, support and beside relations) and is what ``holousd example`` writes. Geometry is exact
(boxes and a faceted cylinder), placed so that it rests without interpenetration.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from holousd.geometry import sdf_from_convex_parts
from holousd.usd import (
    BACKGROUND,
    Collider,
    GaussianSplats,
    MeshData,
    PhysicsProps,
    Pose,
    SceneGraph,
)

__all__ = ["build_example_scene", "splats_on_mesh"]

_BOX_FACES = np.array(
    [[0, 1, 2], [1, 3, 2], [4, 6, 5], [5, 6, 7], [0, 4, 1], [1, 4, 5],
     [2, 3, 6], [3, 7, 6], [0, 2, 4], [2, 6, 4], [1, 5, 3], [3, 5, 7]]
)  # fmt: skip  # outward (counter-clockwise seen from outside); corner index = 4 x + 2 y + z


def _box(size: tuple[float, float, float], center: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> MeshData:
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    return MeshData(points=corners * np.asarray(size) + np.asarray(center), faces=_BOX_FACES)


def _cylinder(radius: float, height: float, segments: int = 24) -> MeshData:
    angle = 2 * np.pi * np.arange(segments) / segments
    ring = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    points = np.concatenate([np.c_[ring, np.zeros(segments)], np.c_[ring, np.full(segments, height)],
                             [[0, 0, 0], [0, 0, height]]])  # fmt: skip
    faces = []
    bottom, top = 2 * segments, 2 * segments + 1
    for i in range(segments):
        j = (i + 1) % segments
        faces += [[i, j, segments + j], [i, segments + j, segments + i], [bottom, j, i],
                  [top, segments + i, segments + j]]  # fmt: skip
    return MeshData(points=points, faces=np.array(faces))


def _merge(parts: list[MeshData]) -> MeshData:
    offsets = np.cumsum([0] + [len(p.points) for p in parts[:-1]])
    return MeshData(
        points=np.concatenate([p.points for p in parts]),
        faces=np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)]),
    )


def _union(parts: list[MeshData]) -> MeshData:
    """Watertight boolean union of closed meshes (manifold3d)."""
    import manifold3d

    solid = manifold3d.Manifold()
    for part in parts:
        mesh = manifold3d.Mesh(vert_properties=part.points.astype(np.float32), tri_verts=part.faces.astype(np.uint32))
        solid = solid + manifold3d.Manifold(mesh)
    out = solid.to_mesh()
    return MeshData(points=np.asarray(out.vert_properties)[:, :3], faces=np.asarray(out.tri_verts))


def _volume(mesh: MeshData) -> float:
    tri = mesh.points[mesh.faces]
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


def splats_on_mesh(mesh: MeshData, count: int, color: tuple[float, float, float], seed: int) -> GaussianSplats:
    """Sample ``count`` flat splats bound uniformly (by area) to the faces of ``mesh``.

    Colours vary around ``color`` with a procedural checker pattern so that appearance is not flat.
    """
    rng = np.random.default_rng(seed)
    tri = mesh.points[mesh.faces]  # [F, 3, 3]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    face = rng.choice(len(area), size=count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    bary = np.stack([1 - u - v, u, v], axis=1)  # [N, 3]
    positions = np.einsum("nk,nkj->nj", bary, tri[face])
    normal = cross[face] / np.linalg.norm(cross[face], axis=1, keepdims=True)
    # quaternion (x, y, z, w) turning +Z onto the face normal
    axis = np.cross(np.tile([0.0, 0.0, 1.0], (count, 1)), normal)
    w = 1.0 + normal[:, 2]
    quat = np.c_[axis, w]
    degenerate = w < 1e-6
    quat[degenerate] = [1.0, 0.0, 0.0, 0.0]
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    sigma = np.sqrt(area.sum() / count) * 0.6
    checker = (np.floor(positions / 0.05).sum(axis=1) % 2)[:, None] * 0.15
    rgb = np.clip(np.asarray(color) * (0.85 + checker), 0.0, 1.0)
    sh_c0 = 0.28209479177387814  # Y_0^0: colour = 0.5 + C0 * coefficient
    return GaussianSplats(
        positions=positions,
        orientations=quat,
        scales=np.c_[np.full(count, sigma), np.full(count, sigma), np.full(count, sigma * 0.05)],
        opacities=np.full(count, 0.9),
        sh_coeffs=((rgb - 0.5) / sh_c0)[:, None, :],
        face_index=face,
        barycentric=bary,
        normal_offset=np.zeros(count),
        in_plane_rotation=np.zeros(count),
        in_plane_scale=np.c_[np.full(count, sigma), np.full(count, sigma)],
    )


def build_example_scene(out_dir: str | os.PathLike[str], *, seed: int = 0, overwrite: bool = False) -> Path:
    """Write the example scene to ``out_dir/scene.usda`` (plus its assets/) and return the scene path."""
    out_dir = Path(out_dir)
    scene = SceneGraph.create(out_dir / "scene.usda", overwrite=overwrite, provenance="holousd example")
    floor = _box((4.0, 4.0, 0.1), (0.0, 0.0, -0.05))
    wall = _box((4.0, 0.1, 2.5), (0.0, 2.05, 1.25))
    scene.add_background(observed_fraction=1.0)
    scene.set_mesh(BACKGROUND, _merge([floor, wall]))
    scene.set_collider(BACKGROUND, Collider(approximation="none", parts=[_merge([floor, wall])]))
    scene.set_physics(BACKGROUND, PhysicsProps(mass=None, static_friction=0.6, dynamic_friction=0.5))

    top = _box((1.0, 0.6, 0.04), (0.0, 0.0, 0.70))
    legs = [_box((0.05, 0.05, 0.68), (sx * 0.45, sy * 0.25, 0.34)) for sx in (-1, 1) for sy in (-1, 1)]
    table_parts = [top, *legs]
    book = _box((0.22, 0.16, 0.03), (0.0, 0.0, 0.015))
    mug = _cylinder(0.04, 0.10)
    box = _box((0.12, 0.12, 0.12), (0.0, 0.0, 0.06))
    objects = [
        # name, parts, pose translation, support, density kg/m^3, colour
        ("table", table_parts, (0.0, 0.3, 0.0), BACKGROUND, 600.0, (0.55, 0.35, 0.2)),
        ("book", [book], (-0.1, 0.3, 0.72), "table", 700.0, (0.7, 0.1, 0.1)),
        ("mug", [mug], (-0.1, 0.3, 0.75), "book", 900.0, (0.9, 0.9, 0.85)),
        ("box", [box], (0.08, 0.3, 0.72), "table", 300.0, (0.2, 0.4, 0.8)),
    ]
    for instance_id, (name, parts, position, parent, density, color) in enumerate(objects, start=1):
        mesh = _union(parts)
        volume = sum(_volume(p) for p in parts)
        scene.add_object(name, instance_id=instance_id, pose=Pose(translation=position), observed_fraction=0.7)
        scene.set_mesh(name, mesh)
        approximation = "convexDecomposition" if len(parts) > 1 else "convexHull"
        scene.set_collider(name, Collider(approximation=approximation, parts=parts))
        com = sum(_volume(p) * p.points.mean(axis=0) for p in parts) / volume
        scene.set_physics(name, PhysicsProps(mass=density * volume, center_of_mass=com, density=density))
        scene.set_sdf(name, sdf_from_convex_parts(mesh, parts, voxel_size=0.02))
        scene.set_gaussians(name, splats_on_mesh(mesh, 2000, color, seed + instance_id))
        scene.set_support(name, parent)
    scene.set_beside("book", ["box"])
    scene.set_beside("box", ["book"])
    return scene.save()
