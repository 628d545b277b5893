"""``holousd batch``: one task per capture on a local pool or on Ray; failures reported, reruns resumed."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
from pxr import Sdf

from holousd.batch import BatchConfig, run_batch, run_tasks
from holousd.io import load
from holousd.stages import _search
from holousd.stages._pipeline import preset
from holousd.synth import SynthConfig, generate_suite
from holousd.usd import SceneGraph, data_layer_path


def _tiny():  # noqa: ANN202 - PipelineConfig
    cfg = preset("fast", progress=False)
    return replace(cfg, fit=replace(cfg.fit, iterations=2))


@pytest.fixture(scope="module")
def captures(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    root = tmp_path_factory.mktemp("batch")
    generate_suite("demo", root / "synth", SynthConfig(frames=6, width=48, height=48, progress=False))
    rooms = [root / "room1", root / "room2"]
    for room in rooms:
        shutil.copytree(root / "synth" / "demo", room)
    broken = root / "broken"
    broken.mkdir()
    (broken / "observations.json").write_text("{")  # a corrupt manifest
    return [rooms[0], broken, rooms[1]]


def _layer(path: Path) -> str:
    layer = Sdf.Layer.OpenAsAnonymous(str(path))
    data = dict(layer.customLayerData)
    holo = dict(data.get("holousd", {}))
    holo.pop("stage", None)  # wall time, memory and run id differ from run to run
    data["holousd"] = holo
    layer.customLayerData = data
    crate = data_layer_path(path)  # and the large arrays, kept in the layer's crate file
    return layer.ExportToString() + (Sdf.Layer.OpenAsAnonymous(str(crate)).ExportToString() if crate.is_file() else "")


def _check_rows(rows: list[dict], out: Path, run: list[str]) -> None:
    assert [Path(r["out"]).name for r in rows] == ["room1", "broken", "room2"]  # the order given
    bad = rows[1]
    assert bad["status"] == "failed" and "observations.json" in bad["error"] and "\n" not in bad["error"]
    assert not (out / "broken").exists() or not any((out / "broken").iterdir())  # nothing half-written
    for row in (rows[0], rows[2]):
        assert row["status"] == "done" and row["stages_run"] == run and row["objects"] == 10, row


def test_batch_on_a_local_pool_reports_the_failure_and_a_rerun_skips_what_is_done(
        captures: list[Path], tmp_path: Path) -> None:  # fmt: skip
    out = tmp_path / "out"
    result = run_batch(captures, out, BatchConfig(pipeline=_tiny(), until="fit", workers=2, progress=False))
    _check_rows(result.rows, out, ["observe", "fit"])
    saved = json.loads((out / "batch.json").read_text())
    assert [r["status"] for r in saved["captures"]] == ["done", "failed", "done"] and saved["wall_s"] > 0
    assert _layer(out / "room1" / "10_fit.usda") == _layer(out / "room2" / "10_fit.usda")  # the same capture
    again = run_batch(captures, out, BatchConfig(pipeline=_tiny(), until="fit", workers=1, progress=False))
    _check_rows(again.rows, out, [])
    assert again.rows[0]["stages_skipped"] == ["observe", "fit"]


def test_an_interrupted_batch_is_resumed(captures: list[Path], tmp_path: Path) -> None:
    out = tmp_path / "out"
    held = tmp_path / "held"  # the batch holds in room2's fit (it would finish before a busy machine stopped it)
    script = (f"import pathlib, signal, time\n"
              f"signal.signal(signal.SIGINT, signal.default_int_handler)\n"  # a shell's background jobs ignore it
              f"import holousd.stages._fit as fit\n"
              f"from holousd.batch import BatchConfig, run_batch\n"
              f"from tests.test_batch import _tiny\n"
              f"run = fit.run\n"
              f"def holding(scene, obs, config):\n"
              f"    if 'room2' in str(scene.path):\n"
              f"        pathlib.Path({str(held)!r}).touch()\n"
              f"        time.sleep(300)\n"
              f"    return run(scene, obs, config)\n"
              f"fit.run = holding\n"
              f"run_batch({[str(c) for c in captures]!r}, {str(out)!r}, "
              f"BatchConfig(pipeline=_tiny(), until='fit', workers=1, progress=False))\n")  # fmt: skip
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=root, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not held.is_file():  # the first capture done, the second under way: stop the batch there
        assert proc.poll() is None and time.monotonic() < deadline, "the batch ended before it could be stopped"
        time.sleep(0.2)
    assert (out / "room1" / "scene.usda").is_file()
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=120)
    assert not (out / "batch.json").exists()  # it did not get to the end
    assert not (out / "room2" / "10_fit.usda").exists()  # the capture under way was rolled back, not half-written
    result = run_batch(captures, out, BatchConfig(pipeline=_tiny(), until="fit", workers=1, progress=False))
    assert result.rows[0]["stages_run"] == [] and result.rows[2]["stages_run"] == ["observe", "fit"]
    assert _layer(out / "room1" / "10_fit.usda") == _layer(out / "room2" / "10_fit.usda")


def _twice(x: int) -> int:
    if x < 0:
        raise ValueError(f"negative: {x}")
    return 2 * x


def test_ray_tasks_give_what_the_local_pool_gives(captures: list[Path], tmp_path: Path) -> None:
    ray = pytest.importorskip("ray", reason="Ray is the optional extra holousd[ray]")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        outcomes = run_tasks(_twice, [(str(k), (k,)) for k in (3, -1, 5, 0)], ray="auto")
        assert [o.value for o in outcomes] == [6, None, 10, 0]  # in the order given, whatever order they ended
        assert not outcomes[1].ok and outcomes[1].error == "internal error (ValueError: negative: -1)"
        out = tmp_path / "ray"
        result = run_batch(captures, out, BatchConfig(pipeline=_tiny(), until="fit", ray="auto", progress=False))
        searched = {}
        for engine, options in (("ray", {"ray": "auto"}), ("local", {"workers": 1})):
            shutil.copytree(out / "room1", tmp_path / f"search-{engine}")
            scene = SceneGraph.open(tmp_path / f"search-{engine}" / "scene.usda")
            found = _search.search(scene, load(captures[0]), _search.SearchConfig(**options))
            searched[engine] = [(c.name, c.parent, c.chosen, [s.total for s in c.scores]) for c in found.choices]
    finally:
        ray.shutdown()
    _check_rows(result.rows, out, ["observe", "fit"])
    local = tmp_path / "local"
    run_batch(captures[:1], local, BatchConfig(pipeline=_tiny(), until="fit", workers=1, progress=False))
    assert _layer(out / "room1" / "10_fit.usda") == _layer(local / "room1" / "10_fit.usda")
    assert searched["ray"] and searched["ray"] == searched["local"]  # the search's candidates on Ray: the same choices
    assert _layer(tmp_path / "search-ray" / "15_search.usda") == _layer(tmp_path / "search-local" / "15_search.usda")


def _worker_state(_: int) -> tuple[int, str | None]:
    import os

    return os.getpid(), os.environ.get("OMP_NUM_THREADS")


def test_a_task_pool_keeps_its_workers_and_gives_each_its_share_of_the_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    from holousd._tasks import TaskPool, available_cores

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    with TaskPool(workers=2) as pool:
        first = pool.run(_worker_state, [(str(k), (k,)) for k in range(4)])
        again = pool.run(_worker_state, [(str(k), (k,)) for k in range(4)])
    pids = {o.value[0] for o in first}
    assert len(pids) == 2 and {o.value[0] for o in again} <= pids  # the same warm processes, no new spawn
    assert {o.value[1] for o in first} == {str(max(1, available_cores() // 2))}  # BLAS threads: the worker's share
    assert "OMP_NUM_THREADS" not in __import__("os").environ  # this process's environment as it was


def test_ray_overhead_is_the_wait_of_a_free_worker_and_the_trip_back() -> None:
    from holousd._tasks import TaskOutcome, overhead

    def task(started: float, ended: float) -> TaskOutcome:
        return TaskOutcome(key="t", ok=True, submitted=100.0, started=started, ended=ended, received=ended + 0.2)

    # two slots: two tasks start 1.0 and 1.5 s after submission; the third starts 0.5 s after the first end
    cost = overhead([task(101.0, 111.0), task(101.5, 106.5), task(107.0, 112.0)], slots=2)
    assert cost["dispatch_s"] == pytest.approx((1.0 + 1.5 + 0.5) / 3) and cost["return_s"] == pytest.approx(0.2)


def test_batch_refuses_bad_arguments_before_any_task(captures: list[Path], tmp_path: Path) -> None:
    from holousd._errors import HolousdError

    with pytest.raises(HolousdError, match="no such capture"):
        run_batch([captures[0], tmp_path / "missing"], tmp_path / "out", BatchConfig(progress=False))
    twin = tmp_path / "twin" / "room1"
    twin.mkdir(parents=True)
    with pytest.raises(HolousdError, match="two captures are named 'room1'"):
        run_batch([captures[0], twin], tmp_path / "out", BatchConfig(progress=False))
    assert not (tmp_path / "out").exists()
