"""The holousd command: help, info, validate, export, example; exit codes and one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from holousd.cli import main


def test_entry_point_help() -> None:
    result = subprocess.run([sys.executable, "-m", "holousd.cli", "--help"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0
    for command in ("info", "validate", "export", "example"):
        assert command in result.stdout


def test_no_command_prints_help(capsys: pytest.CaptureFixture) -> None:
    assert main([]) == 2
    assert "usage: holousd" in capsys.readouterr().out


def test_subcommand_help_shows_real_defaults_only(capsys: pytest.CaptureFixture,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    monkeypatch.setenv("COLUMNS", "80")
    for command in ("stability", "bench", "bench-fit", "eval"):  # prose is wrapped to the terminal, % not doubled
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = capsys.readouterr().out
        assert max(len(line) for line in text.splitlines()) <= 80 and "%%" not in text, command
    for command in ("reconstruct", "demo", "bench", "synth", "fit", "stability", "simulate"):
        with pytest.raises(SystemExit) as exit_info:
            main([command, "--help"])
        assert exit_info.value.code == 0
        text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
        assert "(default: None)" not in text and "(default: False)" not in text, command
        if command not in ("stability", "simulate"):  # the physics commands take no seed
            assert "--seed SEED" in text and "(default: 0)" in text, command
        else:
            assert "(default: 2.0)" in text, command
    with pytest.raises(SystemExit):  # the demo's capture size reads as a size, not as a Python tuple
        main(["demo", "--help"])
    assert "capture size (default: 160x120)" in " ".join(capsys.readouterr().out.split())


def test_info_table_and_json(example_dir: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["info", str(example_dir / "scene.usda")]) == 0
    out = capsys.readouterr().out
    assert "mug" in out and "book" in out and "8000 splats" in out
    assert main(["info", str(example_dir / "scene.usda"), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    nodes = {n["name"]: n for n in data["nodes"]}
    assert nodes["mug"]["supported_by"] == "book"
    assert nodes["table"]["collider"] == "convexDecomposition" and nodes["table"]["collider_parts"] == 5
    assert nodes["background"]["mass_kg"] is None
    assert data["total_splats"] == 8000 and data["up_axis"] == "Z"


def test_validate_exit_codes(example_copy: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["validate", str(example_copy)]) == 0
    from holousd import SceneGraph

    scene = SceneGraph.open(example_copy)
    scene.set_support("table", "mug")
    scene.save()
    assert main(["validate", str(example_copy), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] is False
    assert any(i["rule"] == "holousd:support-cycle" for i in report["issues"])


@pytest.mark.parametrize("content", [None, b"not usd at all", b"#usda 1.0\n def {{{"])
def test_bad_input_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture, content: bytes | None) -> None:
    path = tmp_path / "scene.usda"
    if content is not None:
        path.write_bytes(content)
    for command in (["info"], ["validate"], ["export", "--sim", str(tmp_path / "out.usda")]):
        assert main([*command[:1], str(path), *command[1:]]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(path) in err, err
    assert not (tmp_path / "out.usda").exists()


def test_export_refuses_to_overwrite_input(example_copy: Path, capsys: pytest.CaptureFixture) -> None:
    before = example_copy.read_bytes()
    assert main(["export", str(example_copy), "--sim", str(example_copy)]) == 2
    assert "refusing to overwrite" in capsys.readouterr().err
    assert example_copy.read_bytes() == before


def test_export_failure_keeps_existing_output(example_copy: Path, tmp_path: Path) -> None:
    out = tmp_path / "old.usdz"
    out.write_bytes(b"previous output")
    scene_dirty = tmp_path / "bad.usdz.usda"
    assert main(["export", str(example_copy), "--usdz", str(tmp_path / "x.zip")]) == 2  # wrong suffix
    assert main(["export", str(scene_dirty), "--usdz", str(out)]) == 2  # missing input
    assert out.read_bytes() == b"previous output"


def test_export_usdz_packages_assets(example_copy: Path, tmp_path: Path) -> None:
    import zipfile

    out = tmp_path / "scene.usdz"
    assert main(["export", str(example_copy), "--usdz", str(out)]) == 0
    names = zipfile.ZipFile(out).namelist()
    assert names == ["scene.usdc"]  # one crate file: the splats inline, no .npz (a package holds no such file)
    from holousd import SceneGraph

    packed = SceneGraph.open(out)
    assert len(packed.get_gaussians("mug")) == 2000 and packed.get_support("mug") == "book"
    assert main(["validate", str(out)]) == 0


def test_example_command(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["example", str(tmp_path / "ex")]) == 0
    assert (tmp_path / "ex" / "scene.usda").is_file()
    assert main(["example", str(tmp_path / "ex")]) == 2  # exists: refuse without --overwrite
    assert "already exists" in capsys.readouterr().err
