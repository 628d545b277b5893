"""Shared fixtures: the example scene written once per session, and a copy per test that may modify it."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from holousd.synth import build_example_scene


@pytest.fixture(scope="session")
def example_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Folder holding the example scene (scene.usda + assets/); treat it as read-only."""
    out = tmp_path_factory.mktemp("example")
    build_example_scene(out)
    return out


@pytest.fixture()
def example_copy(example_dir: Path, tmp_path: Path) -> Path:
    """A private, writable copy of the example scene folder; returns the scene.usda path."""
    dest = tmp_path / "example"
    shutil.copytree(example_dir, dest)
    return dest / "scene.usda"
