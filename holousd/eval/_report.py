"""``holousd demo``: synthesise the demo scene, reconstruct it, evaluate it and write a one-page HTML report.

The report (``report.html``, images embedded) shows input frames, a novel-view render of the reconstructed
splats, the reconstructed meshes from the same camera (one colour per object), the inferred support tree next to
the ground truth's, the per-object stability and geometry table, the speed-vs-accuracy chart (this run beside the
reference ``holousd bench`` runs shipped in ``holousd/eval/reference/``), the cost per stage and F1 per object,
and the headline metrics.
"""

from __future__ import annotations

import base64
import html
import io
import json
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from holousd._atomic import atomic_path
from holousd._sampling import evenly_spaced

__all__ = ["DemoConfig", "bar_chart", "mesh_view", "reference_runs", "run_demo", "write_report"]

REFERENCE_DIR = Path(__file__).parent / "reference"
"""Committed ``holousd bench`` results (``bench.json`` of the bench suite, ``hard.json`` of the hard suite, and the
older runs the README keeps beside them)."""


@dataclass(kw_only=True)
class DemoConfig:
    """Settings of :func:`run_demo`."""

    frames: int = 40
    """Frames of the synthesised capture."""
    width: int = 160
    """Image width, pixels."""
    height: int = 120
    """Image height, pixels."""
    preset: str = "fast"
    """Pipeline preset."""
    search: str = "tree"
    """s2 search mode (``tree``, ``ground``, ``none``)."""
    seed: int = 0
    """Seed of generation and reconstruction."""
    threads: int | None = None
    """Torch CPU threads (None: torch's setting)."""
    sensor: str = "clean"
    """Sensor model of the synthesised capture (see :mod:`holousd.synth._sensor`)."""
    samples: int = 100_000
    """Surface samples of the geometry metrics."""


def _png_uri(image: Any) -> str:
    from PIL import Image

    if not isinstance(image, Image.Image):
        arr = np.asarray(image)
        if arr.dtype != np.uint8:
            arr = (np.clip(arr, 0, 1) * 255 + 0.5).astype(np.uint8)
        image = Image.fromarray(arr)
    buf = io.BytesIO()
    image.save(buf, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def bar_chart(title: str, labels: list[str], values: list[float | None], *, unit: str = "", width: int = 480):  # noqa: ANN201
    """A horizontal bar chart as a PIL image (None values drawn as '-')."""
    from PIL import Image, ImageDraw

    row = 18
    img = Image.new("RGB", (width, 30 + row * max(1, len(labels))), "white")
    draw = ImageDraw.Draw(img)
    draw.text((6, 6), title, fill=(0, 0, 0))
    finite = [v for v in values if v is not None]
    top = max(finite) if finite and max(finite) > 0 else 1.0
    for i, (label, v) in enumerate(zip(labels, values, strict=True)):
        y = 26 + i * row
        draw.text((6, y + 2), label[:16], fill=(0, 0, 0))
        if v is None:
            draw.text((130, y + 2), "-", fill=(120, 120, 120))
            continue
        w = int((width - 210) * max(v, 0.0) / top)
        draw.rectangle([130, y + 2, 130 + w, y + row - 3], fill=(31, 119, 180))
        draw.text((136 + w, y + 2), f"{v:.2f}{unit}", fill=(0, 0, 0))
    return img


_PALETTE = np.array([(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
                     (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]) / 255.0  # fmt: skip


def mesh_view(scene: Any, camera: Any) -> np.ndarray:
    """The scene's object meshes seen from ``camera`` ([H, W, 3] float in 0..1, white where no object is hit).

    One colour per object, Lambert-shaded by the face normal against a light at the camera; the background node is
    left out so the room's walls do not hide the objects. Ray cast with Warp (the kernel ``holousd synth`` uses).
    """
    from holousd.synth._raycast import RayCaster

    points, faces, owner = [], [], []
    start = 0
    for k, name in enumerate(scene.objects()):
        try:
            mesh = scene.get_mesh(name)
        except Exception:  # noqa: BLE001 - an object without a mesh is simply not drawn
            continue
        if not len(mesh.faces):
            continue
        points.append(scene.get_pose(name).apply(mesh.points))
        faces.append(np.asarray(mesh.faces) + start)
        owner.append(np.full(len(mesh.faces), k))
        start += len(mesh.points)
    image = np.ones((camera.height, camera.width, 3))
    if not points:
        return image
    pts, tri, own = np.concatenate(points), np.concatenate(faces), np.concatenate(owner)
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]])
    hits = RayCaster(pts, tri).cast(K, camera.cam_to_world, camera.width, camera.height)
    face = hits.face[0]
    hit = face >= 0
    corners = pts[tri[face[hit]]]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    rows, cols = np.nonzero(hit)
    rays = np.stack([(cols + 0.5 - camera.cx) / camera.fx, (rows + 0.5 - camera.cy) / camera.fy,
                     np.ones(len(rows))], 1) @ camera.cam_to_world[:3, :3].T  # fmt: skip
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    shade = 0.25 + 0.75 * np.abs(np.einsum("ij,ij->i", normal, rays))
    image[hit] = _PALETTE[own[face[hit]] % len(_PALETTE)] * shade[:, None]
    return image


def reference_runs() -> list[dict[str, Any]]:
    """The committed reference ``holousd bench`` runs, preset labelled ``<suite> <preset>``, with the file's name
    after it when that is not the suite's own (``hard fast (hard_ablation)``: an older run of the same preset)
    ([] when absent)."""
    runs = []
    for path in sorted(REFERENCE_DIR.glob("*.json")):
        try:
            payload = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        suite = payload.get("suite", path.stem)
        which = "" if path.stem in (suite, f"{suite}_default") else f" ({path.stem})"
        for r in payload.get("runs", []):
            runs.append({**r, "preset": f"{suite} {r['preset']}{which}"})
    return runs


def _verdict(stable: bool | None) -> str:
    return "&ndash;" if stable is None else ("stable" if stable else "falls")


def _search_cells(scene: Any, name: str | None) -> str:
    """Two table cells: the candidate the s2 search chose for ``name`` (with its total and whether its check had
    it standing) and the runner-up; dashes where the search scored nothing."""
    energies = scene.get_energies(name) if name is not None and name in scene.objects() else None
    if energies is None or energies.chosen is None:
        return "<td>&ndash;</td><td>&ndash;</td>"
    stands = ("stands" if energies.stable == 0.0 else "stands once set up" if energies.stands_once_set_up
              else "falls")  # fmt: skip
    runner = energies.runner_up()
    other = f"{html.escape(runner[0])} ({runner[1]:.2f})" if runner else "none (the others rejected by E_obs)"
    total = f"{energies.total:.2f}" if energies.total >= 0 else "every candidate rejected by E_obs: kept as fitted"
    return f"<td>{html.escape(energies.chosen)} ({total}, {stands})</td><td>{other}</td>"


def _tree_from_graph(graph: dict[str, Any]) -> list[str]:
    from holousd.graph import Relations

    rel = Relations()
    for n in graph["nodes"]:
        if n.get("role") == "object":
            rel.support[n["name"]] = n["parent"]
            rel.beside[n["name"]] = list(n.get("beside", []))
    return rel.tree_lines()


def _tree_from_scene(scene: Any) -> list[str]:
    from holousd.graph import Relations

    rel = Relations()
    for name in scene.objects():
        rel.support[name] = scene.get_support(name) or "background"
        rel.beside[name] = scene.get_beside(name)
    return rel.tree_lines()


def write_report(path: str | os.PathLike[str], *, evaluation: dict[str, Any], scene_file: Path, gt_dir: Path,
                 frames: int = 4, title: str = "holousd demo") -> Path:  # fmt: skip
    """Write the one-page HTML report of a reconstruction and its evaluation (images embedded), atomically.

    Args:
        path: HTML file.
        evaluation: ``SceneEvaluation.to_dict()``.
        scene_file: The reconstructed scene.
        gt_dir: The synth scene folder (capture + ``gt/``).
        frames: Input frames shown.
        title: Page title.
    """
    from PIL import Image

    from holousd.eval._bench_suite import chart_vs_time
    from holousd.io import load
    from holousd.render import SceneRenderer, scene_orbit
    from holousd.usd import SceneGraph

    obs = load(gt_dir)
    pick = evenly_spaced(len(obs), frames)
    inputs = [_png_uri(np.asarray(obs.rgb(int(i)))[..., :3]) for i in pick]
    scene = SceneGraph.open(scene_file)
    novel = meshes = None
    novel_error = mesh_error = ""
    width = max(2 * obs.width, 320)
    cam = scene_orbit(scene, 8, width=width, height=width * obs.height // obs.width)[3]
    try:
        renderer = SceneRenderer(scene, background=(1.0, 1.0, 1.0))
        novel = _png_uri(renderer.render(cam).color.detach().cpu().numpy()[..., :3])
    except Exception as exc:  # noqa: BLE001 - the report shows why instead of failing
        novel_error = f"{type(exc).__name__}: {exc}"
    try:
        meshes = _png_uri(mesh_view(scene, cam))
    except Exception as exc:  # noqa: BLE001 - the report shows why instead of failing
        mesh_error = f"{type(exc).__name__}: {exc}"
    graph = json.loads((gt_dir / "gt" / "graph.json").read_text())
    ev = evaluation
    stages = ev["cost"]["stages"]
    cost_chart = _png_uri(bar_chart("wall time per stage (s)", list(stages), list(stages.values()), unit=" s"))
    rows = ev["objects"]
    f1_chart = _png_uri(bar_chart("F1 per object (%, 5 cm)", [o["name"] for o in rows], [o["f1"] for o in rows]))
    reference = reference_runs()
    reference_labels = html.escape(", ".join(sorted({r["preset"] for r in reference})))
    with tempfile.TemporaryDirectory() as tmp:
        this = {"preset": "this run", "wall_s": ev["cost"]["total_s"] or 0.0, "eval": ev}
        chart_file = chart_vs_time([*reference, this], Path(tmp) / "chart.png")
        tradeoff_chart = _png_uri(Image.open(chart_file).copy())

    def f(v: Any, spec: str = ".2f") -> str:
        return "&ndash;" if v is None else (format(v, spec) if isinstance(v, float) else html.escape(str(v)))

    def pct(v: float | None) -> str:
        return f(v, ".0f") + ("%" if v is not None else "")

    g, r, p, c = ev["geometry"], ev["render"], ev["physics"], ev["cost"]
    cross = p.get("cross_check") or {}
    table = "".join(
        f"<tr><td>{html.escape(o['name'])}</td><td>{f(o['recon'])}</td><td>{f(o['parent_gt'])}</td>"
        f"<td>{f(o['parent_recon'])}</td><td>{f(o['chamfer_cm'])}</td><td>{f(o['f1'], '.1f')}</td>"
        f"<td>{f(o.get('f1_visible'), '.1f')}</td>"
        f"<td>{f(o['translation_m'], '.3f')}</td><td>{f(o['rotation_deg'], '.1f')}</td>"
        f"<td class={'ok' if o['stable'] else 'bad'}>{_verdict(o['stable'])}</td>"
        f"<td class={'ok' if o.get('stable_cross_check') else 'bad'}>{_verdict(o.get('stable_cross_check'))}</td>"
        f"{_search_cells(scene, o['recon'])}</tr>"
        for o in rows
    )  # fmt: skip
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title><style>
body{{font-family:sans-serif;max-width:1100px;margin:20px auto;color:#222}} img{{margin:4px;border:1px solid #ccc}}
table{{border-collapse:collapse}} td,th{{border:1px solid #ccc;padding:3px 8px;text-align:left}}
.ok{{color:#080}} .bad{{color:#b00}}
pre{{background:#f6f6f6;padding:8px;display:inline-block;vertical-align:top;margin-right:16px}}
</style></head><body><h1>{html.escape(title)}</h1>
<p>Scene: <code>{html.escape(str(scene_file))}</code> &mdash; ground truth: <code>{html.escape(str(gt_dir))}</code></p>
<h2>Headline</h2><table>
<tr><th>Chamfer (scene)</th><th>F1 (scene)</th><th>NC</th><th>PSNR</th><th>SSIM</th><th>OR%</th>
<th>Stable% ({html.escape(str(p.get("solver") or "-"))})</th>
<th>Stable% ({html.escape(str(cross.get("solver", "-")))})</th>
<th>solvers agree</th><th>search agrees</th><th>penetration</th>
<th>collider reach</th><th>mesh penetration</th><th>move from fit</th><th>wall time</th>
<th>peak memory</th></tr>
<tr><td>{f(g["scene"]["chamfer_cm"])} cm</td><td>{f(g["scene"]["f1"], ".1f")}</td>
<td>{f(g["scene"]["nc"], ".1f")}</td><td>{f(r["psnr"])} dB</td><td>{f(r["ssim"], ".3f")}</td>
<td>{f(p["or_pct"], ".0f")}</td><td>{f(p["stable_pct"], ".0f")}</td><td>{f(cross.get("stable_pct"), ".0f")}</td>
<td>{pct(cross.get("agreement_pct"))}</td><td>{pct(p.get("search_agreement_pct"))}</td>
<td>{f(p["penetration_cm3"], ".1f")} cm&sup3;</td>
<td>{f(p.get("max_collider_reach_cm"), ".1f")} cm</td><td>{f(p.get("max_penetration_cm"), ".1f")} cm</td>
<td>{f(p.get("max_fit_shift_cm"), ".1f")} cm</td>
<td>{f(c["total_s"], ".1f")} s</td><td>{f(c["peak_mem_mb"], ".0f")} MiB</td></tr></table>
<h2>Input frames</h2>{"".join(f'<img src="{u}">' for u in inputs)}
<h2>Novel view (reconstructed splats, orbit camera)</h2>
{f'<img src="{novel}">' if novel else f"<p>no render: {html.escape(novel_error)}</p>"}
<h2>Meshes (same camera, one colour per object)</h2>
{f'<img src="{meshes}">' if meshes else f"<p>no mesh view: {html.escape(mesh_error)}</p>"}
<h2>Support tree</h2><pre>reconstructed
{html.escape(chr(10).join(_tree_from_scene(scene)))}</pre><pre>ground truth
{html.escape(chr(10).join(_tree_from_graph(graph)))}</pre>
<h2>Objects: geometry and stability</h2><p>Stability: all objects dynamic together, gravity, friction 0.5, 2 s at
240 Hz; stable = moved &lt; 2 cm and turned &lt; 5&deg;.</p><table><tr><th>object</th><th>reconstructed</th>
<th>parent (gt)</th><th>parent (recon)</th><th>Chamfer cm (complete)</th><th>F1 (complete)</th><th>F1 (seen)</th>
<th>moved m</th><th>turned &deg;</th>
<th>verdict ({html.escape(str(p.get("solver") or "-"))})</th>
<th>verdict ({html.escape(str(cross.get("solver", "-")))})</th>
<th>search: chosen shape</th><th>search: runner-up</th></tr>{table}</table>
<p>Search: the completion candidate the s2 search kept (lowest E_obs + E_stable + E_touch + E_pene; its
E_stable is quasi-static, "search agrees" is how often the verdict above repeats it) beside the runner-up.</p>
<h2>Speed against accuracy</h2><p>This run ("this run") beside the reference <code>holousd bench</code> runs
shipped with holousd ({len(reference)} runs: {reference_labels}; see the README for the
command and machine). x: wall time of the reconstruction.</p><img src="{tradeoff_chart}">
<h2>Cost</h2><img src="{cost_chart}"><img src="{f1_chart}">
<ul>{"".join(f"<li>{html.escape(n)}</li>" for n in ev["notes"])}</ul>
</body></html>"""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return path


def run_demo(out: str | os.PathLike[str], config: DemoConfig | None = None) -> Path:
    """Synthesise the demo scene, reconstruct it, evaluate it and write ``out/report.html``.

    Args:
        out: Output folder (``data/demo`` capture + ground truth, ``recon/`` the reconstruction).
        config: Settings.

    Returns:
        The report file.
    """
    from holousd._paths import output_folder
    from holousd.eval._scene_eval import EvalConfig, evaluate_scene
    from holousd.stages._pipeline import preset, reconstruct
    from holousd.synth import SynthConfig, generate_suite

    config = config or DemoConfig()
    out = output_folder(out, "demo folder")
    start = time.perf_counter()

    def say(line: str) -> None:
        print(f"[demo {time.perf_counter() - start:6.1f}s] {line}", file=sys.stderr, flush=True)

    data = out / "data"
    say(f"synthesising the demo scene ({config.frames} frames, {config.width}x{config.height}, sensor "
        f"{config.sensor}) -> {data}")
    generate_suite("demo", data, SynthConfig(seed=config.seed, frames=config.frames, width=config.width,
                                             height=config.height, progress=False, overwrite=True,
                                             sensor=config.sensor))  # fmt: skip
    say(f"reconstructing with the {config.preset} preset -> {out / 'recon'}")
    result = reconstruct(data / "demo", out / "recon",
                         preset(config.preset, seed=config.seed, progress=True, threads=config.threads,
                                search=config.search),
                         log=say)  # fmt: skip
    say("evaluating against the ground truth (geometry, held-out renders, stability)")
    evaluation = evaluate_scene(result.scene_file, data / "demo", EvalConfig(samples=config.samples, log=say)).to_dict()
    with atomic_path(out / "eval.json") as tmp:
        tmp.write_text(json.dumps(evaluation, indent=2))
    say("writing the report")
    report = write_report(out / "report.html", evaluation=evaluation, scene_file=result.scene_file,
                          gt_dir=data / "demo")  # fmt: skip
    say(f"done: {report}")
    return report
