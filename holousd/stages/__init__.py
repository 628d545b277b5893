"""Stage-to-stage transforms of the reconstruction pipeline (ARCHITECTURE.md section 2).

Each stage module exposes ``run(scene, observations, config) -> SceneGraph`` that pushes and saves its own layer.
"""

from holousd.stages import _appearance as appearance
from holousd.stages._appearance import AppearanceConfig, AppearanceResult, fit_appearance

__all__ = ["AppearanceConfig", "AppearanceResult", "appearance", "fit_appearance"]
