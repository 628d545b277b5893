"""End-to-end evaluation of a reconstruction against a ``holousd synth`` scene's ground truth (``holousd eval``).

Geometry (ARCHITECTURE.md section 5): Chamfer (cm), F-score at 5 cm and normal consistency x100 from
:func:`holousd.eval.evaluate_fit`, objects matched by instance id; ``scene`` = all objects together (ground-truth
side restricted to the samples some camera saw), ``objects`` = mean over the matched ground-truth objects, each
against its complete ground-truth surface (so the unseen backs count: this is where completion shows).
Render: the reconstructed splats rendered at the capture's held-out cameras (frames the pipeline's appearance
stage did not fit; all frames when none is held out) against the captured images; null when there are no splats.
``mesh_psnr``: the same frames ray-cast from the meshes in the colour baked onto them (what tools that read no
splats show, unlit: the texture where a mesh has one), on every other held-out frame; ``vertex_psnr``: the same
with the per-point colour alone (the fallback of tools that read no textures); null when no mesh carries baked
colour.
Physics: OR% (ground-truth objects with a reconstructed mesh), Stable% (stable reconstructed objects matched to a
ground-truth object / ground-truth objects, :func:`holousd.physics.stability` on the whole reconstructed scene)
and the summed pairwise intersection volume of the objects' meshes (cm^3).
Cost: wall time and peak memory per stage from the stage layers' records.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from holousd._errors import HolousdError
from holousd._sampling import evenly_spaced

__all__ = ["EvalConfig", "ObjectRow", "SceneEvaluation", "evaluate_scene", "resolve_gt", "resolve_scene"]


@dataclass(kw_only=True)
class EvalConfig:
    """Settings of :func:`evaluate_scene`."""

    samples: int = 200_000
    """Surface samples over all objects for the geometry metrics."""
    threshold: float = 0.05
    """F-score threshold, metres."""
    render_frames: int = 8
    """Most held-out frames rendered for PSNR / SSIM."""
    physics: bool = True
    """Run the stability verdict (the slowest part; off: stable_pct is null)."""
    cross_check: str | None = "mujoco"
    """Second solver whose Stable% and agreement are reported beside the primary's (None: not run)."""
    seed: int = 0
    """Seed of the surface sampling."""
    log: Callable[[str], None] | None = None
    """Called with a progress line per step (geometry, render, stability in quarters); None: silent."""


@dataclass(kw_only=True)
class ObjectRow:
    """One ground-truth object in the per-object table."""

    name: str
    """Ground-truth object name."""
    instance_id: int
    """Instance id (shared by ground truth and reconstruction)."""
    recon: str | None
    """Reconstructed node name, or None when it is missing."""
    chamfer_cm: float | None
    """Chamfer distance of its own mesh against its complete ground-truth surface, cm."""
    f1: float | None
    """F-score at the threshold against the complete surface, percent."""
    nc: float | None
    """Normal consistency x100 against the complete surface."""
    f1_visible: float | None = None
    """F-score against the observed part of its surface only, percent."""
    stable: bool | None
    """Stability verdict of the reconstructed object (None: missing or not simulated)."""
    translation_m: float | None
    """Largest drift of the reconstructed object in the verdict, metres."""
    rotation_deg: float | None
    """Largest rotation of the reconstructed object in the verdict, degrees."""
    parent_gt: str | None = None
    """Ground-truth support parent."""
    parent_recon: str | None = None
    """Reconstructed support parent (ground-truth name when it maps to one)."""
    fit_shift_cm: float | None = None
    """How far the physics set-up moved the reconstructed object from its fitted pose, cm (its record)."""
    collider_reach_cm: float | None = None
    """How far its collider reaches outside its rendered mesh, cm (its record)."""
    penetration_cm: float | None = None
    """Its rendered mesh's deepest penetration into another node, cm (its record)."""
    stable_cross_check: bool | None = None
    """Its verdict in the cross-check solver (MuJoCo by default; None: missing, or no cross-check run)."""
    translation_cross_check_m: float | None = None
    """Its largest drift in the cross-check solver's verdict, metres."""
    rotation_cross_check_deg: float | None = None
    """Its largest rotation in the cross-check solver's verdict, degrees."""


@dataclass(kw_only=True)
class SceneEvaluation:
    """Everything ``holousd eval`` reports; :meth:`to_dict` gives the JSON layout."""

    geometry: dict[str, dict[str, float | None]]
    """``{"scene": {chamfer_cm, f1, nc}, "objects": {chamfer_cm, f1, nc}}``."""
    render: dict[str, float | None]
    """``{psnr, ssim}`` (null without splats)."""
    physics: dict[str, Any]
    """``{or_pct, stable_pct, penetration_cm3, solver, cross_check: {solver, stable_pct, agreement_pct} | null,
    search_agreement_pct, max_fit_shift_cm, max_collider_reach_cm, max_penetration_cm}``: ``search_agreement_pct``
    is the share of the objects the s2 search scored whose search verdict (its quasi-static E_stable) the
    primary solver repeats on the shipped scene (null without search records); the last three are the worst
    object's ``HoloGeometryAPI`` record (null when no object has one)."""
    cost: dict[str, Any]
    """``{total_s, stages: {name: seconds}, peak_mem_mb}``."""
    objects: list[ObjectRow] = field(default_factory=list)
    """Per-object table."""
    notes: list[str] = field(default_factory=list)
    """What could not be measured and why."""
    scene_file: str = ""
    """The evaluated scene."""
    gt_dir: str = ""
    """The synth scene folder."""
    support_accuracy_pct: float | None = None
    """Reconstructed objects whose support parent is the ground truth's, percent of matched objects."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with exactly the keys geometry, render, physics, cost, objects (per-object table) and
        notes; the support accuracy is one of the notes."""
        notes = list(self.notes)
        if self.support_accuracy_pct is not None:
            notes.append(f"support: {self.support_accuracy_pct:.0f}% of the matched objects rest on their "
                         "ground-truth parent")  # fmt: skip
        return {
            "geometry": self.geometry,
            "render": self.render,
            "physics": self.physics,
            "cost": self.cost,
            "objects": [asdict(o) for o in self.objects],
            "notes": notes,
        }


def resolve_gt(path: str | os.PathLike[str]) -> Path:
    """The synth scene folder from either that folder or its ``gt/`` folder."""
    path = Path(path)
    if (path / "gt" / "graph.json").is_file():
        return path
    if (path / "graph.json").is_file() and path.name == "gt":
        return path.parent
    raise HolousdError(f"{path}: no gt/graph.json here; give a `holousd synth` scene folder or its gt/ folder")


def resolve_scene(path: str | os.PathLike[str]) -> Path:
    """The scene file of a reconstruction: the file itself, or ``<folder>/scene.usda``."""
    path = Path(path)
    if path.is_file():
        return path
    if (path / "scene.usda").is_file():
        return path / "scene.usda"
    raise HolousdError(f"{path}: no scene.usda here; give a `holousd reconstruct` output folder or a scene file")


def _clean(value: float | None) -> float | None:
    if value is None or not np.isfinite(value):
        return None
    return float(value)


def _mean_metrics(metrics: list[Any]) -> dict[str, float | None]:
    """Mean Chamfer / F1 / NC over per-object metrics (all None when there are none)."""
    if not metrics:
        return {"chamfer_cm": None, "f1": None, "nc": None}
    return {"chamfer_cm": _clean(np.mean([m.chamfer_cm for m in metrics])),
            "f1": _clean(np.mean([m.fscore for m in metrics])),
            "nc": _clean(np.mean([m.normal_consistency for m in metrics]))}  # fmt: skip


def _render_metrics(scene: Any, gt_dir: Path, config: EvalConfig, notes: list[str]) -> dict[str, float | None]:
    from holousd.eval._image import psnr, ssim
    from holousd.io import load
    from holousd.render import Camera, SceneRenderer
    from holousd.stages._fit import observations_as_fitted
    from holousd.stages._pipeline import holdout_frames

    try:
        renderer = SceneRenderer(scene, background=(0.0, 0.0, 0.0))
    except HolousdError as exc:
        notes.append(f"render: no splats to render ({exc})")
        return {"psnr": None, "ssim": None, "mesh_psnr": None, "vertex_psnr": None}
    if renderer.splat_count == 0:
        notes.append("render: the scene has no Gaussian splats (appearance stage not run); PSNR/SSIM are null")
        return {"psnr": None, "ssim": None, "mesh_psnr": None, "vertex_psnr": None}
    obs = observations_as_fitted(load(gt_dir), scene)  # rendered from where the fit put the cameras
    frames = holdout_frames(len(obs)) or list(range(len(obs)))
    frames = [frames[i] for i in evenly_spaced(len(frames), config.render_frames)]
    p, s = [], []
    for i in frames:
        cam = Camera.from_intrinsics(obs.intrinsics[i], obs.poses[i], obs.width, obs.height)
        image = renderer.render(cam).color.detach().cpu().numpy()[..., :3]
        ref = np.asarray(obs.rgb(i))[..., :3].astype(np.float32) / 255.0
        p.append(psnr(image, ref))
        s.append(ssim(image, ref))
    notes.append(f"render: {len(frames)} held-out frames {frames}")
    out: dict[str, float | None] = {"psnr": float(np.mean(p)), "ssim": float(np.mean(s))}
    out["mesh_psnr"], out["vertex_psnr"] = _mesh_psnr(scene, obs, frames, notes)
    return out


def _mesh_psnr(scene: Any, obs: Any, frames: list[int], notes: list[str]) -> tuple[float | None, float | None]:
    """Held-out PSNR of the meshes coloured as other tools show them: (with each mesh's baked texture where it has
    one, else its per-point colour; with the per-point colour ``primvars:displayColor`` alone), one ray per pixel
    centre, no lighting, sRGB-encoded, on every other held-out frame; None when no mesh is coloured."""
    import trimesh

    from holousd.eval._image import psnr
    from holousd.render import Camera
    from holousd.render._bake import sample_texture, srgb_from_linear
    from holousd.render._raycast import raycast
    from holousd.usd import MeshData

    meshes, colours, textures = [], [], []
    for node in scene.nodes():
        colour = scene.get_surface_color(node.name)
        if colour is None:
            continue
        mesh = scene.get_mesh(node.name)
        meshes.append(MeshData(points=scene.get_pose(node.name).apply(mesh.points), faces=mesh.faces))
        colours.append(srgb_from_linear(colour))
        textures.append(scene.get_surface_texture(node.name))
    if not meshes:
        notes.append("render: no mesh carries baked colour (primvars:displayColor); mesh PSNR is null")
        return None, None
    if not any(t is not None for t in textures):
        notes.append("render: no mesh carries a baked texture; mesh PSNR is that of the per-point colours")
    shown, per_point = [], []
    for i in frames[::2]:
        cam = Camera.from_intrinsics(obs.intrinsics[i], obs.poses[i], obs.width, obs.height)
        hits = raycast(meshes, cam, chunk=1 << 21)  # bounded memory: at most 2M ray-triangle pairs at once
        image = np.zeros((len(hits.mesh), 3))
        textured = np.zeros((len(hits.mesh), 3))
        for k in np.unique(hits.mesh[hits.mesh >= 0]):
            hit = np.flatnonzero(hits.mesh == k)
            face_index = hits.face[hit]
            faces = np.asarray(meshes[k].faces)[face_index]
            weights = trimesh.triangles.points_to_barycentric(np.asarray(meshes[k].points)[faces], hits.points[hit])
            weights = np.clip(weights, 0, 1)
            image[hit] = np.einsum("rv,rvc->rc", weights, colours[k][faces])
            if textures[k] is None:
                textured[hit] = image[hit]
            else:
                st, texels = textures[k]
                textured[hit] = sample_texture(texels, np.einsum("rv,rvc->rc", weights, st[face_index]))
        reference = np.asarray(obs.rgb(i))[..., :3].astype(np.float32) / 255.0
        per_point.append(psnr(image.reshape(reference.shape).astype(np.float32), reference))
        shown.append(psnr(textured.reshape(reference.shape).astype(np.float32), reference))
    return float(np.mean(shown)), float(np.mean(per_point))


def _penetration_cm3(world: dict[str, tuple[np.ndarray, np.ndarray]], notes: list[str]) -> float:
    from holousd.physics import PhysicsInputError, e_pene_mesh

    names = sorted(world)
    bounds = {n: (world[n][0].min(0), world[n][0].max(0)) for n in names}
    total, failed = 0.0, 0
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if np.any(bounds[a][0] > bounds[b][1]) or np.any(bounds[b][0] > bounds[a][1]):
                continue
            try:
                total += e_pene_mesh(world[a], world[b])
            except PhysicsInputError:
                failed += 1
    if failed:
        notes.append(f"penetration: {failed} overlapping pair(s) skipped (a mesh is not a closed manifold)")
    return total * 1e6


def evaluate_scene(recon: str | os.PathLike[str], gt: str | os.PathLike[str],
                   config: EvalConfig | None = None) -> SceneEvaluation:  # fmt: skip
    """Evaluate a reconstruction (folder with ``scene.usda`` or a scene file) against a synth scene.

    Args:
        recon: ``holousd reconstruct`` output folder or scene file.
        gt: Synth scene folder (holding the capture and ``gt/``) or its ``gt/`` folder.
        config: Settings.
    """
    from holousd.eval._geometry import evaluate_fit
    from holousd.stages._pipeline import read_stage_records
    from holousd.usd._scene import SceneGraph

    config = config or EvalConfig()
    say = config.log or (lambda _line: None)
    scene_file = resolve_scene(recon)  # the argument named first is checked first
    gt_dir = resolve_gt(gt)
    notes: list[str] = []
    graph = json.loads((gt_dir / "gt" / "graph.json").read_text())
    gt_objects = {int(n["instance_id"]): n for n in graph["nodes"] if n.get("role") == "object"}

    say(f"eval: geometry ({config.samples} surface samples)")
    report = evaluate_fit(gt_dir, scene_file, samples=config.samples, threshold=config.threshold, seed=config.seed)
    geometry = {
        "scene": {
            "chamfer_cm": _clean(report.visible.chamfer_cm),
            "f1": _clean(report.visible.fscore),
            "nc": _clean(report.visible.normal_consistency),
        },  # fmt: skip
        "objects": _mean_metrics(list(report.per_object_complete.values())),
    }

    scene = SceneGraph.open(scene_file)
    recon_of_id: dict[int, str] = {}
    world: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for info in scene.nodes():
        if info.role != "object":
            continue
        recon_of_id[info.instance_id] = info.name
        try:
            mesh = scene.get_mesh(info.name)
        except HolousdError:
            continue
        if len(mesh.faces):
            world[info.name] = (scene.get_pose(info.name).apply(mesh.points), mesh.faces)

    say("eval: rendering the held-out frames")
    render = _render_metrics(scene, gt_dir, config, notes)

    verdicts: dict[str, Any] = {}
    second: dict[str, Any] = {}
    stable_pct: float | None = None
    cross: dict[str, Any] | None = None
    primary: str | None = None
    if config.physics:
        from holousd.physics import stability

        said: set[tuple[str, int]] = set()

        def tick(solver: str, fraction: float) -> None:
            quarter = int(fraction * 4)
            if (solver, quarter) not in said:  # each solver's run reports its own quarters
                said.add((solver, quarter))
                say(f"eval: stability ({solver}, 2 s simulated) {25 * quarter}%")

        say("eval: stability verdict (the first run on a machine compiles Newton's kernels: a few minutes)")
        try:
            result = stability(scene_file, progress=tick, cross_check=config.cross_check)
        except HolousdError as exc:
            notes.append(f"physics: no stability verdict ({exc})")
        else:
            verdicts = {o.name.rsplit("/", 1)[-1]: o for o in result.objects}
            primary = result.solver
            stable = sum(1 for k, name in recon_of_id.items() if k in gt_objects and name in verdicts
                         and verdicts[name].stable)  # fmt: skip
            stable_pct = 100.0 * stable / max(1, len(gt_objects))
            if result.cross_check is not None:
                second = {o.name.rsplit("/", 1)[-1]: o for o in result.cross_check.objects}
                stable2 = sum(1 for k, name in recon_of_id.items() if k in gt_objects and name in second
                              and second[name].stable)  # fmt: skip
                cross = {"solver": result.cross_check.solver, "stable_pct": 100.0 * stable2 / max(1, len(gt_objects)),
                         "agreement_pct": float(result.cross_check.agreement_pct)}  # fmt: skip
    else:
        notes.append("physics: stability not simulated (--no-physics)")
    penetration = _penetration_cm3(world, notes)

    rows: list[ObjectRow] = []
    agree = matched = 0
    for k, node in sorted(gt_objects.items()):
        name = recon_of_id.get(k) if recon_of_id.get(k) in world else None
        metrics = report.per_object_complete.get(node["name"])
        seen = report.per_object.get(node["name"])
        verdict = verdicts.get(name) if name else None
        crossed = second.get(name) if name else None
        parent_recon = None
        if name is not None:
            parent = scene.get_support(name)
            if parent is not None and parent != "background":
                pid = scene.node_info(parent).instance_id
                parent_recon = gt_objects[pid]["name"] if pid in gt_objects else parent
            else:
                parent_recon = parent
            matched += 1
            agree += int(parent_recon == node.get("parent"))
        rows.append(ObjectRow(
            name=node["name"], instance_id=k, recon=name,
            chamfer_cm=_clean(metrics.chamfer_cm) if metrics else None, f1=_clean(metrics.fscore) if metrics else None,
            nc=_clean(metrics.normal_consistency) if metrics else None,
            f1_visible=_clean(seen.fscore) if seen else None,
            stable=verdict.stable if verdict else None, translation_m=verdict.translation_m if verdict else None,
            rotation_deg=verdict.rotation_deg if verdict else None, parent_gt=node.get("parent"),
            parent_recon=parent_recon,
            stable_cross_check=crossed.stable if crossed else None,
            translation_cross_check_m=crossed.translation_m if crossed else None,
            rotation_cross_check_deg=crossed.rotation_deg if crossed else None,
            **_record_cm(scene, name),
        ))  # fmt: skip

    records = read_stage_records(scene_file.parent)
    if records:
        cost = {"total_s": float(sum(r.wall_s for r in records)), "stages": {r.name: float(r.wall_s) for r in records},
                "peak_mem_mb": float(max(r.peak_mem_mb for r in records))}  # fmt: skip
    else:
        cost = {"total_s": None, "stages": {}, "peak_mem_mb": None}
        notes.append("cost: no stage records beside the scene (not written by holousd reconstruct)")
    return SceneEvaluation(
        geometry=geometry,
        render=render,
        physics={
            "or_pct": float(report.object_rate),
            "stable_pct": stable_pct,
            "penetration_cm3": float(penetration),
            "solver": primary,
            "cross_check": cross,
            "search_agreement_pct": _search_agreement(scene, verdicts),
            **_worst_records(rows),
        },
        cost=cost,
        objects=rows,
        notes=notes,
        scene_file=str(scene_file),
        gt_dir=str(gt_dir),
        support_accuracy_pct=100.0 * agree / matched if matched else None,
    )


def _record_cm(scene: Any, name: str | None) -> dict[str, float | None]:
    """An object's geometry record (HoloGeometryAPI) in cm, for its row (``scene``: a SceneGraph)."""
    record = scene.get_geometry_record(name) if name is not None else None
    if record is None:
        return {"fit_shift_cm": None, "collider_reach_cm": None, "penetration_cm": None}
    return {"fit_shift_cm": 100.0 * float(np.linalg.norm(record.fit_shift)),
            "collider_reach_cm": 100.0 * float(record.collider_reach),
            "penetration_cm": 100.0 * float(record.penetration)}  # fmt: skip


def _search_agreement(scene: Any, verdicts: dict[str, Any]) -> float | None:
    """Of the objects the s2 search scored (``HoloEnergyAPI``), the share whose search verdict (E_stable 0, or
    chosen as standing once its parent is set up: stands) the primary solver's protocol verdict on the shipped
    scene repeats, %; None without either."""
    same = []
    for name, verdict in verdicts.items():
        energies = scene.get_energies(name) if name in scene.objects() else None
        if energies is not None and energies.chosen is not None:
            same.append(energies.stands == verdict.stable)
    return 100.0 * sum(same) / len(same) if same else None


def _worst_records(rows: list[ObjectRow]) -> dict[str, float | None]:
    """The worst object's records: ``max_fit_shift_cm``, ``max_collider_reach_cm``, ``max_penetration_cm``."""
    out: dict[str, float | None] = {}
    for key in ("fit_shift_cm", "collider_reach_cm", "penetration_cm"):
        values = [getattr(r, key) for r in rows if getattr(r, key) is not None]
        out[f"max_{key}"] = float(max(values)) if values else None
    return out
