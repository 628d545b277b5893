"""The codeless schema plugin: generation, registration, applied values, and reading without the plugin."""

from __future__ import annotations

import filecmp
import os
import shutil
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest
from pxr import Usd

import holousd
from holousd.usd import API_SCHEMAS, plugin_resources_dir

REPO = Path(__file__).resolve().parents[1]


def _run(code: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        env={**os.environ, **env},
        timeout=120,
    )


def test_generated_plugin_matches_schema_source(tmp_path: Path) -> None:
    """Regenerating from schemas/holousd/schema.usda reproduces the committed plugin files exactly."""
    resources = REPO / "plugins" / "holousd" / "resources"
    out = tmp_path / "resources"
    out.mkdir()
    # usdGenSchema keeps hand edits to plugInfo.json (our LibraryPath/ResourcePath/Root): start from the committed one
    (out / "plugInfo.json").write_bytes((resources / "plugInfo.json").read_bytes())
    result = subprocess.run(
        [sys.executable, "-m", "pxr.Usd.usdGenSchema", str(REPO / "schemas" / "holousd" / "schema.usda"), str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    for name in ("generatedSchema.usda", "plugInfo.json"):
        assert filecmp.cmp(out / name, resources / name, shallow=False), (
            f"{name} is stale: run python -m pxr.Usd.usdGenSchema schemas/holousd/schema.usda "
            "plugins/holousd/resources and commit the result"
        )


def test_all_api_schemas_registered_with_holo_properties() -> None:
    registry = Usd.SchemaRegistry()
    for name in API_SCHEMAS:
        definition = registry.FindAppliedAPIPrimDefinition(name)
        assert definition is not None, name
        names = definition.GetPropertyNames()
        assert names and all(n.startswith("holo:") for n in names), (name, names)
        for prop in names:
            assert definition.GetPropertyDocumentation(prop), f"{name}.{prop} has no doc string"


def test_apply_api_and_authored_values() -> None:
    stage = Usd.Stage.CreateInMemory()
    prim = stage.DefinePrim("/N", "Xform")
    for name in API_SCHEMAS:
        assert prim.ApplyAPI(name)
        assert prim.HasAPI(name)
    assert prim.GetAttribute("holo:node:role").Get() == "object"  # fallback from the schema
    prim.GetAttribute("holo:node:role").Set("background")
    prim.GetAttribute("holo:physics:linearDamping").Set(0.25)
    assert prim.GetAttribute("holo:node:role").Get() == "background"
    assert prim.GetAttribute("holo:physics:linearDamping").Get() == pytest.approx(0.25)
    assert prim.GetRelationship("holo:supportedBy")


def test_registry_built_before_import_gives_clear_error() -> None:
    result = _run(
        """
        from pxr import Usd
        Usd.SchemaRegistry().FindAppliedAPIPrimDefinition("CollisionAPI")
        import holousd
        """
    )
    assert result.returncode != 0
    assert "schema registry was built before holousd registered its schemas" in result.stderr


def test_import_is_light() -> None:
    result = _run(
        """
        import sys
        import holousd, holousd.cli
        holousd.cli.build_parser()
        heavy = [m for m in ("torch", "warp", "newton", "mujoco", "coacd") if m in sys.modules]
        print(",".join(heavy))
        """
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "", f"import holousd pulled in {result.stdout.strip()}"


def test_scene_reads_without_plugin(example_dir: Path) -> None:
    """A viewer without our plugin keeps every authored value (fallbacks are not needed)."""
    result = _run(
        f"""
        from pxr import Usd
        stage = Usd.Stage.Open({str(example_dir / "scene.usda")!r})
        assert Usd.SchemaRegistry().FindAppliedAPIPrimDefinition("HoloNodeAPI") is None
        mug = stage.GetPrimAtPath("/World/Objects/mug")
        print(mug.GetAttribute("holo:node:instanceId").Get())
        print(mug.GetAttribute("holo:node:role").Get())
        print(mug.GetRelationship("holo:supportedBy").GetTargets()[0])
        print(mug.GetAttribute("holo:physics:linearDamping").Get())
        print(mug.GetAttribute("holo:sdf:voxelSize").Get())
        print(len(stage.GetPrimAtPath("/World/Objects/mug/Splats").GetAttribute("holo:gom:faceIndex").Get()))
        """
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["3", "object", "/World/Objects/book", "0.0", "0.02", "2000"]


def test_wheel_ships_plugin(tmp_path: Path) -> None:
    """A plain (non-editable) install carries the schema plugin inside the package."""
    source = tmp_path / "src"
    ignore = shutil.ignore_patterns(".git", "build", "*.egg-info", "__pycache__", ".pytest_cache", "tests")
    shutil.copytree(REPO, source, symlinks=True, ignore=ignore)
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(source),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    wheel = next(tmp_path.glob("holousd-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    assert "holousd/_plugins/holousd/resources/plugInfo.json" in names
    assert "holousd/_plugins/holousd/resources/generatedSchema.usda" in names
    assert "holousd/py.typed" in names
    assert "holousd/eval/reference/bench.json" in names  # the demo report's reference speed-vs-accuracy points


def test_plugin_dir_is_found() -> None:
    assert (plugin_resources_dir() / "generatedSchema.usda").is_file()
    assert holousd.SCHEMA_VERSION == 1
