"""The reconstruction pipeline: s0 observe -> s1 fit -> s2 search -> physics set-up -> appearance -> ``scene.usda``.

Each stage pushes its own layer over the previous one (``00_observe.usda``, ``10_fit.usda``, ``15_search.usda``,
``20_physics.usda``, ``30_appearance.usda``) and the pipeline then records in that layer's customLayerData, under
``holousd: {stage: {...}}``, the stage name, wall time, peak memory (``ru_maxrss``), its config (as a dict and
as JSON), the input hash and a run id. ``out/scene.usda`` sublayers the last stage layer, and so every stage.

Before any stage writes anything, the whole capture is read and checked (every file's presence, decodability,
shape, dtype and value range; :meth:`holousd.io.Observations.validate`) and the output folder is checked for
writability: bad input is refused with a one-line error and the output folder is never touched. Depth pixels
without a measurement (0, NaN, a far plane) are ignored with one warning; a capture whose depth holds no
measurement at all is fitted from its masks (visual hull), with a warning.

Resume: a stage is skipped when its layer exists and records the same input hash. The hash is content-only: the
holousd version, the capture's content (relative path and bytes of every input file), the stage's config and
the input hash of the stage below, so the same capture and settings give the same hashes (and, the stages being
seeded, the same layers) on every run and machine. Every layer is written atomically (temp file + rename), the
record is added only after the stage's own save succeeded, and the whole run is one transaction on the output
folder: when any stage fails (or Ctrl-C), every layer and asset it wrote is removed and every file it replaced
is put back, byte for byte.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import resource
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from holousd._atomic import folder_transaction
from holousd._errors import HolousdError
from holousd._paths import output_folder
from holousd._sampling import evenly_spaced
from holousd._torch_threads import torch_threads
from holousd.stages import _fit, _observe, _search
from holousd.stages import _physics_setup as _physics
from holousd.stages._appearance import AppearanceConfig
from holousd.usd._scene import SceneGraph

__all__ = [
    "APPEARANCE_LAYER",
    "HOLDOUT_EVERY",
    "PRESETS",
    "SCENE_FILE",
    "STAGES",
    "AppearanceStageConfig",
    "PipelineConfig",
    "PipelineResult",
    "StageRecord",
    "OUTPUT_PATTERNS",
    "capture_manifest_hash",
    "checked",
    "holdout_frames",
    "preset",
    "read_stage_records",
    "reconstruct",
]

STAGES = ("observe", "fit", "search", "physics", "appearance")
"""Stage names in pipeline order (``--until`` takes one of them)."""
LAYERS = {
    "observe": _observe.OBSERVE_LAYER,
    "fit": _fit.FIT_LAYER,
    "search": _search.SEARCH_LAYER,
    "physics": _physics.PHYSICS_LAYER,
    "appearance": "30_appearance.usda",
}
"""Layer file of each stage."""
APPEARANCE_LAYER = LAYERS["appearance"]
"""File name of the appearance layer."""
SCENE_FILE = "scene.usda"
"""The pipeline's output: a layer that sublayers the last stage's layer."""
HOLDOUT_EVERY = 8
"""Frames ``i % HOLDOUT_EVERY == HOLDOUT_EVERY - 1`` are held out of the appearance fit (evaluation views)."""


def holdout_frames(count: int) -> list[int]:
    """Frame indices held out of the appearance fit for a capture of ``count`` frames."""
    return [i for i in range(count) if i % HOLDOUT_EVERY == HOLDOUT_EVERY - 1]


@dataclass(kw_only=True)
class AppearanceStageConfig:
    """Settings of the pipeline's appearance stage (Gaussians on the physics-ready meshes)."""

    enabled: bool = True
    """Run the stage (False: the scene has no splats; render metrics are then null)."""
    iterations: int = 300
    """Adam steps (one observed frame rendered per step)."""
    frames: int = 40
    """Training frames used (evenly subsampled, held-out frames excluded), at most."""
    spacing_px: float = 2.0
    """Splat spacing on screen at the closest observing camera, pixels."""
    max_splats: int = 20_000
    """Upper clamp of a node's splat count."""
    seed: int = 0
    """Seed of splat sampling and frame order."""
    progress: bool = False
    """Show a progress bar of the fit on stderr (does not change the result)."""
    threads: int | None = None
    """Torch CPU threads during the fit (restored afterwards); None keeps torch's setting."""


@dataclass(kw_only=True)
class PipelineConfig:
    """Settings of the whole pipeline (named instances: :data:`PRESETS`)."""

    name: str = "default"
    """Preset name (recorded with the results)."""
    observe: _observe.ObserveConfig = field(default_factory=_observe.ObserveConfig)
    """s0_observe settings."""
    fit: _fit.FitConfig = field(default_factory=lambda: _fit.DEFAULT)
    """s1_fit geometry settings."""
    search: _search.SearchConfig = field(default_factory=_search.SearchConfig)
    """s2 search settings (completion candidates and the tree search; ``mode`` is the ablation)."""
    physics: _physics.PhysicsSetupConfig = field(default_factory=_physics.PhysicsSetupConfig)
    """Physics set-up settings."""
    appearance: AppearanceStageConfig = field(default_factory=AppearanceStageConfig)
    """Appearance stage settings."""


PRESETS: dict[str, PipelineConfig] = {
    "fast": PipelineConfig(
        name="fast",
        fit=_fit.FAST,
        appearance=AppearanceStageConfig(iterations=60, frames=12, spacing_px=3.0, max_splats=4_000),
    ),  # fmt: skip
    "default": PipelineConfig(name="default", fit=_fit.DEFAULT),
    "best": PipelineConfig(
        name="best",
        fit=_fit.BEST,
        appearance=AppearanceStageConfig(iterations=1000, frames=100, spacing_px=1.5, max_splats=50_000),
    ),  # fmt: skip
}
"""Named pipeline presets: ``fast`` (about a minute for the demo scene on 2 cores), ``default``, ``best``."""


def preset(name: str, *, seed: int = 0, progress: bool = True, threads: int | None = None,
           search: str | None = None) -> PipelineConfig:  # fmt: skip
    """A copy of the named preset with the seed (fit, search, physics, appearance), progress and torch thread
    settings (fit and appearance; the search's worker processes: None, one per core) and the search mode (``none``,
    ``ground``, ``tree``; None keeps the preset's) applied."""
    if name not in PRESETS:
        raise HolousdError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    if search is not None and search not in _search.MODES:
        raise HolousdError(f"unknown search mode {search!r}; choose one of {', '.join(_search.MODES)}")
    base = PRESETS[name]
    return replace(
        base,
        fit=replace(base.fit, seed=seed, progress=progress, threads=threads),
        search=replace(base.search, seed=seed, progress=progress, mode=search or base.search.mode, workers=threads),
        physics=replace(base.physics, seed=seed),
        appearance=replace(base.appearance, seed=seed, progress=progress, threads=threads),
    )


@dataclass(kw_only=True)
class StageRecord:
    """What one stage did in a pipeline run (also stored in its layer's customLayerData)."""

    name: str
    """Stage name (one of :data:`STAGES`)."""
    layer: str
    """Layer file written (absolute path)."""
    wall_s: float
    """Wall-clock time of the stage when it ran, seconds (as recorded, also when skipped now)."""
    peak_mem_mb: float
    """Peak resident memory of the process at the end of the stage, MiB."""
    input_hash: str
    """Hash of the capture manifest, the stage config and the run id of the layer below."""
    run_id: str
    """Unique id of the run that wrote the layer."""
    skipped: bool = False
    """True when ``--resume`` found the layer up to date and did not run the stage."""
    config: dict[str, Any] = field(default_factory=dict)
    """The stage's config as a dict."""


@dataclass(kw_only=True)
class PipelineResult:
    """What :func:`reconstruct` did."""

    scene_file: Path
    """``out/scene.usda``."""
    stages: list[StageRecord]
    """One record per stage run or skipped, in order."""
    total_s: float
    """Wall time of this call, seconds."""

    @property
    def peak_mem_mb(self) -> float:
        """Largest peak memory over the stages, MiB."""
        return max((s.peak_mem_mb for s in self.stages), default=0.0)


# --------------------------------------------------------------------------------------------- hashing / records
def _jsonable(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, bool | int | float | str):
        return value
    return str(value)


def _usd_dict(value: Any) -> Any:
    """A JSON-able value as something a USD dictionary stores (None -> 'None', lists -> their JSON text)."""
    if isinstance(value, dict):
        return {k: _usd_dict(v) for k, v in value.items()}
    if value is None:
        return "None"
    if isinstance(value, list):
        return json.dumps(value)
    return value


_VOLATILE = {"progress", "threads", "device", "workers", "ray"}
"""Config fields that do not change a stage's result (left out of the input hash)."""


def _hash_config(config: Any) -> dict[str, Any]:
    def strip(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: strip(x) for k, x in v.items() if k not in _VOLATILE}
        return v

    return strip(_jsonable(config))


def _file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def capture_manifest_hash(path: str | os.PathLike[str], *, exclude: str | os.PathLike[str] | None = None) -> str:
    """SHA-256 over the capture's content: relative path and SHA-256 of every file (``gt/`` and dot-files
    skipped); a video given as a file counts with the whole folder it lies in (its side files, masks and
    depth live there). Times and sizes play no part, so a
    copied or re-extracted capture hashes the same. ``exclude``: a folder left out (an output folder placed
    inside the capture)."""
    path = Path(path).resolve()
    skip = Path(exclude).resolve() if exclude is not None else None
    digest = hashlib.sha256()
    root = path.parent if path.is_file() else path
    for folder, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not (Path(folder) == root and d == "gt")
                         and (Path(folder) / d).resolve() != skip)  # fmt: skip
        for name in sorted(files):
            if name.startswith("."):
                continue
            f = Path(folder) / name
            digest.update(f"{f.relative_to(root).as_posix()}|{_file_digest(f)}\n".encode())
    return digest.hexdigest()


def _stage_hash(manifest: str, config: Any, below_hash: str) -> str:
    from holousd import __version__

    payload = json.dumps({"holousd": __version__, "capture": manifest, "config": _hash_config(config),
                          "below": below_hash}, sort_keys=True)  # fmt: skip
    return hashlib.sha256(payload.encode()).hexdigest()


def _read_record(layer_file: Path) -> dict[str, Any] | None:
    from pxr import Sdf, Tf

    if not layer_file.is_file():
        return None
    try:
        layer = Sdf.Layer.FindOrOpen(str(layer_file))
        if layer is None:
            return None
        layer.Reload()
    except Tf.ErrorException:
        return None  # unreadable: no record, so the stage runs again and replaces it
    data = layer.customLayerData.get("holousd", {})
    record = data.get("stage") if isinstance(data, dict) else None
    return dict(record) if isinstance(record, dict) else None


def read_stage_records(folder: str | os.PathLike[str]) -> list[StageRecord]:
    """The stage records of a reconstruction folder, in pipeline order (stages never run are absent)."""
    out = []
    for name in STAGES:
        layer_file = Path(folder) / LAYERS[name]
        rec = _read_record(layer_file)
        if rec is None:
            continue
        try:
            config = json.loads(rec.get("config_json", "{}"))
        except json.JSONDecodeError:
            config = {}
        out.append(StageRecord(name=name, layer=str(layer_file.absolute()), wall_s=float(rec.get("wall_s", 0.0)),
                               peak_mem_mb=float(rec.get("peak_mem_mb", 0.0)),
                               input_hash=str(rec.get("input_hash", "")), run_id=str(rec.get("run_id", "")),
                               skipped=True, config=config))  # fmt: skip
    return out


def _write_record(layer_file: Path, record: StageRecord) -> None:
    from pxr import Sdf

    from holousd.usd._layers import save_layer

    layer = Sdf.Layer.FindOrOpen(str(layer_file))
    if layer is None:
        raise HolousdError(f"{layer_file}: the stage did not write its layer; re-run the pipeline")
    data = dict(layer.customLayerData)
    holo = dict(data.get("holousd", {}))
    holo["stage"] = {
        "name": record.name,
        "wall_s": float(record.wall_s),
        "peak_mem_mb": float(record.peak_mem_mb),
        "input_hash": record.input_hash,
        "run_id": record.run_id,
        "config": _usd_dict(record.config),
        "config_json": json.dumps(record.config, sort_keys=True),
    }
    data["holousd"] = holo
    layer.customLayerData = data
    save_layer(layer)


def _peak_mem_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _write_scene_file(out: Path, top_layer: Path) -> Path:
    """``out/scene.usda``: an empty layer over ``top_layer`` (root metadata copied), written atomically."""
    from pxr import Sdf

    from holousd.usd._layers import new_layer_over, save_layer

    base = Sdf.Layer.FindOrOpen(str(top_layer))
    base.Reload()
    layer = new_layer_over(base, out / SCENE_FILE)
    data = dict(layer.customLayerData)
    holo = dict(data.get("holousd", {}))
    holo.pop("stage", None)  # the record belongs to the stage layer, not to scene.usda
    data["holousd"] = holo
    layer.customLayerData = data
    return save_layer(layer)


# --------------------------------------------------------------------------------------------- appearance
def _appearance_frames(obs: Any, config: AppearanceStageConfig) -> list[tuple]:
    held = set(holdout_frames(len(obs)))
    train = [i for i in range(len(obs)) if i not in held] or list(range(len(obs)))
    train = [train[i] for i in evenly_spaced(len(train), config.frames)]
    return [(np.asarray(obs.rgb(i))[..., :3], obs.intrinsics[i], obs.poses[i], obs.mask(i)) for i in train]


def _run_appearance(scene: SceneGraph, obs: Any, config: AppearanceStageConfig, out: Path) -> SceneGraph:
    from holousd.render._fit import FitConfig as SplatFitConfig
    from holousd.stages._appearance import fit_appearance

    cfg = AppearanceConfig(layer=str(out / APPEARANCE_LAYER), spacing_px=config.spacing_px,
                           max_splats=config.max_splats, seed=config.seed, provenance="s3_appearance",
                           fit=SplatFitConfig(iterations=config.iterations, seed=config.seed,
                                              progress=config.progress))  # fmt: skip
    with torch_threads(config.threads):
        return fit_appearance(scene, _appearance_frames(obs, config), cfg).scene


# --------------------------------------------------------------------------------------------- the pipeline
OUTPUT_PATTERNS = ("*.usda", "*.usdc", "assets", "assets/**/*")
"""Files of an output folder a run may write (and puts back when it fails): layers, scene file, assets."""


def checked(obs: Any, log: Callable[[str], None]) -> Any:
    """``obs`` after reading and checking every frame (:meth:`Observations.validate`), with its warnings logged
    and the depth pixels without a measurement ignored; what every stage reads. Raises on the first problem."""
    from holousd.stages._observe import require_masks

    log(f"checking the capture: {len(obs)} frames of {obs.root or obs} ...")
    require_masks(obs)
    check = obs.validate()
    for line in check.warnings:
        log(f"warning: {line}")
    return obs.with_valid_depth(check)


def with_depth_source(obs: Any, observe: _observe.ObserveConfig, fit: _fit.FitConfig,
                      log: Callable[[str], None]) -> Any:  # fmt: skip
    """``obs`` with the depth ``observe.depth`` chooses (see :class:`~holousd.stages._observe.ObserveConfig`): the
    capture's as it is, or a depth prior's, estimated for the frames the fit reads before anything is written.
    An unknown prior or a bad option is refused here, with nothing written."""
    from holousd.priors._depth import make_depth_prior, with_depth_prior

    name = observe.depth
    if name == "capture" or (name == "auto" and obs.has_depth):
        if observe.depth_options:
            raise HolousdError(f"depth options {sorted(observe.depth_options)} given but no depth prior runs "
                               f"(depth {name!r}); choose one, e.g. --depth stereo")  # fmt: skip
        return obs
    prior = make_depth_prior("stereo" if name == "auto" else name, **observe.depth_options)
    where = obs.root or "<observations>"
    if obs.has_depth:
        log(f"depth: {where} has its own {obs.depth_kind} depth; using the {prior.name} prior's instead (--depth)")
    frames = evenly_spaced(len(obs), max(fit.render_frames, fit.fusion_frames))
    start = time.perf_counter()
    log(f"depth: {where} has no depth; estimating it with the {prior.name} prior ({len(frames)} frames) ..."
        if not obs.has_depth else f"depth: estimating it with the {prior.name} prior ({len(frames)} frames) ...")
    with torch_threads(fit.threads):
        out = with_depth_prior(obs, prior, frames, progress=fit.progress)
        maps = [out.depth(int(i)) for i in frames]
    given = float(np.mean([np.count_nonzero(m) / m.size for m in maps])) if maps else 0.0
    values = np.concatenate([m[m > 0] for m in maps]) if maps else np.zeros(0)
    unit = " m" if prior.kind == "metric" else ""
    median = f", median {float(np.median(values)):.2f}{unit}" if len(values) else ""
    log(f"depth: {prior.name} ({prior.kind}) gave {100 * given:.0f}% of the pixels a depth{median} in "
        f"{time.perf_counter() - start:.1f} s")  # fmt: skip
    if not len(values):
        fallback = f"using the capture's {obs.depth_kind} depth" if obs.has_depth else "fitting from the masks"
        log(f"warning: the {prior.name} prior found no depth in any frame; {fallback}")
        return obs
    return out


def _stage_configs(config: PipelineConfig) -> dict[str, Any]:
    return {"observe": config.observe, "fit": config.fit, "search": config.search, "physics": config.physics,
            "appearance": config.appearance}  # fmt: skip


def _plan(out: Path, stages: list[str], configs: dict[str, Any], manifest: str,
          resume: bool) -> list[tuple[str, str, bool, dict[str, Any] | None]]:  # fmt: skip
    """(stage, input hash, skip, existing record) per stage: with ``resume``, the stages up to the first one whose
    layer is missing or records another input hash are skipped; that stage and every one above it run."""
    plan = []
    below = ""
    forced = not resume
    for name in stages:
        input_hash = _stage_hash(manifest, configs[name], below)
        existing = None if forced else _read_record(out / LAYERS[name])
        skip = existing is not None and existing.get("input_hash") == input_hash
        forced = forced or not skip
        plan.append((name, input_hash, skip, existing if skip else None))
        below = input_hash
    return plan


def _run_stages(plan: list[tuple[str, str, bool, dict[str, Any] | None]], obs: Any, out: Path,
                config: PipelineConfig, log: Callable[[str], None]) -> list[StageRecord]:  # fmt: skip
    configs = _stage_configs(config)
    stages = [name for name, _, _, _ in plan]
    scene: SceneGraph | None = None
    records: list[StageRecord] = []
    for k, (name, input_hash, skip, existing) in enumerate(plan):
        layer_file = out / LAYERS[name]
        prefix = f"[{k + 1}/{len(plan)}] {name}"
        if skip:
            assert existing is not None
            rec = StageRecord(name=name, layer=str(layer_file), wall_s=float(existing.get("wall_s", 0.0)),
                              peak_mem_mb=float(existing.get("peak_mem_mb", 0.0)), input_hash=input_hash,
                              run_id=str(existing.get("run_id", "")), skipped=True,
                              config=_jsonable(configs[name]))  # fmt: skip
            records.append(rec)
            log(f"{prefix}: up to date ({layer_file.name}, recorded {rec.wall_s:.1f} s), skipped")
            continue
        log(f"{prefix}: running ...")
        if scene is None and k > 0:
            scene = SceneGraph.open(out / LAYERS[stages[k - 1]])
        t0 = time.perf_counter()
        if name == "observe":
            scene = _observe.run(obs, out, config.observe)
        elif name == "fit":
            scene = _fit.run(scene, obs, config.fit)
        elif name == "search":  # the stages after the fit see the cameras where the fit put them
            scene = _search.run(scene, _fit.observations_as_fitted(obs, scene), config.search, log=log)
        elif name == "physics":
            scene = _physics.run(scene, config.physics)
        else:
            scene = _run_appearance(scene, _fit.observations_as_fitted(obs, scene), config.appearance, out)
        wall = time.perf_counter() - t0
        rec = StageRecord(name=name, layer=str(layer_file), wall_s=wall, peak_mem_mb=_peak_mem_mb(),
                          input_hash=input_hash, run_id=uuid.uuid4().hex, config=_jsonable(configs[name]))  # fmt: skip
        _write_record(layer_file, rec)
        records.append(rec)
        log(f"{prefix}: done in {wall:.1f} s (peak {rec.peak_mem_mb:.0f} MiB) -> {layer_file.name}")
    return records


def reconstruct(
    input_path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    config: PipelineConfig | None = None,
    *,
    until: str | None = None,
    resume: bool = False,
    log: Callable[[str], None] | None = None,
) -> PipelineResult:
    """Run the pipeline on a capture and write ``out/scene.usda``.

    Args:
        input_path: Capture folder or file (any layout :func:`holousd.io.load` reads; instance masks needed).
        out: Output folder (created). On failure it is left exactly as it was.
        config: Settings (default: the ``default`` preset).
        until: Last stage to run (one of :data:`STAGES`; default: all).
        resume: Skip stages whose layer exists with an unchanged input hash.
        log: Called with one progress line per stage (default: print to stderr).

    Returns:
        Stage records and the scene file.

    Raises:
        HolousdError: bad input (capture, output folder, options), before anything was written; or a stage
            failed, after the output folder was put back as it was.
    """
    from holousd.io import load

    config = config or PRESETS["default"]
    if log is None:

        def log(line: str) -> None:
            print(line, file=sys.stderr, flush=True)

    if until is not None and until not in STAGES:
        raise HolousdError(f"--until {until!r}: unknown stage; choose one of {', '.join(STAGES)}")
    stages = list(STAGES[: STAGES.index(until) + 1]) if until else list(STAGES)
    if not config.appearance.enabled and "appearance" in stages:
        stages.remove("appearance")
    input_path = Path(input_path).absolute()
    if not input_path.exists():
        raise HolousdError(f"{input_path}: no such folder; give the folder of a capture (or a video file)")
    out = output_folder(out, "output folder", create=False)  # absolute: stages re-root relative paths
    capture_folder = input_path.resolve() if input_path.is_dir() else input_path.resolve().parent
    if out.resolve() == capture_folder:
        raise HolousdError(f"{out}: the output folder is the capture's own folder; choose another --out")
    start = time.perf_counter()
    obs = load(input_path)  # reads the manifest: a capture that cannot be opened fails here, before anything else
    manifest = capture_manifest_hash(input_path, exclude=out)
    plan = _plan(out, stages, _stage_configs(config), manifest, resume)
    if any(not skip for _, _, skip, _ in plan):
        obs = with_depth_source(checked(obs, log), config.observe, config.fit, log)
    out.mkdir(parents=True, exist_ok=True)
    with folder_transaction(out, OUTPUT_PATTERNS):
        records = _run_stages(plan, obs, out, config, log)
        scene_file = _write_scene_file(out, out / LAYERS[stages[-1]])
    total = time.perf_counter() - start
    log(f"reconstruct: {scene_file} in {total:.1f} s")
    return PipelineResult(scene_file=scene_file, stages=records, total_s=total)
