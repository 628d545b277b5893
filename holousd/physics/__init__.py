"""Physics domain: UsdPhysics stage -> Newton model, simulation, energies, colliders and stability verdicts.

Heavy engines (warp, newton, mujoco, coacd) are imported inside the functions that use them, so importing this
package stays light.
"""

from ._colliders import (
    ColliderChoice,
    DecompositionConfig,
    choose_collider,
    choose_object_collider,
    collider_verdict,
    convex_decomposition,
    convex_hull,
    convexity,
    cut_above,
    cut_axis,
    cut_below,
    cut_plane,
)
from ._energy import e_pene_mesh, e_pene_sdf, e_stable, e_touch
from ._errors import PhysicsInputError
from ._model import ColliderOverride, ModelConfig, PhysicsModel, build_model, default_device
from ._scene import resolve_object, rigid_bodies, support_chain
from ._simulate import SimulationConfig, Trajectories, simulate, simulate_model, write_trajectory_layer
from ._solvers import SOLVERS, SolverConfig
from ._stability import (
    CrossCheck,
    ObjectVerdict,
    StabilityConfig,
    StabilityReport,
    agreement_pct,
    stability,
    stability_alone,
    stability_each_alone,
)

__all__ = [
    "SOLVERS",
    "ColliderChoice",
    "ColliderOverride",
    "CrossCheck",
    "DecompositionConfig",
    "ModelConfig",
    "ObjectVerdict",
    "PhysicsInputError",
    "PhysicsModel",
    "SimulationConfig",
    "SolverConfig",
    "StabilityConfig",
    "StabilityReport",
    "Trajectories",
    "agreement_pct",
    "build_model",
    "choose_collider",
    "choose_object_collider",
    "collider_verdict",
    "convex_decomposition",
    "convex_hull",
    "convexity",
    "cut_above",
    "cut_axis",
    "cut_plane",
    "cut_below",
    "default_device",
    "e_pene_mesh",
    "e_pene_sdf",
    "e_stable",
    "e_touch",
    "resolve_object",
    "rigid_bodies",
    "simulate",
    "simulate_model",
    "stability",
    "stability_alone",
    "stability_each_alone",
    "support_chain",
    "write_trajectory_layer",
]
