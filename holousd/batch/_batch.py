"""``holousd batch``: reconstruct many captures, one task per capture, on this machine or on a Ray cluster.

Each capture ``CAPTURE`` is reconstructed into ``OUT/<name of CAPTURE>/`` by :func:`holousd.reconstruct` with
``resume=True``: a capture whose layers are up to date is skipped stage by stage (a rerun after an interruption
redoes only what did not finish), and a capture that fails leaves its folder as it was (the pipeline's own
transaction) while the others go on. At the end ``OUT/batch.json`` (written atomically) holds one row per
capture: its status, its one-line error or its figures (objects, splats, worst collider reach, penetration and
move from the fit, stages run and skipped) and its wall time.
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from holousd._atomic import atomic_path
from holousd._errors import HolousdError
from holousd._tasks import TaskOutcome, run_tasks

__all__ = ["BatchConfig", "BatchResult", "batch_table", "run_batch"]


@dataclass(kw_only=True)
class BatchConfig:
    """Settings of :func:`run_batch`."""

    pipeline: Any = None
    """``PipelineConfig`` of every capture (None: the ``default`` preset)."""
    until: str | None = None
    """Last stage to run (None: all)."""
    workers: int | None = None
    """Local worker processes (None: one per core; 1: one capture after another in this process)."""
    ray: str | None = None
    """Ray cluster: None (no Ray: a local process pool), ``"local"``, ``"auto"`` or ``"HOST:PORT"``."""
    num_cpus: float = 1.0
    """Cores each capture's Ray task declares (its torch threads follow unless the pipeline sets them)."""
    memory_mb: float | None = 3000.0
    """Memory each capture's Ray task declares, MiB (the default preset peaks near 1.7 GB on 160x120 captures)."""
    progress: bool = True
    """A progress bar over captures on stderr."""


@dataclass(kw_only=True)
class BatchResult:
    """What :func:`run_batch` did."""

    rows: list[dict[str, Any]]
    """One per capture, in the order given: capture, out, status ('done' / 'failed'), error, wall_s, figures."""
    file: Path
    """``OUT/batch.json``."""
    wall_s: float = 0.0
    """Seconds for the whole batch."""

    @property
    def failed(self) -> list[dict[str, Any]]:
        """The rows of the captures that failed."""
        return [r for r in self.rows if r["status"] != "done"]


def _figures(scene_file: Path) -> dict[str, Any]:
    from holousd.usd import SceneGraph

    nodes = [n for n in SceneGraph.open(scene_file).summary().nodes if n.role == "object"]

    def worst(values: list[float | None]) -> float | None:
        found = [v for v in values if v is not None]
        return max(found) if found else None

    return {"objects": len(nodes), "splats": sum(n.splats for n in nodes),
            "max_collider_reach_cm": worst([n.collider_reach_cm for n in nodes]),
            "max_penetration_cm": worst([n.penetration_cm for n in nodes]),
            "max_fit_shift_cm": worst([n.fit_shift_cm for n in nodes])}  # fmt: skip


def reconstruct_capture(capture: str, out: str, config: Any, until: str | None, threads: int | None) -> dict:
    """One batch task: reconstruct ``capture`` into ``out`` (resuming) and return its figures."""
    from dataclasses import replace

    from holousd.stages._pipeline import PRESETS, reconstruct

    config = config or PRESETS["default"]
    if threads is not None:  # a worker process of its own (never this process: its setting is the caller's)
        import torch

        torch.set_num_threads(threads)
        config = replace(config, fit=replace(config.fit, threads=config.fit.threads or threads),
                         appearance=replace(config.appearance,
                                            threads=config.appearance.threads or threads))  # fmt: skip
    lines: list[str] = []
    result = reconstruct(capture, out, config, until=until, resume=True, log=lines.append)
    return {"scene": str(result.scene_file), "reconstruct_s": result.total_s,
            "stages_run": [s.name for s in result.stages if not s.skipped],
            "stages_skipped": [s.name for s in result.stages if s.skipped], **_figures(result.scene_file)}  # fmt: skip


def _names(captures: list[Path]) -> list[str]:
    names = [(c.name if c.is_dir() else c.stem) for c in captures]
    seen: dict[str, Path] = {}
    for name, capture in zip(names, captures, strict=True):
        if name in seen:
            raise HolousdError(f"{capture}: two captures are named {name!r} ({seen[name]} too); each goes to "
                               f"OUT/{name}/, so rename one of them or run them in two batches")  # fmt: skip
        seen[name] = capture
    return names


def run_batch(captures: list[str | os.PathLike[str]], out: str | os.PathLike[str],
              config: BatchConfig | None = None) -> BatchResult:  # fmt: skip
    """Reconstruct every capture into ``out/<capture name>/``; write ``out/batch.json``.

    Raises:
        HolousdError: before any task starts, when a capture does not exist, two share a name, or the output
            folder cannot be used. A capture that fails later is reported in its row, not raised.
    """
    from holousd._paths import output_folder

    config = config or BatchConfig()
    paths = [Path(c).absolute() for c in captures]
    if not paths:
        raise HolousdError("no capture given; pass one or more capture folders: holousd batch CAPTURE... --out DIR")
    for p in paths:
        if not p.exists():
            raise HolousdError(f"{p}: no such capture; give capture folders (or video files) that exist")
    names = _names(paths)
    out = output_folder(out, "--out", create=True)
    threads = None
    if config.ray is not None:
        threads = max(1, int(config.num_cpus))  # a task's torch threads: the cores it declared
    elif (config.workers or os.cpu_count() or 1) > 1:
        threads = max(1, (os.cpu_count() or 1) // min(config.workers or os.cpu_count() or 1, len(paths)))
    tasks = [(name, (str(p), str(out / name), config.pipeline, config.until, threads))
             for name, p in zip(names, paths, strict=True)]  # fmt: skip
    bar = None
    if config.progress:
        from tqdm import tqdm

        bar = tqdm(total=len(tasks), desc="captures", unit="capture", file=sys.stderr)

    def on_done(outcome: TaskOutcome) -> None:
        if bar is not None:
            bar.set_postfix_str(f"{outcome.key} {'done' if outcome.ok else 'FAILED'}", refresh=False)
            bar.update(1)
        else:
            state = "done" if outcome.ok else f"failed: {outcome.error}"
            print(f"batch: {outcome.key} {state} ({outcome.wall_s:.1f} s)", file=sys.stderr, flush=True)

    start = time.perf_counter()
    try:
        outcomes = run_tasks(reconstruct_capture, tasks, workers=config.workers, ray=config.ray,
                             num_cpus=config.num_cpus, memory_mb=config.memory_mb, on_done=on_done)  # fmt: skip
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - start
    rows = []
    for (_, args), outcome in zip(tasks, outcomes, strict=True):
        row: dict[str, Any] = {"capture": args[0], "out": args[1], "status": "done" if outcome.ok else "failed",
                               "error": outcome.error, "wall_s": outcome.wall_s}  # fmt: skip
        if outcome.ok:
            row.update(outcome.value)
        rows.append(row)
    payload = {"format": "holousd-batch", "version": 1, "date": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
               "engine": f"ray {config.ray}" if config.ray else f"local ({config.workers or os.cpu_count()} workers)",
               "wall_s": wall, "captures": rows}  # fmt: skip
    with atomic_path(out / "batch.json") as tmp:
        tmp.write_text(json.dumps(payload, indent=2))
    return BatchResult(rows=rows, file=out / "batch.json", wall_s=wall)


def batch_table(rows: list[dict[str, Any]]) -> str:
    """Markdown table of a batch: one row per capture."""

    def f(v: Any, spec: str = ".2f") -> str:
        return "-" if v is None else format(v, spec)

    lines = ["| capture | status | objects | splats | reach cm | pen cm | shift cm | stages run | wall s |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        name = Path(r["out"]).name
        if r["status"] != "done":
            lines.append(f"| {name} | failed: {r['error']} | | | | | | | {r['wall_s']:.1f} |")
            continue
        run = ", ".join(r["stages_run"]) or "none (up to date)"
        lines.append(f"| {name} | done | {r['objects']} | {r['splats']} | {f(r['max_collider_reach_cm'])} | "
                     f"{f(r['max_penetration_cm'])} | {f(r['max_fit_shift_cm'])} | {run} | "
                     f"{r['wall_s']:.1f} |")  # fmt: skip
    return "\n".join(lines) + "\n"
