"""Synthetic scenes: the bundled example scene (procedural benchmark suites come later)."""

from holousd.synth._example import build_example_scene, splats_on_mesh

__all__ = ["build_example_scene", "splats_on_mesh"]
