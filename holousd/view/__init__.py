"""The browser viewer and editor (``holousd view``): splats or coloured meshes, the support tree, a gizmo to move
and turn objects, edits saved as a layer over the scene, and live Newton physics (drop, push) from the edited
state, saved as a time-sampled layer.

:class:`ViewSession` is the state and every action without a browser (usable from Python and tests);
:class:`ViewServer` puts it on a viser page. viser is an optional dependency (``pip install -e ".[view]"``).
"""

from ._session import Motion, NodeView, SplatArrays, ViewConfig, ViewSession

__all__ = ["Motion", "NodeView", "SplatArrays", "ViewConfig", "ViewServer", "ViewSession"]


def __getattr__(name: str) -> object:
    if name == "ViewServer":  # imports viser
        from ._server import ViewServer

        return ViewServer
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
