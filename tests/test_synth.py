"""Procedural benchmark: determinism, render / ground-truth consistency, physical validity of layouts, CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import holousd
from holousd.cli import main
from holousd.geometry import point_triangle_distance
from holousd.io import load
from holousd.synth import SUITES, SynthConfig, build_scene, generate_suite
from holousd.synth._generate import _mass_properties
from holousd.synth._raycast import RayCaster
from holousd.usd import BACKGROUND, MeshData, Pose, SceneGraph


def _read_ply(path: Path) -> MeshData:
    data = path.read_bytes()
    header, body = data.split(b"end_header\n", 1)
    lines = header.decode().splitlines()
    nv = int(next(line for line in lines if line.startswith("element vertex")).split()[-1])
    nf = int(next(line for line in lines if line.startswith("element face")).split()[-1])
    points = np.frombuffer(body[: nv * 12], dtype="<f4").reshape(nv, 3)
    faces = np.frombuffer(body[nv * 12 :], dtype=[("n", "u1"), ("v", "<i4", (3,))])
    assert len(faces) == nf and np.all(faces["n"] == 3)
    return MeshData(points=points.astype(np.float64), faces=faces["v"].astype(np.int64))


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth")
    generate_suite("demo", out, SynthConfig(frames=6, width=64, height=48, progress=False))
    return out / "demo"


def _gt_world(folder: Path) -> tuple[dict, dict[int, MeshData]]:
    graph = json.loads((folder / "gt" / "graph.json").read_text())
    meshes = {}
    for node in graph["nodes"]:
        mesh = _read_ply(folder / "gt" / node["mesh"])
        if node["role"] == "object":
            pose = Pose(translation=node["pose"]["translation"], orientation=node["pose"]["orientation_xyzw"])
            mesh = MeshData(points=pose.apply(mesh.points), faces=mesh.faces)
        meshes[node["instance_id"]] = mesh
    return graph, meshes


def test_same_seed_gives_identical_bytes(tmp_path: Path) -> None:
    config = SynthConfig(seed=5, frames=3, width=40, height=30, format="monosdf", progress=False)
    generate_suite("hard", tmp_path / "a", config, scenes=["stack"])
    generate_suite("hard", tmp_path / "b", config, scenes=["stack"])
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert len(files) > 20
    for rel in files:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel
    other = SynthConfig(seed=6, frames=3, width=40, height=30, format="monosdf", progress=False)
    generate_suite("hard", tmp_path / "c", other, scenes=["stack"])
    assert (tmp_path / "a/stack/gt/graph.json").read_bytes() != (tmp_path / "c/stack/gt/graph.json").read_bytes()


def test_depth_lands_on_ground_truth_meshes(demo: Path) -> None:
    obs = load(demo)
    obs.validate()
    _, meshes = _gt_world(demo)
    for i in (0, 3, 5):
        depth, mask, k, c2w = obs.depth(i), obs.mask(i), obs.intrinsics[i], obs.poses[i]
        v, u = np.nonzero(depth > 0)
        z = depth[v, u].astype(np.float64)
        cam = np.stack([(u - k[0, 2]) / k[0, 0] * z, (v - k[1, 2]) / k[1, 1] * z, z], axis=1)
        world = cam @ c2w[:3, :3].T + c2w[:3, 3]
        footprint = z / k[0, 0] + 1e-3  # one pixel at that depth, plus the millimetre depth quantisation
        for node in np.unique(mask):
            sel = mask[v, u] == node
            mesh = meshes[int(node)]
            dist = point_triangle_distance(world[sel], mesh.points[mesh.faces])
            assert np.all(dist <= footprint[sel]), (i, node, float(dist.max()))


def test_masks_agree_with_ray_hits_on_written_ground_truth(demo: Path) -> None:
    obs = load(demo)
    _, meshes = _gt_world(demo)
    ids = sorted(meshes)
    points = np.concatenate([meshes[i].points for i in ids])
    offsets = np.cumsum([0] + [len(meshes[i].points) for i in ids[:-1]])
    faces = np.concatenate([meshes[i].faces + o for i, o in zip(ids, offsets, strict=True)])
    owner = np.concatenate([np.full(len(meshes[i].faces), i) for i in ids])
    hits = RayCaster(points, faces).cast(obs.intrinsics, obs.poses, obs.width, obs.height)
    for i in range(len(obs)):
        assert np.all(hits.face[i] >= 0)  # the room is closed: every ray hits something
        agree = owner[hits.face[i]] == obs.mask(i)
        assert agree.mean() > 0.995, (i, agree.mean())  # float32 PLY vs float64 scene: rare edge pixels differ
        normal = obs.normal(i)
        assert np.all(np.abs(np.linalg.norm(normal, axis=-1) - 1) < 0.02)
        k = obs.intrinsics[i]
        u, v = np.meshgrid(np.arange(obs.width), np.arange(obs.height))
        ray = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones(u.shape)], axis=-1)
        assert np.all(np.einsum("hwc,hwc->hw", normal, ray) < 0.02)  # camera-frame normals face the camera


def test_ground_truth_is_complete_and_valid(demo: Path) -> None:
    import trimesh

    graph, _ = _gt_world(demo)
    for ply in (demo / "gt" / "meshes").glob("*.ply"):
        mesh = trimesh.load(ply, process=True)
        assert mesh.is_watertight and mesh.is_volume, ply.name
    scene = SceneGraph.open(demo / "gt" / "scene.usda")
    report = holousd.validate(scene.stage)
    assert report.ok, [str(i) for i in report.issues]
    objects = [n for n in graph["nodes"] if n["role"] == "object"]
    assert sorted(scene.objects()) == sorted(n["name"] for n in objects)
    names = {n["instance_id"]: n["name"] for n in objects}
    assert load(demo).instance_names == names
    for node in objects:
        assert scene.get_support(node["name"]) == node["parent"]
        assert sorted(scene.get_beside(node["name"])) == node["beside"]
        assert scene.node_info(node["name"]).instance_id == node["instance_id"]
        physics = scene.get_physics(node["name"])
        assert physics.mass == pytest.approx(node["density_kg_m3"] * node["volume_m3"])
        assert 0 <= node["observed_fraction"] <= 1 and node["pixels_observed"] > 0
    assert ["book_1", "box_1"] in graph["beside_pairs"]
    assert scene.get_collider("table_1").approximation == "convexDecomposition"
    assert scene.get_collider("plate_1").approximation == "convexHull"
    room = scene.get_collider(BACKGROUND)  # six disjoint slabs whose union is the room shell's solid
    assert room.approximation == "convexDecomposition" and len(room.parts) == 6
    volume = sum(trimesh.Trimesh(p.points, p.faces).volume for p in room.parts)
    shell = scene.get_mesh(BACKGROUND)
    assert volume == pytest.approx(trimesh.Trimesh(shell.points, shell.faces).volume, rel=1e-6)


@pytest.mark.parametrize("suite", sorted(SUITES))
def test_layouts_are_physically_valid(suite: str) -> None:
    """Every object rests on its parent's surface (checked at build), is supported under its centre of mass,
    and the support relations form a tree rooted at the background."""
    from scipy.spatial import Delaunay

    for name in SUITES[suite]:
        spec = build_scene(suite, name, seed=0)
        assert len(spec.objects) >= (4 if suite == "hard" else 8)
        names = {o.name for o in spec.objects}
        for obj in spec.objects:
            node, depth = obj.parent, 0
            while node != BACKGROUND:
                assert node in names
                node, depth = spec.by_name(node).parent, depth + 1
                assert depth < 10
            parts = obj.template.parts
            props = [_mass_properties(p) for p in parts]  # (volume, centre of mass) per convex part
            com = sum(v * c for v, c in props) / sum(v for v, _ in props)
            pts = np.concatenate([p.points for p in parts])
            contact = pts[pts[:, 2] < 1e-9][:, :2]
            assert Delaunay(contact).find_simplex(com[:2]) >= 0, (name, obj.name)
            for other in obj.beside:
                assert obj.name in spec.by_name(other).beside and spec.by_name(other).parent == obj.parent


def test_hard_suite_names_and_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert sorted(SUITES["hard"]) == sorted(
        ["stack", "against_wall", "thin", "small_beside_large", "touching_siblings", "shelf", "top_only"]
    )
    assert len(SUITES["bench"]) >= 5
    args = [
        "synth",
        "--suite",
        "hard",
        "--scenes",
        "top_only",
        "--out",
        str(tmp_path),
        "--frames",
        "4",
        "--resolution",
        "64x48",
        "--format",
        "nerfstudio",
        "--no-progress",
    ]
    assert main(args) == 0
    assert (tmp_path / "top_only" / "transforms.json").is_file()
    graph = json.loads((tmp_path / "top_only" / "gt" / "graph.json").read_text())
    bin_node = next(n for n in graph["nodes"] if n["name"] == "bin")
    assert bin_node["pixels_observed"] > 0 and bin_node["observed_fraction"] < 0.17  # at most its top
    assert sorted(bin_node["beside"]) == ["cabinet_1", "cabinet_2"]
    capsys.readouterr()
    assert main(args) == 2  # refuses to overwrite without --overwrite
    assert "--overwrite" in capsys.readouterr().err
    assert main([*args, "--overwrite"]) == 0
    more = [*args]
    more[more.index("top_only")] = "touching_siblings"
    assert main(more) == 0  # a second scene into the same folder: the index lists both, in suite order
    index = json.loads((tmp_path / "suite.json").read_text())
    assert [s["folder"] for s in index["scenes"]] == ["touching_siblings", "top_only"]
    other = [*more, "--overwrite"]
    other[other.index("4")] = "5"
    assert main(other) == 0  # made with other settings: the earlier scene is no longer listed beside it
    assert [s["folder"] for s in json.loads((tmp_path / "suite.json").read_text())["scenes"]] == ["touching_siblings"]
    with pytest.raises(SystemExit):
        main(["synth", "--out", str(tmp_path), "--resolution", "big"])
