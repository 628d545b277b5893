"""``holousd bench``: reconstruct + evaluate every scene of a synth suite with each preset.

Writes ``bench.json`` (one entry per scene and preset: the evaluation dict plus the wall time), ``bench.png``
(F1, Chamfer, PSNR and Stable% against wall time, one point per preset and scene, drawn with PIL) and, for the
``hard`` suite, ``hard_stable.md`` (Stable% per failure mode and preset).
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from holousd._atomic import atomic_path
from holousd._tasks import machine_info

__all__ = [
    "BenchSuiteConfig",
    "BenchSuiteResult",
    "chart_vs_time",
    "load_bench",
    "machine_info",
    "run_bench",
    "stable_table",
    "summary_table",
]


@dataclass(kw_only=True)
class BenchSuiteConfig:
    """Settings of :func:`run_bench`."""

    suite: str = "bench"
    """Synth suite: 'bench', 'hard' or 'demo'."""
    presets: list[str] = field(default_factory=lambda: ["fast", "default"])
    """Pipeline presets to compare; ``PRESET@MODE`` runs the preset with that s2 search mode (``none``,
    ``ground``; plain ``PRESET`` is the full ``tree`` search): the ablation rows."""
    scenes: list[str] | None = None
    """Only these scenes of the suite (None: all)."""
    data: Path | None = None
    """Existing synth output of the suite (None: generate into ``out/data``)."""
    frames: int = 60
    """Frames per generated scene."""
    width: int = 160
    """Width of generated images, pixels."""
    height: int = 120
    """Height of generated images, pixels."""
    seed: int = 0
    """Seed of generation and reconstruction."""
    threads: int | None = None
    """Torch CPU threads (None: torch's setting)."""
    samples: int = 100_000
    """Surface samples of the geometry metrics."""
    command: str | None = None
    """Command line recorded in ``bench.json`` (None: rebuilt from these settings)."""
    ray: str | None = None
    """Run the (scene, preset) pairs as Ray tasks on this cluster ('local', 'auto' or 'HOST:PORT'); None: one after
    another in this process. The figures are the same either way (same seeds; each task's torch threads are
    ``threads``, 1 when unset)."""
    num_cpus: float = 1.0
    """Cores each Ray task declares."""
    sensors: list[str] = field(default_factory=lambda: ["clean"])
    """Sensor models of the generated captures (``holousd synth --sensor``): every preset runs on each, side by
    side; a run on another sensor than 'clean' is labelled ``PRESET[SENSOR]``. Not with ``data`` (an existing
    capture has the sensor it was made with)."""


@dataclass(kw_only=True)
class BenchSuiteResult:
    """What :func:`run_bench` wrote."""

    runs: list[dict[str, Any]]
    """One entry per (scene, preset): scene, preset, wall_s and the evaluation dict."""
    files: list[Path]
    """Files written (JSON, chart, table)."""


_COLORS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75)]


def chart_vs_time(runs: list[dict[str, Any]], path: str | os.PathLike[str], *,
                  metrics: tuple[tuple[str, str], ...] | None = None) -> Path:  # fmt: skip
    """Scatter plots of metrics against wall time (one point per run, colour per preset) as a PNG, with PIL.

    Args:
        runs: Entries with ``preset``, ``wall_s`` and ``eval`` (an evaluation dict).
        path: PNG file to write (atomically).
        metrics: (title, dotted key into the evaluation dict) per panel.
    """
    from PIL import Image, ImageDraw

    metrics = metrics or (("F1 % (scene)", "geometry.scene.f1"), ("Chamfer cm (scene)", "geometry.scene.chamfer_cm"),
                          ("PSNR dB", "render.psnr"), ("Stable %", "physics.stable_pct"))  # fmt: skip
    presets = sorted({r["preset"] for r in runs}, key=lambda p: [r["preset"] for r in runs].index(p))
    pw, ph, margin = 320, 240, 48
    img = Image.new("RGB", (pw * len(metrics), ph + 30), "white")
    draw = ImageDraw.Draw(img)

    def get(d: dict[str, Any], key: str) -> float | None:
        for part in key.split("."):
            d = d.get(part) if isinstance(d, dict) else None
        return float(d) if isinstance(d, int | float) else None

    times = [r["wall_s"] for r in runs] or [1.0]
    t_lo, t_hi = 0.0, max(times) * 1.1 or 1.0
    for k, (title, key) in enumerate(metrics):
        x0 = k * pw
        values = [get(r["eval"], key) for r in runs]
        finite = [v for v in values if v is not None]
        v_lo = min(0.0, min(finite)) if finite else 0.0
        v_hi = max(finite) * 1.1 if finite and max(finite) > 0 else 1.0
        if key.endswith(("f1", "_pct")):  # percentages: the full 0..100 scale
            v_lo, v_hi = 0.0, 100.0
        left, right, top, bottom = x0 + margin, x0 + pw - 12, 24, ph - 28
        draw.rectangle([left, top, right, bottom], outline=(0, 0, 0))
        draw.text((x0 + margin, 6), title, fill=(0, 0, 0))
        for frac in (0.0, 0.5, 1.0):
            y = bottom - frac * (bottom - top)
            draw.text((x0 + 4, y - 6), f"{v_lo + frac * (v_hi - v_lo):.3g}", fill=(80, 80, 80))
            x = left + frac * (right - left)
            draw.text((x - 10, bottom + 4), f"{t_lo + frac * (t_hi - t_lo):.0f}s", fill=(80, 80, 80))
        if not finite:
            draw.text((left + 10, (top + bottom) // 2), "no data (null)", fill=(150, 0, 0))
        for r, v in zip(runs, values, strict=True):
            if v is None:
                continue
            x = left + (r["wall_s"] - t_lo) / (t_hi - t_lo) * (right - left)
            y = bottom - (v - v_lo) / max(v_hi - v_lo, 1e-9) * (bottom - top)
            color = _COLORS[presets.index(r["preset"]) % len(_COLORS)]
            draw.ellipse([x - 4, y - 4, x + 4, y + 4], fill=color)
    for i, p in enumerate(presets):
        draw.ellipse([10 + 110 * i, ph + 10, 18 + 110 * i, ph + 18], fill=_COLORS[i % len(_COLORS)])
        draw.text((22 + 110 * i, ph + 8), p, fill=(0, 0, 0))
    draw.text((10 + 110 * len(presets), ph + 8), "x: wall time of reconstruct, s", fill=(80, 80, 80))
    path = Path(path)
    with atomic_path(path) as tmp:
        img.save(tmp, format="PNG")
    return path


def _mean(values: list[float | None]) -> float | None:
    finite = [v for v in values if v is not None]
    return sum(finite) / len(finite) if finite else None


def load_bench(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a ``bench.json`` written by :func:`run_bench`, with a clear error for anything else."""
    from holousd._errors import HolousdError

    path = Path(path)
    try:
        payload = json.loads(path.read_text())
    except FileNotFoundError:
        raise HolousdError(f"{path}: no such file; give a bench.json written by `holousd bench`") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise HolousdError(f"{path}: not readable JSON ({exc}); re-run `holousd bench`") from None
    if not isinstance(payload, dict) or payload.get("format") != "holousd-bench":
        raise HolousdError(f"{path}: not a holousd bench result (no format 'holousd-bench')")
    if payload.get("version") != 1:
        raise HolousdError(f"{path}: bench format version {payload.get('version')!r} is not supported (this "
                           "holousd reads version 1); re-run `holousd bench` with this version")  # fmt: skip
    return payload


def summary_table(payloads: list[dict[str, Any]]) -> str:
    """Markdown table of one or more ``bench.json`` payloads: one row per suite and preset, means over scenes.

    Columns: scenes, wall time per scene, F1@5cm and Chamfer (scene, visible ground truth), PSNR / SSIM at held-out
    views, OR% (objects recovered), support% (recovered objects resting on their ground-truth parent, over all the
    preset's scenes), Stable% (primary solver), the cross-check solver's Stable% and the two solvers' agreement, the
    worst object's records over the scenes (collider reach outside the rendered mesh, rendered-mesh penetration,
    move from the fitted pose, cm; "–" for runs made before the records), peak memory. Below it, the command
    and machine of each payload. The README's results table is this function's output on the committed reference
    runs (``holousd bench --table``).
    """

    def cell(v: float | None, spec: str) -> str:
        return "–" if v is None else format(v, spec)

    def worst(ev: list[dict[str, Any]], key: str) -> float | None:
        values = [e["physics"].get(key) for e in ev if e["physics"].get(key) is not None]
        return max(values) if values else None

    def support(ev: list[dict[str, Any]]) -> float | None:
        rows = [o for e in ev for o in e.get("objects", []) if o.get("recon") is not None]
        return 100.0 * sum(o["parent_recon"] == o["parent_gt"] for o in rows) / len(rows) if rows else None

    lines = ["| suite | preset | scenes | wall s / scene | F1@5cm % | Chamfer cm | PSNR dB | SSIM | OR % | support % "
             "| Stable % | Stable % (cross-check) | agreement % | reach cm | pen cm | shift cm | peak MiB |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    notes = []
    for payload in payloads:
        runs = payload["runs"]
        for p in payload["presets"]:
            rows = [r for r in runs if r["preset"] == p]
            if not rows:
                continue
            ev = [r["eval"] for r in rows]
            lines.append(
                f"| {payload['suite']} | {p} | {len(rows)} | {cell(_mean([r['wall_s'] for r in rows]), '.0f')} "
                f"| {cell(_mean([e['geometry']['scene']['f1'] for e in ev]), '.1f')} "
                f"| {cell(_mean([e['geometry']['scene']['chamfer_cm'] for e in ev]), '.2f')} "
                f"| {cell(_mean([e['render']['psnr'] for e in ev]), '.1f')} "
                f"| {cell(_mean([e['render']['ssim'] for e in ev]), '.3f')} "
                f"| {cell(_mean([e['physics']['or_pct'] for e in ev]), '.0f')} "
                f"| {cell(support(ev), '.0f')} "
                f"| {cell(_mean([e['physics']['stable_pct'] for e in ev]), '.0f')} "
                f"| {cell(_mean([(e['physics'].get('cross_check') or {}).get('stable_pct') for e in ev]), '.0f')} "
                f"| {cell(_mean([(e['physics'].get('cross_check') or {}).get('agreement_pct') for e in ev]), '.0f')} "
                f"| {cell(worst(ev, 'max_collider_reach_cm'), '.1f')} | {cell(worst(ev, 'max_penetration_cm'), '.1f')} "
                f"| {cell(worst(ev, 'max_fit_shift_cm'), '.1f')} "
                f"| {cell(max(r['peak_mem_mb'] for r in rows), '.0f')} |"
            )
        m = payload.get("machine") or {}
        where = ", ".join(f"{k} {m[k]}" for k in ("cpu", "cores", "memory_gb", "torch_threads") if m.get(k))
        notes.append(f"- {payload['suite']}: `{payload.get('command', 'holousd bench')}` on {where or 'unrecorded'}"
                     f"{', ' + payload['date'] if payload.get('date') else ''}")  # fmt: skip
    return "\n".join(lines + [""] + notes) + "\n"


def stable_table(runs: list[dict[str, Any]]) -> str:
    """Markdown table: Stable% (and OR%) per scene (failure mode) and preset."""
    presets = list(dict.fromkeys(r["preset"] for r in runs))
    scenes = list(dict.fromkeys(r["scene"] for r in runs))
    by = {(r["scene"], r["preset"]): r for r in runs}
    lines = ["| failure mode | " + " | ".join(f"{p} Stable% (OR%)" for p in presets) + " |",
             "|---|" + "---|" * len(presets)]  # fmt: skip
    for s in scenes:
        cells = []
        for p in presets:
            r = by.get((s, p))
            phys = r["eval"]["physics"] if r else None
            if not phys:
                cells.append("-")
                continue
            st = "-" if phys["stable_pct"] is None else f"{phys['stable_pct']:.0f}"
            cells.append(f"{st} ({phys['or_pct']:.0f})")
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _command_line(config: BenchSuiteConfig) -> str:
    parts = ["holousd bench", f"--suite {config.suite}", f"--presets {','.join(config.presets)}"]
    if config.scenes:
        parts.append(f"--scenes {','.join(config.scenes)}")
    parts += [f"--frames {config.frames}", f"--resolution {config.width}x{config.height}", f"--seed {config.seed}"]
    if config.threads:
        parts.append(f"--threads {config.threads}")
    if config.sensors != ["clean"]:
        parts.append(f"--sensor {','.join(config.sensors)}")
    if config.ray:
        parts.append(f"--ray {config.ray}")
    return " ".join(parts)


def bench_run(data: str, out: str, suite: str, name: str, preset_name: str, seed: int, threads: int | None,
              samples: int, quiet: bool) -> dict[str, Any]:  # fmt: skip
    """One (scene, preset) of the benchmark: reconstruct (resuming) and evaluate; the entry of ``bench.json``."""
    from holousd.eval._scene_eval import EvalConfig, evaluate_scene
    from holousd.stages._pipeline import preset, reconstruct

    def log(line: str) -> None:
        if not quiet:
            print(line, file=sys.stderr, flush=True)

    if threads is not None and quiet:  # a worker process of its own: the whole task on these threads
        import torch

        torch.set_num_threads(threads)
    scene = Path(data) / name
    base, _, mode = preset_name.split("[")[0].partition("@")
    result = reconstruct(scene, Path(out), preset(base, seed=seed, progress=False, threads=threads,
                                                  search=mode or None),
                         resume=True, log=log if not quiet else (lambda _: None))  # fmt: skip
    wall = sum(stage.wall_s for stage in result.stages)  # as recorded, also for stages resumed
    evaluation = evaluate_scene(result.scene_file, scene, EvalConfig(samples=samples, log=log))
    try:
        sensor = json.loads((scene / "gt" / "graph.json").read_text())["capture"]["sensor"]["name"]
    except (OSError, ValueError, KeyError, TypeError):
        sensor = "clean"  # captures generated before sensor models
    return {"suite": suite, "scene": name, "preset": preset_name, "sensor": sensor, "wall_s": wall,
            "peak_mem_mb": result.peak_mem_mb, "eval": evaluation.to_dict()}  # fmt: skip


def run_bench(out: str | os.PathLike[str], config: BenchSuiteConfig | None = None) -> BenchSuiteResult:
    """Reconstruct and evaluate every scene of the suite with each preset; write JSON, chart and table.

    Args:
        out: Output folder (``data/`` generated scenes, ``runs/<preset>/<scene>/`` reconstructions). Running again
            into the same folder resumes: up-to-date reconstructions are kept (with their recorded wall time) and
            only evaluated again.
        config: Settings.
    """
    from holousd._errors import HolousdError
    from holousd.synth import SynthConfig, generate_suite, scene_names, sensor_model

    config = config or BenchSuiteConfig()
    for s in config.sensors:
        sensor_model(s)
    if config.data is not None and config.sensors != ["clean"]:
        raise HolousdError("--sensor generates captures; with --data the captures are given (and carry the sensor "
                           "they were made with): drop one of them")  # fmt: skip
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = config.scenes or scene_names(config.suite)
    datas: dict[str, Path] = {}
    for sensor in config.sensors:
        if config.data is not None:
            datas[sensor] = Path(config.data)
            continue
        data = out / ("data" if sensor == "clean" else f"data-{sensor}")
        datas[sensor] = data
        todo = [n for n in names if not (data / n / "gt" / "graph.json").is_file()]
        if todo:
            generate_suite(config.suite, data, SynthConfig(seed=config.seed, frames=config.frames, width=config.width,
                                                          height=config.height, progress=False, overwrite=True,
                                                          sensor=sensor),
                           scenes=todo)  # fmt: skip
    runs: list[dict[str, Any]] = []

    def log(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    def label(p: str, sensor: str) -> str:
        return p if sensor == "clean" else f"{p}[{sensor}]"

    labels = [label(p, sensor) for sensor in config.sensors for p in config.presets]
    data_of = {label(p, sensor): datas[sensor] for sensor in config.sensors for p in config.presets}
    pairs = [(p, name) for p in labels for name in names]
    start = time.perf_counter()
    engine: dict[str, Any] = {"engine": "sequential"}
    if config.ray is None:
        for p, name in pairs:
            log(f"bench: {config.suite}/{name} preset {p}")
            runs.append(bench_run(str(data_of[p]), str(out / "runs" / p / name), config.suite, name, p, config.seed,
                                  config.threads, config.samples, False))  # fmt: skip
    else:
        from holousd._tasks import overhead, run_tasks

        threads = config.threads or max(1, int(config.num_cpus))
        tasks = [(f"{name}/{p}", (str(data_of[p]), str(out / "runs" / p / name), config.suite, name, p, config.seed,
                                  threads, config.samples, True)) for p, name in pairs]  # fmt: skip
        outcomes = run_tasks(bench_run, tasks, ray=config.ray, num_cpus=config.num_cpus,
                             on_done=lambda o: log(f"bench: {config.suite}/{o.key} {'done' if o.ok else 'FAILED'} "
                                                   f"({o.wall_s:.1f} s in its worker)"))  # fmt: skip
        failed = [o for o in outcomes if not o.ok]
        if failed:  # as a sequential run would: no bench.json with scenes missing
            raise HolousdError(f"{config.suite}/{failed[0].key}: {failed[0].error}"
                               + (f" (and {len(failed) - 1} more)" if len(failed) > 1 else ""))  # fmt: skip
        runs = [o.value for o in outcomes]
        wall = time.perf_counter() - start
        inside = sum(o.wall_s for o in outcomes)
        import ray

        slots = max(1.0, float(ray.cluster_resources().get("CPU", 1.0)) // config.num_cpus)
        cost = overhead(outcomes, int(slots))
        engine = {"engine": f"ray {config.ray}", "slots": slots, "tasks": len(outcomes), "wall_s": wall,
                  "task_wall_s": inside,
                  # Ray's own cost per task: a free worker waiting for its next task, and the result coming back
                  "overhead_per_task_s": cost["dispatch_s"] + cost["return_s"], **cost,
                  # worker time outside any task, the idle tail of the last tasks included, per task
                  "idle_per_task_s": max(0.0, (wall * min(slots, len(outcomes)) - inside) / len(outcomes))}  # fmt: skip
    if config.ray is None:
        engine["wall_s"] = time.perf_counter() - start
    files = []
    payload = {"format": "holousd-bench", "version": 1, "suite": config.suite, "presets": labels,
               "sensors": config.sensors,
               "scenes": names, "command": config.command or _command_line(config),
               "date": time.strftime("%Y-%m-%d", time.gmtime()), "machine": machine_info(), "engine": engine,
               "runs": runs}  # fmt: skip
    with atomic_path(out / "bench.json") as tmp:
        tmp.write_text(json.dumps(payload, indent=2))
    files.append(out / "bench.json")
    files.append(chart_vs_time(runs, out / "bench.png"))
    with atomic_path(out / "summary.md") as tmp:
        tmp.write_text(summary_table([payload]))
    files.append(out / "summary.md")
    if config.suite == "hard":
        with atomic_path(out / "hard_stable.md") as tmp:
            tmp.write_text(f"# Stable% per failure mode (hard suite)\n\n{stable_table(runs)}")
        files.append(out / "hard_stable.md")
    return BenchSuiteResult(runs=runs, files=files)
