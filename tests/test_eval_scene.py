"""``holousd eval`` on ground truth against itself, and the benchmark charts / tables."""

from __future__ import annotations

from pathlib import Path

import pytest

from holousd._errors import HolousdError
from holousd.eval._bench_suite import chart_vs_time, stable_table
from holousd.eval._scene_eval import EvalConfig, evaluate_scene, resolve_gt
from holousd.synth import SynthConfig, generate_suite


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth")
    generate_suite("demo", out, SynthConfig(frames=8, width=64, height=64, progress=False))
    return out / "demo"


def test_ground_truth_against_itself_is_perfect(capture: Path) -> None:
    result = evaluate_scene(capture / "gt", capture, EvalConfig(samples=200_000))
    d = result.to_dict()
    assert d["geometry"]["scene"]["f1"] == pytest.approx(100.0)
    assert d["geometry"]["objects"]["f1"] == pytest.approx(100.0)
    assert d["geometry"]["scene"]["chamfer_cm"] < 0.5 and d["geometry"]["objects"]["chamfer_cm"] < 0.5
    assert d["physics"]["stable_pct"] == pytest.approx(100.0) and d["physics"]["or_pct"] == pytest.approx(100.0)
    assert d["physics"]["penetration_cm3"] < 1.0
    assert d["physics"]["cross_check"]["stable_pct"] == pytest.approx(100.0)  # MuJoCo agrees
    assert d["render"] == {"psnr": None, "ssim": None, "mesh_psnr": None, "vertex_psnr": None}
    assert any("splats" in n for n in d["notes"])
    assert d["cost"] == {"total_s": None, "stages": {}, "peak_mem_mb": None}
    assert set(d) == {"geometry", "render", "physics", "cost", "objects", "notes"}
    assert result.support_accuracy_pct == pytest.approx(100.0)
    assert all(o["stable"] and o["f1"] == pytest.approx(100.0) for o in d["objects"])
    assert all(o["stable_cross_check"] is True for o in d["objects"])  # each object's MuJoCo verdict beside XPBD's


def test_gt_folder_is_accepted_in_both_forms(capture: Path, tmp_path: Path) -> None:
    assert resolve_gt(capture) == capture and resolve_gt(capture / "gt") == capture
    with pytest.raises(HolousdError, match="gt/graph.json"):
        resolve_gt(tmp_path)
    with pytest.raises(HolousdError, match="scene.usda"):
        evaluate_scene(tmp_path, capture)


def _run(preset: str, scene: str, wall: float, f1: float, stable: float | None, psnr: float | None) -> dict:
    return {"preset": preset, "scene": scene, "wall_s": wall,
            "eval": {"geometry": {"scene": {"f1": f1, "chamfer_cm": 3.0, "nc": 80.0}}, "render": {"psnr": psnr},
                     "physics": {"stable_pct": stable, "or_pct": 100.0, "penetration_cm3": 0.0}}}  # fmt: skip


def test_bench_chart_and_failure_mode_table(tmp_path: Path) -> None:
    from PIL import Image

    runs = [_run("fast", "stack", 30.0, 80.0, 50.0, None), _run("default", "stack", 90.0, 90.0, 100.0, None),
            _run("fast", "thin", 20.0, 70.0, None, 20.0)]  # fmt: skip
    png = chart_vs_time(runs, tmp_path / "c.png")
    img = Image.open(png)
    assert img.size[0] == 4 * 320 and len(img.getcolors(maxcolors=1 << 16) or []) > 3
    table = stable_table(runs).splitlines()
    assert table[0] == "| failure mode | fast Stable% (OR%) | default Stable% (OR%) |"
    assert table[2] == "| stack | 50 (100) | 100 (100) |" and table[3] == "| thin | - (100) | - |"


def test_eval_command_prints_json_and_table(capture: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import argparse
    import json

    from holousd.stages import _pipeline_cli

    parser = argparse.ArgumentParser()
    _pipeline_cli.add_commands(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["eval", str(capture / "gt"), "--gt", str(capture / "gt"), "--json", "--samples", "20000",
                              "--no-physics"])  # fmt: skip
    assert args.handler(args) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["physics"]["stable_pct"] is None and d["geometry"]["scene"]["f1"] == pytest.approx(100.0)
    args = parser.parse_args(["eval", str(capture / "gt"), "--gt", str(capture), "--samples", "20000", "--no-physics"])
    assert args.handler(args) == 0
    text = capsys.readouterr().out
    assert "geometry scene:" in text and "mug_1" in text and "Stable -%" in text


REPO = Path(__file__).resolve().parents[1]
REFERENCE = REPO / "holousd" / "eval" / "reference"


def test_readme_results_table_is_the_committed_bench_output() -> None:
    from holousd.eval._bench_suite import load_bench, summary_table

    files = [REFERENCE / f for f in ("bench.json", "bench_default.json", "bench_phone.json", "hard.json",
                                     "hard_ablation.json", "hard_default.json", "hard_phone.json")]
    assert all(f.is_file() for f in files), "commit the reference bench.json files the README table comes from"
    readme = (REPO / "README.md").read_text()
    start, end = "<!-- bench-table:start -->\n", "<!-- bench-table:end -->"
    section = readme[readme.index(start) + len(start) : readme.index(end)]
    payloads = [load_bench(f) for f in files]
    assert section == summary_table(payloads), (
        "README results table is stale: paste the output of `holousd bench --table "
        "holousd/eval/reference/bench.json holousd/eval/reference/bench_default.json "
        "holousd/eval/reference/bench_phone.json holousd/eval/reference/hard.json "
        "holousd/eval/reference/hard_ablation.json "
        "holousd/eval/reference/hard_default.json holousd/eval/reference/hard_phone.json`"
    )
    for payload in payloads:  # the runs behind the table are real: a command, a machine, every metric present
        assert payload["command"].startswith("holousd bench") and payload["machine"]["cores"] >= 1
        assert {r["preset"] for r in payload["runs"]} == set(payload["presets"])
        for r in payload["runs"]:
            assert r["wall_s"] > 0 and 0 < r["eval"]["geometry"]["scene"]["f1"] <= 100


def test_bench_table_rejects_other_files(tmp_path: Path) -> None:
    from holousd.eval._bench_suite import load_bench

    (tmp_path / "x.json").write_text('{"format": "something-else"}')
    with pytest.raises(HolousdError, match="not a holousd bench result"):
        load_bench(tmp_path / "x.json")
    (tmp_path / "y.json").write_text('{"format": "holousd-bench", "version": 7}')
    with pytest.raises(HolousdError, match="version 7"):
        load_bench(tmp_path / "y.json")
    (tmp_path / "z.json").write_text("{not json")
    with pytest.raises(HolousdError, match="z.json: not readable JSON"):
        load_bench(tmp_path / "z.json")
    with pytest.raises(HolousdError, match="no such file"):
        load_bench(tmp_path / "missing.json")


def test_summary_table_means_over_scenes() -> None:
    from holousd.eval._bench_suite import summary_table

    runs = [_run("fast", "a", 30.0, 80.0, 50.0, 20.0), _run("fast", "b", 50.0, 90.0, None, 22.0)]
    for r in runs:
        r["peak_mem_mb"] = 900.0
        r["eval"]["render"]["ssim"] = 0.8
    runs[0]["eval"]["physics"].update(max_collider_reach_cm=0.4, max_penetration_cm=0.2, max_fit_shift_cm=0.9)
    runs[1]["eval"]["physics"].update(max_collider_reach_cm=2.5, max_penetration_cm=None, max_fit_shift_cm=0.3)
    runs[1]["eval"]["physics"]["cross_check"] = {"solver": "mujoco", "stable_pct": 40.0, "agreement_pct": 70.0}
    payload = {"suite": "hard", "presets": ["fast"], "runs": runs, "command": "holousd bench --suite hard",
               "machine": {"cpu": "X", "cores": 2}, "date": "2026-11-22"}  # fmt: skip
    lines = summary_table([payload]).splitlines()
    # means over scenes; the records are the worst scene's; a run without a figure is left out of its mean
    assert lines[2] == ("| hard | fast | 2 | 40 | 85.0 | 3.00 | 21.0 | 0.800 | 100 | – | 50 | 40 | 70 | 2.5 | 0.2 "
                        "| 0.9 | 900 |")  # no per-object rows: no support figure
    assert lines[-1] == "- hard: `holousd bench --suite hard` on cpu X, cores 2, 2026-11-22"


def test_eval_json_from_the_command_line_is_pure_json(capture: Path) -> None:
    """A fresh ``holousd eval --json`` process (Warp initialised in it, physics on) prints nothing but the JSON."""
    import json
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "-m", "holousd.cli", "eval", str(capture / "gt"), "--gt", str(capture),
                             "--json", "--samples", "5000"], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    d = json.loads(result.stdout)
    assert d["physics"]["stable_pct"] == 100.0 and d["physics"]["cross_check"]["solver"] == "mujoco"
