"""End-to-end pipeline on a tiny synthetic capture (the demo scene, 8 frames at 64x64): reconstruct, resume,
interruption, relation inference, evaluation and the demo report."""

from __future__ import annotations

import argparse
import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh
from pxr import Sdf

from holousd.cli import main
from holousd.stages import _pipeline
from holousd.stages._pipeline import STAGES, preset, read_stage_records, reconstruct
from holousd.synth import SynthConfig, generate_suite
from holousd.usd import SceneGraph, data_layer_path


def tiny_config(**appearance: object) -> _pipeline.PipelineConfig:
    """The fast preset cut to the bone: 2 refinement steps, hull colliders only, a few splat steps."""
    appearance = {"iterations": 3, "frames": 4, **appearance}
    cfg = preset("fast", progress=False, threads=1)
    return replace(
        cfg,
        fit=replace(cfg.fit, iterations=2),
        physics=replace(cfg.physics, collider_policy="convexity", convex_threshold=0.0),
        appearance=replace(cfg.appearance, **appearance),
    )


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth")
    generate_suite("demo", out, SynthConfig(frames=8, width=64, height=64, progress=False))
    return out / "demo"


@pytest.fixture(scope="module")
def recon(capture: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, _pipeline.PipelineResult]:
    out = tmp_path_factory.mktemp("recon")
    lines: list[str] = []
    result = reconstruct(capture, out, tiny_config(), log=lines.append)
    assert len([line for line in lines if "done in" in line]) == len(STAGES)
    return out, result


def _copy(recon_dir: Path, tmp_path: Path) -> Path:
    dest = tmp_path / "recon"
    shutil.copytree(recon_dir, dest)
    return dest


def _record(layer: Path) -> dict:
    return dict(Sdf.Layer.OpenAsAnonymous(str(layer)).customLayerData["holousd"]["stage"])


def test_reconstruct_writes_every_stage_layer_with_records(recon: tuple[Path, _pipeline.PipelineResult],
                                                           capture: Path) -> None:  # fmt: skip
    out, result = recon
    assert result.scene_file == out / "scene.usda"
    assert [s.name for s in result.stages] == list(STAGES)
    scene = SceneGraph.open(out / "scene.usda")
    stack = [Path(layer.identifier).relative_to(out).as_posix()
             for layer in scene.stage.GetLayerStack(includeSessionLayers=False)]  # fmt: skip
    assert stack == ["scene.usda", "30_appearance.usda", "assets/30_appearance/arrays.usdc", "20_physics.usda",
                     "assets/20_physics/arrays.usdc", "15_search.usda", "assets/15_search/arrays.usdc",
                     "10_fit.usda", "assets/10_fit/arrays.usdc", "00_observe.usda"]  # large arrays under each
    for name in STAGES:
        rec = _record(out / _pipeline.LAYERS[name])
        assert rec["name"] == name and rec["wall_s"] >= 0 and rec["peak_mem_mb"] > 0
        assert len(rec["input_hash"]) == 64
        assert isinstance(rec["config"], dict) and json.loads(rec["config_json"])
    assert json.loads(_record(out / "10_fit.usda")["config_json"])["iterations"] == 2
    graph = json.loads((capture / "gt" / "graph.json").read_text())
    parents = {n["name"]: n["parent"] for n in graph["nodes"] if n["role"] == "object"}
    summary = {n.name: n for n in scene.summary().nodes}
    agree = 0
    for name, parent in parents.items():
        node = summary[name]
        assert node.mass_kg and node.mass_kg > 0 and node.splats > 0
        assert node.collider in ("convexHull", "convexDecomposition") and node.collider_parts >= 1  # convex parts
        agree += node.supported_by == parent
    assert agree >= 0.7 * len(parents)
    assert summary["background"].collider == "convexDecomposition"  # floor and wall slabs
    assert summary["background"].collider_parts >= 1


def test_resume_skips_unchanged_and_reruns_changed_stages(recon: tuple[Path, _pipeline.PipelineResult],
                                                          capture: Path, tmp_path: Path) -> None:  # fmt: skip
    out = _copy(recon[0], tmp_path)
    before = {n: (out / _pipeline.LAYERS[n]).read_bytes() for n in STAGES}
    result = reconstruct(capture, out, tiny_config(), resume=True, log=lambda _: None)
    assert all(s.skipped for s in result.stages)
    assert all((out / _pipeline.LAYERS[n]).read_bytes() == before[n] for n in STAGES)

    result = reconstruct(capture, out, tiny_config(iterations=4), resume=True, log=lambda _: None)
    assert [s.skipped for s in result.stages] == [True, True, True, True, False]
    assert _record(out / "30_appearance.usda")["config"]["iterations"] == 4

    cfg = tiny_config(iterations=4)
    cfg = replace(cfg, physics=replace(cfg.physics, friction=0.6))
    result = reconstruct(capture, out, cfg, resume=True, log=lambda _: None)
    assert [s.skipped for s in result.stages] == [True, True, True, False, False]  # the stage above re-runs
    assert SceneGraph.open(out / "scene.usda").get_physics("book_1").static_friction == pytest.approx(0.6)


def test_until_stops_and_scene_points_at_the_last_layer(recon: tuple[Path, _pipeline.PipelineResult],
                                                        capture: Path, tmp_path: Path) -> None:  # fmt: skip
    out = _copy(recon[0], tmp_path)
    result = reconstruct(capture, out, tiny_config(), until="fit", resume=True, log=lambda _: None)
    assert [s.name for s in result.stages] == ["observe", "fit"] and all(s.skipped for s in result.stages)
    layer = Sdf.Layer.OpenAsAnonymous(str(out / "scene.usda"))
    assert list(layer.subLayerPaths) == ["./10_fit.usda"]
    assert "stage" not in dict(layer.customLayerData["holousd"])


def test_interrupted_stage_leaves_previous_layers_intact(recon: tuple[Path, _pipeline.PipelineResult],
                                                         capture: Path, tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    out = _copy(recon[0], tmp_path)
    before = {p.name: p.read_bytes() for p in out.glob("*.usda")}

    def crash(scene: SceneGraph, config: object) -> SceneGraph:
        scene.push_layer(out / "20_physics.usda", replace=True)
        scene.set_support("mug_1", "background")  # half-done work in memory
        raise KeyboardInterrupt

    monkeypatch.setattr(_pipeline._physics, "run", crash)
    cfg = tiny_config()
    cfg = replace(cfg, physics=replace(cfg.physics, friction=0.7))
    with pytest.raises(KeyboardInterrupt):
        reconstruct(capture, out, cfg, resume=True, log=lambda _: None)
    after = {p.name: p.read_bytes() for p in out.glob("*.usda")}
    assert after == before  # nothing half-written, nothing lost
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]
    monkeypatch.undo()
    result = reconstruct(capture, out, cfg, resume=True, log=lambda _: None)
    assert [s.skipped for s in result.stages] == [True, True, True, False, False]


def test_eval_of_reconstruction_reports_every_key(recon: tuple[Path, _pipeline.PipelineResult], capture: Path,
                                                  tmp_path: Path) -> None:  # fmt: skip
    from holousd.eval._report import write_report
    from holousd.eval._scene_eval import EvalConfig, evaluate_scene

    out, _ = recon
    d = evaluate_scene(out, capture / "gt", EvalConfig(samples=20_000)).to_dict()
    assert set(d["geometry"]) == {"scene", "objects"}
    for part in ("scene", "objects"):
        assert set(d["geometry"][part]) == {"chamfer_cm", "f1", "nc"}
        assert 0 < d["geometry"][part]["f1"] <= 100 and d["geometry"][part]["chamfer_cm"] > 0
    assert set(d["render"]) == {"psnr", "ssim", "mesh_psnr", "vertex_psnr"} and np.isfinite(d["render"]["psnr"])
    assert 10.0 < d["render"]["mesh_psnr"] < 60.0  # the meshes in the texture baked onto them
    assert 10.0 < d["render"]["vertex_psnr"] < 60.0  # in the per-point colour
    assert set(d["physics"]) == {"or_pct", "stable_pct", "penetration_cm3", "solver", "cross_check",
                                 "search_agreement_pct", "max_fit_shift_cm", "max_collider_reach_cm",
                                 "max_penetration_cm"}  # fmt: skip
    worst = max(o["collider_reach_cm"] for o in d["objects"])  # the rows carry each object's record
    assert d["physics"]["max_collider_reach_cm"] == pytest.approx(worst) and d["physics"]["max_fit_shift_cm"] <= 1.0
    assert d["physics"]["solver"] == "xpbd" and d["physics"]["cross_check"]["solver"] == "mujoco"
    assert d["physics"]["or_pct"] == 100.0
    # Stable% counts the ground truth's objects whose reconstruction stands (the rows' verdicts)
    assert d["physics"]["stable_pct"] == pytest.approx(10.0 * sum(o["stable"] is True for o in d["objects"]))
    # and the cross-check's Stable% counts the rows' MuJoCo verdicts, shown beside XPBD's
    mujoco = sum(o["stable_cross_check"] is True for o in d["objects"])
    assert d["physics"]["cross_check"]["stable_pct"] == pytest.approx(10.0 * mujoco)
    # the search's verdict (quasi-static E_stable) beside the protocol's, per object the search scored
    shipped = SceneGraph.open(out / "scene.usda")
    scored = [(shipped.get_energies(o["recon"]), o["stable"]) for o in d["objects"]]
    same = [e.stands == stable for e, stable in scored if e is not None and e.chosen is not None]
    assert same and d["physics"]["search_agreement_pct"] == pytest.approx(100.0 * sum(same) / len(same))
    assert set(d["cost"]) == {"total_s", "stages", "peak_mem_mb"} and list(d["cost"]["stages"]) == list(STAGES)
    assert len(d["objects"]) == 10 and all(o["recon"] == o["name"] for o in d["objects"])
    report = write_report(tmp_path / "report.html", evaluation=d, scene_file=out / "scene.usda", gt_dir=capture)
    page = report.read_text()
    # 4 input frames, the novel view, the mesh view, the speed-vs-accuracy chart, cost and F1 charts
    assert page.count("data:image/png;base64,") >= 4 + 1 + 1 + 1 + 2
    assert "no render" not in page and "no mesh view" not in page and "Speed against accuracy" in page
    assert "mug_1" in page and "Stable%" in page and "verdict (mujoco)" in page
    assert "hard fast (hard_ablation)" in page  # the older run of a preset is told apart from the current one


def test_records_are_read_back(recon: tuple[Path, _pipeline.PipelineResult]) -> None:
    records = read_stage_records(recon[0])
    assert [r.name for r in records] == list(STAGES)
    assert records[1].config["iterations"] == 2 and records[1].wall_s == pytest.approx(recon[1].stages[1].wall_s)


def test_every_mesh_has_normals_and_nvidias_validator_finds_no_failure(
        recon: tuple[Path, _pipeline.PipelineResult], tmp_path: Path) -> None:  # fmt: skip
    from pxr import Usd, UsdGeom

    scene = recon[0] / "scene.usda"
    stage = Usd.Stage.Open(str(scene))
    meshes = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert len(meshes) > 10
    for mesh in meshes:  # render meshes smooth (a normal per point), colliders flat (one per face)
        normals, points = mesh.GetNormalsAttr().Get(), mesh.GetPointsAttr().Get()
        counts = mesh.GetFaceVertexCountsAttr().Get()
        expected = len(points) if mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex else len(counts)
        assert normals is not None and len(normals) == expected, mesh.GetPath()
        assert np.allclose(np.linalg.norm(np.asarray(normals), axis=1), 1.0, atol=1e-4), mesh.GetPath()
    import sys

    beside = Path(sys.executable).with_name("nvidia_usd_validate")  # a virtual environment not on PATH
    tool = str(beside) if beside.is_file() else shutil.which("nvidia_usd_validate")
    if tool is None:
        pytest.skip("NVIDIA's validator is not installed (pip install usd-validation-nvidia: the dev extra has it)")
    import subprocess

    package, sim, text_sim = tmp_path / "scene.usdz", tmp_path / "sim.usdc", tmp_path / "sim.usda"
    assert main(["export", str(scene), "--usdz", str(package), "--sim", str(sim)]) == 0
    assert main(["export", str(scene), "--sim", str(text_sim)]) == 0

    def failures(written: Path) -> dict[str, list[str]]:
        report = tmp_path / f"nvidia_{written.name}.json"
        subprocess.run([tool, str(written), "--json-output", str(report)], capture_output=True, timeout=300)
        rules = {r["rule"]["name"]: r.get("issues", []) for r in json.loads(report.read_text())["rules"]}
        return {name: [i.get("message", "")[:200] for i in issues if i.get("severity") == "FAILURE"]
                for name, issues in rules.items() if any(i.get("severity") == "FAILURE" for i in issues)}  # fmt: skip

    for written in (scene, package, sim):  # every stage layer (through scene.usda), the package, the sim scene
        assert failures(written) == {}, written.name
    # Negative control: one flattened text file holds its arrays as text, and the validator says so.
    assert "UsdAsciiPerformanceChecker" in failures(text_sim)


def test_relations_inferred_from_ground_truth_meshes(capture: Path) -> None:
    import trimesh

    from holousd.graph import infer_relations, settle_offsets
    from holousd.usd import Pose

    graph = json.loads((capture / "gt" / "graph.json").read_text())
    meshes = {}
    for n in graph["nodes"]:
        if n["role"] != "object":
            continue
        tm = trimesh.load(capture / "gt" / n["mesh"], force="mesh", process=False)
        pose = Pose(translation=n["pose"]["translation"], orientation=n["pose"]["orientation_xyzw"])
        meshes[n["name"]] = (pose.apply(tm.vertices), np.asarray(tm.faces))
    rel = infer_relations(meshes)
    objects = [n for n in graph["nodes"] if n["role"] == "object"]
    assert rel.support == {n["name"]: n["parent"] for n in objects}
    assert {k: v for k, v in rel.beside.items() if v} == {n["name"]: n["beside"] for n in objects if n["beside"]}
    assert rel.tree_lines()[0] == "background"
    lifted = {k: (p + [0.0, 0.0, 0.03] if k == "mug_1" else p, f) for k, (p, f) in meshes.items()}
    shifts = settle_offsets(lifted, None, rel)  # the mug floats 3 cm above the book: it is set back down
    assert shifts["mug_1"] == pytest.approx(-0.03, abs=0.003) and shifts["book_1"] == pytest.approx(0.0, abs=0.003)


def test_concave_object_gets_a_decomposition() -> None:
    import trimesh

    from holousd.stages._physics_setup import PhysicsSetupConfig, _decompose
    from holousd.usd import MeshData

    a = trimesh.creation.box(extents=[0.4, 0.1, 0.1])
    b = trimesh.creation.box(extents=[0.1, 0.1, 0.4])
    b.apply_translation([0.15, 0.0, 0.25])
    mesh = trimesh.boolean.union([a, b], engine="manifold")
    parts = _decompose(MeshData(points=mesh.vertices, faces=mesh.faces), PhysicsSetupConfig())
    assert len(parts) >= 2


def test_cli_parses_pipeline_commands() -> None:
    from holousd.stages import _pipeline_cli

    parser = argparse.ArgumentParser()
    _pipeline_cli.add_commands(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["reconstruct", "cap", "--out", "o", "--preset", "fast", "--until", "physics",
                              "--resume", "--seed", "3"])  # fmt: skip
    assert (args.preset, args.until, args.resume, args.seed) == ("fast", "physics", True, 3)
    args = parser.parse_args(["bench", "--suite", "hard", "--presets", "fast", "--out", "b", "--scenes", "stack"])
    assert (args.suite, args.presets, args.scenes) == ("hard", "fast", "stack")
    with pytest.raises(SystemExit):
        parser.parse_args(["reconstruct", "cap", "--out", "o", "--until", "nowhere"])


def test_object_pushed_out_of_a_wall() -> None:
    import trimesh

    from holousd.graph import push_out_of

    wall = trimesh.creation.box(extents=[0.2, 2.0, 2.0])
    wall.apply_translation([1.1, 0.0, 1.0])  # inner face at x = 1.0
    obj = trimesh.creation.box(extents=[0.4, 0.4, 0.4])
    obj.apply_translation([0.83, 0.0, 0.2])  # 3 cm into the wall
    shift = push_out_of((obj.vertices, obj.faces), (wall.vertices, wall.faces), clearance=0.0)
    assert shift[0] == pytest.approx(-0.03, abs=1e-6) and shift[1] == 0.0 and shift[2] == 0.0
    obj.apply_translation([-0.1, 0.0, 0.0])
    assert not push_out_of((obj.vertices, obj.faces), (wall.vertices, wall.faces)).any()


def test_room_slabs_match_the_ground_truth_room(capture: Path) -> None:
    import trimesh

    from holousd.stages._physics_setup import _room_planes, _room_slabs
    from holousd.usd import MeshData

    room = trimesh.load(capture / "gt" / "meshes" / "background.ply", force="mesh", process=False)
    slabs = _room_slabs(MeshData(points=room.vertices, faces=room.faces), 0.2)
    assert len(slabs) == 5
    floor = slabs[0].points
    assert floor[:, 2].max() == pytest.approx(0.0, abs=1e-6) and floor[:, 2].min() == pytest.approx(-0.2)
    inner = sorted(
        round(float(v), 3)
        for m in slabs[1:]
        for v in (m.points[:, :2].min(0).tolist() + m.points[:, :2].max(0).tolist())
        if abs(abs(v) - 2.3) < 1e-3 or abs(abs(v) - 2.0) < 1e-3
    )
    assert {-2.3, 2.3, -2.0, 2.0} <= set(inner)  # the demo room is 4.6 x 4.0 m
    _, walls = _room_planes(MeshData(points=room.vertices, faces=room.faces))
    turn = trimesh.transformations.rotation_matrix(np.radians(25.0), [0, 0, 1])[:3, :3]
    _, turned = _room_planes(MeshData(points=room.vertices @ turn.T, faces=room.faces))  # filmed turned about z
    assert len(walls) == len(turned) == 4
    for wall in walls:  # the same four walls, turned with the room, as far from its centre
        match = max(turned, key=lambda w: float(np.asarray(w.normal) @ turn @ np.asarray(wall.normal)))
        assert np.asarray(match.normal) @ turn @ np.asarray(wall.normal) == pytest.approx(1.0, abs=1e-4)
        assert match.offset == pytest.approx(wall.offset, abs=1e-3)


def test_background_mesh_collider_option(recon: tuple[Path, _pipeline.PipelineResult], tmp_path: Path) -> None:
    from holousd.stages._physics_setup import PhysicsSetupConfig, setup_physics

    out = _copy(recon[0], tmp_path)
    scene = SceneGraph.open(out / "10_fit.usda")
    result = setup_physics(
        scene, PhysicsSetupConfig(background_collider="mesh", collider_policy="convexity", convex_threshold=0.0)
    )
    assert scene.get_collider("background").approximation == "none"
    assert {o.name for o in result.objects} == set(scene.objects())


def test_threads_reach_fit_and_appearance_and_do_not_change_the_hash() -> None:
    config = preset("fast", threads=1)
    assert config.fit.threads == 1 and config.appearance.threads == 1
    plain = preset("fast")
    for name in ("fit", "appearance"):
        one, default = getattr(config, name), getattr(plain, name)
        assert _pipeline._stage_hash("m", one, "") == _pipeline._stage_hash("m", default, "")


def _layer_without_run_records(path: Path) -> str:
    layer = Sdf.Layer.OpenAsAnonymous(str(path))
    data = dict(layer.customLayerData)
    holo = dict(data.get("holousd", {}))
    if "stage" in holo:
        holo["stage"] = {k: v for k, v in dict(holo["stage"]).items() if k not in ("wall_s", "peak_mem_mb", "run_id")}
    data["holousd"] = holo
    layer.customLayerData = data
    crate = data_layer_path(path)  # and the large arrays, kept in the layer's crate file
    return layer.ExportToString() + (Sdf.Layer.OpenAsAnonymous(str(crate)).ExportToString() if crate.is_file() else "")


def test_same_capture_and_settings_give_the_same_scene_from_a_relative_out(
        recon: tuple[Path, _pipeline.PipelineResult], capture: Path, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    first, result = recon
    monkeypatch.chdir(tmp_path)  # the README's form: a relative --out, here one that climbs out of the working folder
    relative = Path("..") / f"{first.name}_again"  # beside the first run: layers hold image paths relative to them
    again = reconstruct(capture, relative, tiny_config(), log=lambda _: None)
    second = (tmp_path / relative).resolve()
    assert again.scene_file == second / "scene.usda" and (second / "30_appearance.usda").is_file()
    assert not list(second.rglob(f"{relative.name}"))
    assert [s.input_hash for s in again.stages] == [s.input_hash for s in result.stages]  # content-only hashes
    files = sorted(p.relative_to(first) for p in first.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(second) for p in second.rglob("*") if p.is_file())
    for rel in files:
        if rel.suffix == ".usda":
            assert _layer_without_run_records(first / rel) == _layer_without_run_records(second / rel), rel
        else:
            assert (first / rel).read_bytes() == (second / rel).read_bytes(), rel


def test_observed_fraction_is_measured(recon: tuple[Path, _pipeline.PipelineResult]) -> None:
    scene = SceneGraph.open(recon[0] / "scene.usda")
    fractions = {n.name: n.observed_fraction for n in scene.nodes()}
    objects = [v for k, v in fractions.items() if k != "background"]
    assert all(0.05 < v < 0.95 for v in objects), fractions  # seen from one side: never all, never nothing
    assert 0 < fractions["background"] <= 1


def test_physics_set_up_records_how_the_geometry_was_changed(recon: tuple[Path, _pipeline.PipelineResult]) -> None:
    scene = SceneGraph.open(recon[0] / "scene.usda")
    for name in scene.objects():
        record = scene.get_geometry_record(name)
        assert record is not None and record.volume > 0 and record.collider_reach >= 0 and record.penetration >= 0
        mesh = scene.get_mesh(name)  # the default (one-geometry) set-up end to end: closed meshes, and where the
        assert trimesh.Trimesh(mesh.points, mesh.faces, process=False).is_watertight, name  # mesh was made the
        if any(e.startswith("convexify") for e in record.edits):  # union of its collider's parts, nothing of the
            assert record.collider_reach < 1e-3, (name, record.collider_reach)  # collider reaches outside it
        assert np.linalg.norm(record.fit_shift) <= 0.01 + 1e-6, (name, record.fit_shift)  # moved <= 1 cm
        physics = scene.get_physics(name)
        assert physics.diagonal_inertia is not None and np.all(physics.diagonal_inertia > 0)
        assert physics.mass == pytest.approx(500.0 * record.volume, rel=1e-6) or physics.mass == pytest.approx(1e-3)
    rows = {n.name: n for n in scene.summary().nodes}
    assert rows["mug_1"].collider_reach_cm is not None and rows["background"].collider_reach_cm is None
