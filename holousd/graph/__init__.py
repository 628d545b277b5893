"""Support / beside inference: which node each object rests on and which siblings it touches.

``infer_relations(meshes, background)`` reads world-space meshes and returns a support tree rooted at the
background plus the beside (touching siblings) pairs; :mod:`holousd.stages` writes them with
``SceneGraph.set_support`` / ``set_beside``.
"""

from holousd.graph._relations import RelationConfig, Relations, infer_relations, push_out_of, settle_offsets

__all__ = ["RelationConfig", "Relations", "infer_relations", "push_out_of", "settle_offsets"]
