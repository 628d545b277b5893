"""Synthetic scenes: the bundled example scene and the procedural benchmark suites (demo, bench, hard).

``generate_suite('hard', 'out/', SynthConfig())`` writes one folder per scene with a rendered capture
(readable with :func:`holousd.io.load`) and complete ground truth under ``<scene>/gt/``.
"""

from holousd.synth._example import build_example_scene, splats_on_mesh
from holousd.synth._generate import SceneResult, SynthConfig, generate_scene, generate_suite, object_meshes
from holousd.synth._layout import PlacedObject, Room, SceneBuilder, SceneSpec
from holousd.synth._sensor import SENSORS, SensorModel, sensor_model
from holousd.synth._suites import HARD_SCENES, SUITES, build_scene, scene_names

__all__ = [
    "HARD_SCENES",
    "SENSORS",
    "SUITES",
    "PlacedObject",
    "Room",
    "SceneBuilder",
    "SceneResult",
    "SceneSpec",
    "SensorModel",
    "SynthConfig",
    "build_example_scene",
    "build_scene",
    "generate_scene",
    "generate_suite",
    "object_meshes",
    "scene_names",
    "sensor_model",
    "splats_on_mesh",
]
