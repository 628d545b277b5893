"""Tests of holousd.physics: model building, simulation, energies, colliders, stability verdicts and CLI.

Every simulating test uses the same tiny setting (boxes, a bowl, a floor slab; 240 Hz; XPBD and MuJoCo) so a
cold Warp kernel cache compiles each kernel module once for the whole file.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdPhysics

from holousd import physics
from holousd.physics import _cli
from holousd.physics._solvers import make_stepper
from tests.physics_fixtures import Material, Obj, bowl, box, make_scene, tray

SOLVERS = ("xpbd", "mujoco")
A, B = "/World/Objects/a", "/World/Objects/b"


def _quat_y(deg: float) -> tuple[float, float, float, float]:
    h = math.radians(deg) / 2
    return (math.cos(h), 0.0, math.sin(h), 0.0)


def _stack() -> list[Obj]:
    return [
        Obj(name="a", mesh=box(0.1, 0.1, 0.1), position=(0, 0, 0.1)),
        Obj(name="b", mesh=box(0.1, 0.1, 0.1), position=(0, 0, 0.3), supported_by="a"),
    ]


def _overhang() -> list[Obj]:
    # A heavy, wide pedestal and a box whose centre of mass is 5 cm beyond the pedestal's edge.
    return [
        Obj(name="a", mesh=box(0.2, 0.2, 0.1), position=(0, 0, 0.1), mass=50.0),
        Obj(name="b", mesh=box(0.1, 0.1, 0.05), position=(0.25, 0, 0.25), supported_by="a"),
    ]


def _leaning_plank() -> list[Obj]:
    # A 60 cm plank tilted 15 degrees, resting on one bottom edge, nothing to lean on.
    hz, hx, tilt = 0.3, 0.02, math.radians(15)
    z = hz * math.cos(tilt) + hx * math.sin(tilt)
    return [Obj(name="a", mesh=box(hx, 0.1, hz), position=(0, 0, z), orientation=_quat_y(15))]


def _bowl_on_table(collider: str | list = "hull") -> list[Obj]:
    pts, faces = bowl()
    return [
        Obj(name="table", mesh=box(0.2, 0.2, 0.1), position=(0, 0, 0.1), mass=20.0),
        Obj(
            name="bowl",
            mesh=(pts, faces),
            position=(0, 0, 0.2 + 0.08),
            collider=collider,
            supported_by="table",
            mass=0.3,
        ),
    ]


# --------------------------------------------------------------------------------------------------- import


def test_import_is_light() -> None:
    code = (
        "import sys, holousd, holousd.physics, holousd.physics._cli;"
        "heavy = [m for m in ('warp', 'newton', 'mujoco', 'mujoco_warp', 'torch', 'coacd') if m in sys.modules];"
        "print(','.join(heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


# ---------------------------------------------------------------------------------------------------- model


def test_model_honours_mass_com_friction_restitution() -> None:
    objs = _stack()
    objs[0].material = "Rubber"
    objs[1].mass = None  # density from the material: 0.2^3 m^3 * 500 kg/m^3 = 4 kg
    stage = make_scene(objs, materials=[Material(name="Wood"), Material(name="Rubber", friction=0.9, restitution=0.4)])
    UsdPhysics.MassAPI(stage.GetPrimAtPath(A)).CreateCenterOfMassAttr((0.0, 0.0, -0.05))
    pm = physics.build_model(stage)
    assert pm.body_paths == [A, B]
    assert pm.model.body_mass.numpy() == pytest.approx([1.0, 4.0], rel=1e-4)
    assert pm.model.body_com.numpy()[0] == pytest.approx([0.0, 0.0, -0.05], abs=1e-6)
    mu = dict(zip(pm.model.shape_label, pm.model.shape_material_mu.numpy(), strict=True))
    rest = dict(zip(pm.model.shape_label, pm.model.shape_material_restitution.numpy(), strict=True))
    assert mu[f"{A}/Collision"] == pytest.approx(0.9)  # bound on the Xform, inherited by the collider
    assert rest[f"{A}/Collision"] == pytest.approx(0.4)
    assert mu[f"{B}/Collision"] == pytest.approx(0.5)
    forced = physics.build_model(stage, config=physics.ModelConfig(friction=0.5))
    assert set(np.round(forced.model.shape_material_mu.numpy(), 6)) == {0.5}


def test_model_subset_static_chain_and_errors() -> None:
    stage = make_scene(_stack())
    pm = physics.build_model(stage, dynamic=[B], static=[A])
    assert pm.body_paths == [B] and pm.static_paths == [A]
    assert f"{A}/Collision" in pm.model.shape_label  # the support stays as static geometry
    assert stage.GetPrimAtPath(A).HasAPI(UsdPhysics.RigidBodyAPI)  # caller's stage untouched
    assert physics.support_chain(stage, B) == [A]
    with pytest.raises(physics.PhysicsInputError, match="/World/Objects/nope"):
        physics.build_model(stage, dynamic=["/World/Objects/nope"])
    empty = make_scene([])
    with pytest.raises(physics.PhysicsInputError, match="no rigid bodies"):
        physics.build_model(empty)


def test_units_are_checked() -> None:
    with pytest.raises(physics.PhysicsInputError, match="metersPerUnit is 0.01"):
        physics.build_model(make_scene(_stack(), meters_per_unit=0.01))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pm = physics.build_model(make_scene(_stack(), meters_per_unit=None))
    assert any("metersPerUnit is not authored" in str(w.message) for w in caught)
    assert pm.model.body_q.numpy()[1, 2] == pytest.approx(0.3)  # read as metres, not centimetres


# ---------------------------------------------------------------------------------------------- colliders


def test_hull_decomposition_and_how_newton_loads_them() -> None:
    bp, bf = box(0.1, 0.2, 0.3)
    hp, hf = physics.convex_hull(bp, bf)
    assert len(hp) == 8 and len(hf) == 12
    assert physics.convexity(bp, bf) == pytest.approx(1.0)
    pts, faces = bowl()
    assert physics.convexity(pts, faces) < 0.5
    parts = physics.convex_decomposition(pts, faces)
    assert 2 <= len(parts) <= physics.DecompositionConfig().max_parts
    for pp, pf in parts:
        assert pp.shape[1] == 3 and pf.shape[1] == 3 and physics.convexity(pp, pf) > 0.99
    # Our convention: explicit parts each with approximation convexHull load as convex hulls; the background
    # triangle mesh (approximation none) stays a triangle mesh unless it is exactly convex.
    import newton

    stage = make_scene(_bowl_on_table(collider=parts))
    pm = physics.build_model(stage, config=physics.ModelConfig(hull_convex_meshes=False))
    kinds = dict(zip(pm.model.shape_label, pm.model.shape_type.numpy(), strict=True))
    assert kinds["/World/Background/Geom"] == newton.GeoType.MESH
    # By default the exactly convex floor slab is collided as its hull (same geometry, cheaper contact).
    default = physics.build_model(stage)
    assert "/World/Background/Geom" not in default.model.shape_label
    floor = [k for k in default.model.shape_label if k.startswith("/World/Background/Geom_HoloParts/")]
    assert len(floor) == 1 and default.model.shape_type.numpy()[default.model.shape_label.index(floor[0])] == (
        newton.GeoType.CONVEX_MESH
    )
    bowl_parts = [k for k in kinds if k.startswith("/World/Objects/bowl/Collision/Part_")]
    assert len(bowl_parts) == len(parts)
    assert all(kinds[k] == newton.GeoType.CONVEX_MESH for k in bowl_parts)


def test_collider_choice_keeps_the_mesh_verdict() -> None:
    stage = make_scene(_bowl_on_table())
    cfg = physics.StabilityConfig(stop_when_decided=True)
    choice = physics.choose_object_collider(stage, "bowl", cfg)
    assert choice.kind == "decomposition"  # the bowl is far from convex: no hull candidate
    assert choice.reference_stable is True  # the triangle-mesh bowl rests on the table
    assert choice.tried == {"decomposition": True}
    assert choice.approximation == "convexHull" and len(choice.parts) >= 2
    # Parts come back in the bowl's own coordinates (rim at z = 0, foot at z = -0.08).
    lows = min(p[:, 2].min() for p, _ in choice.parts)
    assert lows == pytest.approx(-0.08, abs=2e-3)
    # The convex table keeps a hull: the simplest collider with the mesh's verdict.
    table = physics.choose_object_collider(stage, "table", cfg)
    assert table.kind == "hull" and table.tried == {"hull": True} and table.reference_stable is True
    # Without an oracle, convexity alone decides.
    pts, faces = bowl()
    assert physics.choose_collider(pts, faces).kind == "decomposition"


# --------------------------------------------------------------------------------------------- verdicts


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("stack", {A: True, B: True}),
        ("overhang", {A: True, B: False}),
        ("plank", {A: False}),
        ("tray", {A: True}),
    ],
)
def test_stability_verdicts_agree_across_solvers(case: str, expected: dict[str, bool]) -> None:
    # "tray": a box inside a concave static tray. MuJoCo collides meshes as hulls, which would fill the tray
    # and throw the box out; the model builder decomposes the tray for it, so the verdicts must still agree.
    if case == "tray":
        stage = make_scene(
            [Obj(name="a", mesh=box(0.05, 0.05, 0.05), position=(0, 0, 0.07))], extra_background=[tray()]
        )
    else:
        stage = make_scene({"stack": _stack, "overhang": _overhang, "plank": _leaning_plank}[case]())
    report = physics.stability(stage, cross_check="mujoco")
    assert report.solver == "xpbd"
    assert {o.name: o.stable for o in report.objects} == expected
    assert {o.name: o.stable for o in report.cross_check.objects} == expected
    assert report.cross_check.agreement_pct == 100.0
    assert report.stable_pct == pytest.approx(100.0 * sum(expected.values()) / len(expected))
    for o in report.objects:
        if not o.stable:
            assert o.translation_m > 0.02 or o.rotation_deg > 5.0


@pytest.mark.parametrize("solver", SOLVERS)
def test_alone_on_support_chain(solver: str) -> None:
    # Three stacked boxes; the top one overhangs the middle one: unstable alone, the others stable alone.
    objs = [
        Obj(name="a", mesh=box(0.1, 0.1, 0.1), position=(0, 0, 0.1)),
        Obj(name="b", mesh=box(0.1, 0.1, 0.1), position=(0, 0, 0.3), supported_by="a"),
        Obj(name="c", mesh=box(0.1, 0.1, 0.05), position=(0.15, 0, 0.45), supported_by="b"),
    ]
    stage = make_scene(objs)
    assert physics.support_chain(stage, "/World/Objects/c") == [B, A]
    cfg = physics.StabilityConfig(solver=solver, stop_when_decided=True)
    assert not physics.stability_alone(stage, "c", cfg).stable
    assert physics.stability_alone(stage, "b", cfg).stable


# ---------------------------------------------------------------------------------------------- energies


def test_penetrating_boxes_have_energy_and_are_pushed_apart() -> None:
    objs = [
        Obj(name="a", mesh=box(0.1, 0.1, 0.1), position=(0, 0, 0.1)),
        Obj(name="b", mesh=box(0.1, 0.1, 0.1), position=(0.15, 0, 0.1)),  # 5 cm overlap along x
    ]
    stage = make_scene(objs)

    def world_box(pos: np.ndarray, quat_wxyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts, faces = box(0.1, 0.1, 0.1)
        rot = Gf_rotation(quat_wxyz)
        return pts @ rot.T + pos, faces

    ident = np.array([1.0, 0, 0, 0])
    before = physics.e_pene_mesh(world_box(np.array([0, 0, 0.1]), ident), world_box(np.array([0.15, 0, 0.1]), ident))
    assert before == pytest.approx(0.05 * 0.2 * 0.2, rel=1e-3)
    traj = physics.simulate(stage, physics.SimulationConfig(seconds=0.5))
    after = physics.e_pene_mesh(
        world_box(traj.positions[A][-1], traj.orientations[A][-1]),
        world_box(traj.positions[B][-1], traj.orientations[B][-1]),
    )
    assert after < 0.05 * before
    gap = traj.positions[B][-1, 0] - traj.positions[A][-1, 0]
    assert gap > 0.19


def Gf_rotation(q: np.ndarray) -> np.ndarray:  # noqa: N802 - small helper mirroring Gf naming
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_e_pene_sdf_matches_analytic_overlap() -> None:
    # Two spheres of radius 0.1 whose centres are 0.1 apart: lens volume = pi (4r + d)(2r - d)^2 / 12.
    r, d, h = 0.1, 0.1, 0.004
    axis = np.arange(-0.15, 0.15 + 1e-9, h)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1)
    sdf_a = np.linalg.norm(grid, axis=-1) - r
    origin = np.array([axis[0]] * 3)
    energy = physics.e_pene_sdf(sdf_a, origin, h, sdf_a, origin + [d, 0, 0], h)
    lens = math.pi * (4 * r + d) * (2 * r - d) ** 2 / 12
    assert energy == pytest.approx(lens, rel=0.08)
    assert physics.e_pene_sdf(sdf_a, origin, h, sdf_a, origin + [0.5, 0, 0], h) == 0.0


def test_e_touch_and_e_stable() -> None:
    objs = _stack()
    objs[1].position = (0, 0, 0.33)  # 3 cm gap above its support
    stage = make_scene(objs)
    touch = physics.e_touch(stage)
    assert touch[A] == pytest.approx(0.0, abs=1e-6)  # resting on the floor slab (the background)
    assert touch[B] == pytest.approx(0.03, abs=1e-4)
    traj = physics.simulate(stage, physics.SimulationConfig(seconds=0.5))
    energy = physics.e_stable(traj)
    drop = traj.translation_m(B)[-1]
    assert drop == pytest.approx(0.03, abs=0.005)
    assert energy[B] == pytest.approx(drop + math.radians(traj.rotation_deg(B)[-1]))
    assert energy[A] < 0.005


# -------------------------------------------------------------------------------------- damping, impulses


@pytest.mark.parametrize("solver", SOLVERS)
def test_linear_damping_follows_the_ode(solver: str) -> None:
    # Free fall from 1 m for 0.3 s: dv/dt = -g - c v  =>  drop = g t / c - g (1 - exp(-c t)) / c^2.
    g, c, t = 9.81, 4.0, 0.3
    undamped = make_scene([Obj(name="a", mesh=box(0.1, 0.1, 0.1), position=(0, 0, 1.0))])
    damped = make_scene([Obj(name="a", mesh=box(0.1, 0.1, 0.1), position=(0, 0, 1.0), linear_damping=c)])
    cfg = physics.SimulationConfig(seconds=t, solver=physics.SolverConfig(name=solver))
    free = physics.simulate(undamped, cfg).translation_m(A)[-1]
    slow = physics.simulate(damped, cfg).translation_m(A)[-1]
    assert free == pytest.approx(0.5 * g * t * t, rel=0.03)
    assert slow == pytest.approx(g * t / c - g * (1 - math.exp(-c * t)) / c**2, rel=0.03)
    off = physics.simulate(damped, physics.SimulationConfig(seconds=t, apply_damping=False))
    assert off.translation_m(A)[-1] == pytest.approx(free, rel=1e-3)


def test_angular_damping_decays_spin() -> None:
    stage = make_scene([Obj(name="a", mesh=box(0.1, 0.1, 0.1), position=(0, 0, 2.0), angular_damping=3.0)])
    pm = physics.build_model(stage)
    assert pm.angular_damping.tolist() == [3.0] and pm.linear_damping.tolist() == [0.0]
    stepper = make_stepper(pm)
    stepper.add_velocity(0, np.zeros(3), np.array([0.0, 0.0, 2.0]))
    factor = np.exp(-pm.angular_damping / 240)
    for _ in range(60):
        stepper.step(1 / 240)
        stepper.scale_velocities(np.ones(1), factor)
    assert stepper.body_qd[0, 5] == pytest.approx(2.0 * math.exp(-3.0 * 0.25), rel=0.02)


# ------------------------------------------------------------------------------------------- trajectories


def test_trajectory_layer_round_trips(tmp_path) -> None:
    scene = tmp_path / "scene.usda"
    stage = make_scene(_overhang(), path=str(scene))
    traj = physics.simulate(stage, physics.SimulationConfig(seconds=0.5), impulses={B: (0.2, 0.0, 0.0)})
    out = tmp_path / "anim" / "motion.usda"
    physics.write_trajectory_layer(traj, scene, out, fps=60)
    written = sorted(str(p.relative_to(out.parent)) for p in out.parent.rglob("*") if p.is_file())
    assert written == ["assets/motion/arrays.usdc", "motion.usda"]  # the samples in crate form; no temp files left
    anim = Usd.Stage.Open(str(out))
    assert anim.GetTimeCodesPerSecond() == 60 and anim.GetEndTimeCode() == 30
    assert UsdGeom.GetStageUpAxis(anim) == UsdGeom.Tokens.z and UsdGeom.GetStageMetersPerUnit(anim) == 1.0
    prim = anim.GetPrimAtPath(B)
    assert prim.GetAttribute("xformOp:translate").GetNumTimeSamples() == 31
    assert prim.GetChild("Geom").IsValid()  # the scene is sublayered, so geometry composes
    for frame, k in ((0, 0), (30, -1)):
        world = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode(frame))
        assert np.array(world.ExtractTranslation()) == pytest.approx(traj.positions[B][k], abs=1e-5)
        q = world.ExtractRotationQuat()
        wxyz = np.array([q.GetReal(), *q.GetImaginary()])
        assert abs(float(wxyz @ traj.orientations[B][k])) == pytest.approx(1.0, abs=1e-5)
    assert traj.positions[B][-1, 0] > 0.3  # the push carried it off the pedestal


# ------------------------------------------------------------------------------------------------------ CLI


def _run_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="holousd")
    _cli.add_commands(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.handler(args)


def test_cli_stability_json(tmp_path, capsys) -> None:
    scene = tmp_path / "scene.usda"
    make_scene(_overhang(), path=str(scene))
    assert _run_cli(["stability", str(scene), "--json", "--cross-check"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["stable_pct"] == 50.0
    fields = {"name": str, "translation_m": float, "rotation_deg": float, "stable": bool}
    for obj in data["objects"] + data["cross_check"]["objects"]:
        assert set(obj) == set(fields) and all(isinstance(obj[k], t) for k, t in fields.items())
    assert [o["name"] for o in data["objects"]] == [A, B]
    assert data["cross_check"]["solver"] == "mujoco" and data["cross_check"]["agreement_pct"] == 100.0
    assert _run_cli(["stability", str(scene), "--json", "--seconds", "0.5"]) == 0
    assert "cross_check" not in json.loads(capsys.readouterr().out)


def test_cli_stability_takes_the_xpbd_iteration_count(tmp_path, capsys, monkeypatch) -> None:
    import holousd.physics._stability as stability_module

    scene = tmp_path / "scene.usda"
    make_scene(_stack(), path=str(scene))
    seen = []
    real = stability_module.stability

    def spy(source, config=None, **kwargs):  # noqa: ANN001, ANN202
        seen.append(config.iterations)
        return real(source, config, **kwargs)

    monkeypatch.setattr(stability_module, "stability", spy)
    assert _run_cli(["stability", str(scene), "--json", "--seconds", "0.25", "--xpbd-iterations", "12"]) == 0
    assert seen == [12] and json.loads(capsys.readouterr().out)["xpbd_iterations"] == 12
    assert _run_cli(["stability", str(scene), "--xpbd-iterations", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--xpbd-iterations 0" in err[0] and seen == [12]


def test_cli_simulate_push_writes_layer(tmp_path, capsys) -> None:
    scene = tmp_path / "scene.usda"
    make_scene(_stack(), path=str(scene))
    out = tmp_path / "motion.usda"
    rc = _run_cli(["simulate", str(scene), "--seconds", "0.25", "--out", str(out), "--push", "b=1.5,0,0", "--json"])
    assert rc == 0
    data = json.loads(capsys.readouterr().out)
    moved = {o["name"]: o["final_position_m"] for o in data["objects"]}
    assert moved[B][0] > 0.1 and abs(moved[A][0]) < 0.05
    assert Usd.Stage.Open(str(out)).GetPrimAtPath(B).GetAttribute("xformOp:translate").GetNumTimeSamples() > 1


def test_cli_errors_name_the_culprit(tmp_path, capsys) -> None:
    missing = tmp_path / "nope.usda"
    assert _run_cli(["stability", str(missing)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(missing) in err[0]
    broken = tmp_path / "broken.usda"
    broken.write_text("#usda 1.0\n(\n  this is not usd\n")
    assert _run_cli(["stability", str(broken)]) == 2
    assert str(broken) in capsys.readouterr().err
    empty = tmp_path / "empty.usda"
    make_scene([], path=str(empty))
    assert _run_cli(["stability", str(empty), "--json"]) == 2
    captured = capsys.readouterr()
    assert "no rigid bodies" in captured.err and str(empty) in captured.err and captured.out == ""
    scene = tmp_path / "scene.usda"
    make_scene(_stack(), path=str(scene))
    assert _run_cli(["simulate", str(scene), "--push", "ghost=1,0,0"]) == 2
    assert "'ghost'" in capsys.readouterr().err
    assert _run_cli(["simulate", str(scene), "--push", "b=1,0"]) == 2
    assert "OBJECT=FX,FY,FZ" in capsys.readouterr().err


def test_cli_help_shows_defaults(capsys) -> None:
    with pytest.raises(SystemExit):
        _run_cli(["stability", "--help"])
    assert "(default: 2.0)" in capsys.readouterr().out


def test_hollow_room_shell_is_not_filled_by_hulls() -> None:
    # A static room shell (outer box + inward-facing inner box) as one triangle mesh: its connected pieces are
    # each convex, but hulling them one by one would fill the room and throw the box inside it out.
    outer_p, outer_f = box(0.5, 0.5, 0.5)
    inner_p, inner_f = box(0.4, 0.4, 0.4)
    outer_p[:, 2] += 0.4
    inner_p[:, 2] += 0.4
    shell = (np.concatenate([outer_p, inner_p]), np.concatenate([outer_f, inner_f[:, ::-1] + len(outer_p)]))
    stage = make_scene([Obj(name="a", mesh=box(0.05, 0.05, 0.05), position=(0, 0, 0.05))], extra_background=[shell])
    (verdict,) = physics.stability(stage).objects
    assert verdict.stable, verdict


def test_detailed_hull_keeps_its_flat_bottom() -> None:
    # 130-vertex ball cut flat at the bottom: Newton's default 64-vertex hull cap rounded the flat off and the
    # ball rolled ~30 degrees; ModelConfig.max_hull_vertices keeps every hull vertex.
    from holousd.synth._catalog import _ball

    ball = _ball(0.06)
    assert len(ball.points) > 64
    stage = make_scene([Obj(name="a", mesh=(ball.points, ball.faces), position=(0, 0, 0))])
    (verdict,) = physics.stability(stage).objects
    assert verdict.stable, verdict


def _parts(data: np.lib.npyio.NpzFile, name: str) -> list[tuple[np.ndarray, np.ndarray]]:
    points, faces, part = data[f"{name}_points"].astype(float), data[f"{name}_faces"], data[f"{name}_part"]
    out = []
    for i in np.unique(part):
        used, local = np.unique(faces[part == i], return_inverse=True)
        out.append((points[used] + [0.0, 0.0, 0.5], local.reshape(-1, 3)))
    return out


def test_mujoco_sees_no_contact_where_hulls_only_touch() -> None:
    # bench_00 (fast) at dc71cff: a box of 39 convex parts on its shelf (the shelf's 31 parts near it, the scene's
    # own collider parts, tests/data). Newton hands MuJoCo its broad-phase gap (0.1 m) as every geom's gap, and
    # MuJoCo 4.0's multi-point contacts then reported penetrations of 9-16 mm where the box's parts rest on the
    # board: alone on the whole shelf the box tipped 17 deg; on these parts of it, it was thrown 14 cm and turned
    # 20 deg; XPBD kept it within 3 mm
    from holousd.physics._solvers import SolverConfig

    data = np.load(Path(__file__).parent / "data" / "mujoco_box_on_shelf.npz")
    box_parts, shelf_parts = _parts(data, "box"), _parts(data, "shelf")
    mesh = (data["box_mesh_points"].astype(float) + [0.0, 0.0, 0.5], data["box_mesh_faces"])
    stage = make_scene([Obj(name="shelf", mesh=shelf_parts[0], collider=shelf_parts, position=(0, 0, 0), mass=20.0),
                        Obj(name="box", mesh=mesh, collider=box_parts, position=(0, 0, 0), mass=float(data["mass"]),
                            supported_by="shelf")])  # fmt: skip
    for solver in SOLVERS:
        verdict = physics.stability_alone(stage, "box", physics.StabilityConfig(solver=solver))
        assert verdict.stable and verdict.rotation_deg < 1.0, (solver, verdict)
    pm = physics.build_model(stage)
    gaps = pm.model.shape_gap.numpy().copy()
    stepper = make_stepper(pm, SolverConfig(name="mujoco"))
    assert np.all(stepper._solver.mj_model.geom_gap == 0.0)
    assert np.array_equal(pm.model.shape_gap.numpy(), gaps) and np.all(gaps > 0)  # Newton's own pipeline keeps it


def test_mujoco_gets_an_arena_that_holds_a_decomposed_scene_contacts() -> None:
    # MuJoCo's own 13 MiB arena overflowed on the phone demo (25 thousand contacts between decomposed colliders):
    # it dropped contacts every step and the ball fell 78 cm through the cabinet's top
    from holousd.physics._solvers import SolverConfig

    pm = physics.build_model(make_scene(_stack()))
    stepper = make_stepper(pm, SolverConfig(name="mujoco"))
    assert stepper._solver.mj_model.narena == 256 * 1024 * 1024
    small = make_stepper(physics.build_model(make_scene(_stack())), SolverConfig(name="mujoco", mujoco_arena_mb=0.5))
    assert small._solver.mj_model.narena == 512 * 1024
    z0 = stepper.body_q[:, 2].copy()
    for _ in range(48):
        stepper.step(1.0 / 240.0)
    assert stepper.dropped_contacts == 0 and np.allclose(stepper.body_q[:, 2], z0, atol=2e-3)
    assert make_stepper(pm, SolverConfig(name="xpbd")).dropped_contacts == 0
    import mujoco

    from holousd.physics._solvers import _arena

    # the counter reads MuJoCo's own overflow warnings (contacts, and the constraints that hold them)
    warning = stepper._solver.mj_data.warning
    warning[int(mujoco.mjtWarning.mjWARN_CONTACTFULL)].number = 2
    warning[int(mujoco.mjtWarning.mjWARN_CNSTRFULL)].number = 1
    assert stepper.dropped_contacts == 3
    # the arena is given only while a solver is built: MuJoCo's compile is its own again, after an error too
    original = mujoco.MjSpec.compile
    with pytest.raises(RuntimeError), _arena(1.0):
        assert mujoco.MjSpec.compile is not original
        raise RuntimeError("a solver that fails to build")
    assert mujoco.MjSpec.compile is original
    # an arena too small for MuJoCo's own stack is a one-line error naming the setting, not a FatalError
    tiny = make_stepper(pm, SolverConfig(name="mujoco", mujoco_arena_mb=0.02))
    with pytest.raises(physics.PhysicsInputError, match="mujoco_arena_mb"):
        for _ in range(4):
            tiny.step(1.0 / 240.0)


def test_xpbd_doubles_its_contact_buffer_when_a_step_finds_more_contacts() -> None:
    # Newton sizes the buffer from an estimate and drops what does not fit: hard/stack's phone capture (decomposed
    # colliders, 22751 contacts in a buffer of 22750) had every body thrown tens of metres
    import newton

    pm = physics.build_model(make_scene(_stack()))
    stepper = make_stepper(pm)
    stepper._pipeline = newton.CollisionPipeline(pm.model, rigid_contact_max=2)  # far fewer than a box on a box
    stepper._contacts = stepper._pipeline.contacts()
    z0 = stepper.body_q[:, 2].copy()
    for _ in range(48):
        stepper.step(1.0 / 240.0)
    assert stepper.contact_growths == 3 and stepper._contacts.rigid_contact_max == 16  # 8 contacts: 2 -> 16
    assert int(stepper._contacts.rigid_contact_count.numpy()[0]) < stepper._contacts.rigid_contact_max
    assert np.allclose(stepper.body_q[:, 2], z0, atol=2e-3)  # the stack stands on the contacts it keeps
