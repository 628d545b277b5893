"""Stage-to-stage transforms of the reconstruction pipeline (ARCHITECTURE.md section 2).

Each stage is a module with ``run(...) -> SceneGraph`` that pushes and saves its own layer:

- :mod:`observe` (s0_observe): cameras, image references, one node per instance -> ``00_observe.usda``;
- :mod:`fit` (s1_fit geometry): per-instance SDFs by TSDF fusion + differentiable volume rendering,
  watertight meshes -> ``10_fit.usda`` (presets ``fit.FAST``, ``fit.DEFAULT``, ``fit.BEST``);
- :mod:`physics_setup` (support-graph part of s2_physics): support tree, beside pairs, settling onto the parent,
  colliders, mass and material -> ``20_physics.usda``;
- :mod:`appearance`: Gaussians-on-mesh fitting (stage 1 appearance and stage 3 refinement) -> ``30_appearance.usda``;
- :mod:`pipeline`: chains them into ``scene.usda`` with per-stage records, presets and ``--resume``
  (``holousd reconstruct``).

Stage configs share class names (``FitConfig``), so they are reached through their module:
``holousd.stages.fit.FitConfig``.
"""

from holousd.stages import _appearance as appearance
from holousd.stages import _fit as fit
from holousd.stages import _observe as observe
from holousd.stages import _physics_setup as physics_setup
from holousd.stages import _pipeline as pipeline
from holousd.stages._appearance import AppearanceConfig, AppearanceResult, fit_appearance
from holousd.stages._pipeline import PRESETS, PipelineConfig, PipelineResult, reconstruct

__all__ = [
    "PRESETS",
    "AppearanceConfig",
    "AppearanceResult",
    "PipelineConfig",
    "PipelineResult",
    "appearance",
    "fit",
    "fit_appearance",
    "observe",
    "physics_setup",
    "pipeline",
    "reconstruct",
]
