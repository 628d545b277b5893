"""Registration of the holousd codeless schema plugin with OpenUSD's plugin registry.

USD builds its schema registry once, on the first query (opening a stage that has prims, any
``Usd.SchemaRegistry`` call). A plugin registered after that is silently ignored, so ``import holousd`` registers
ours first and then checks that it took effect.
"""

from __future__ import annotations

from pathlib import Path

from holousd._errors import HolousdError

__all__ = ["SCHEMA_VERSION", "API_SCHEMAS", "plugin_resources_dir", "register"]

SCHEMA_VERSION = 1
"""Version of the holousd schemas this release writes and reads (root-layer customLayerData ``holousd``)."""

API_SCHEMAS = (
    "HoloNodeAPI",
    "HoloSdfAPI",
    "HoloGaussianOnMeshAPI",
    "HoloPhysicsAPI",
    "HoloGeometryAPI",
    "HoloRelationsAPI",
    "HoloEnergyAPI",
    "HoloCameraAPI",
)
"""The applied API schemas defined in ``schemas/holousd/schema.usda``."""

_registered = False


def plugin_resources_dir() -> Path:
    """Return the folder holding ``plugInfo.json`` and ``generatedSchema.usda``.

    The plugin's home is the repository's top-level ``plugins/holousd/resources``; ``holousd/_plugins`` is a
    symbolic link to ``plugins/``, and an installed package carries a copy there. The top-level folder is the
    fallback for a checkout where the link did not survive (e.g. a file system without symbolic links).
    """
    package_dir = Path(__file__).resolve().parents[1]
    candidates = (
        package_dir / "_plugins" / "holousd" / "resources",
        package_dir.parent / "plugins" / "holousd" / "resources",
    )
    for candidate in candidates:
        if (candidate / "plugInfo.json").is_file():
            return candidate
    raise HolousdError(
        f"holousd schema plugin not found (looked in {', '.join(str(c) for c in candidates)}): "
        "reinstall holousd with 'pip install .' from the repository root"
    )


def register() -> None:
    """Register the holousd schema plugin and check that USD knows our API schemas.

    Raises:
        HolousdError: the schema registry was built before the plugin could be registered (import holousd
            before anything opens a stage or queries ``Usd.SchemaRegistry``), or the plugin files are missing.
    """
    global _registered
    if _registered:
        return
    from pxr import Plug, Usd

    Plug.Registry().RegisterPlugins(str(plugin_resources_dir()))
    if Usd.SchemaRegistry().FindAppliedAPIPrimDefinition("HoloNodeAPI") is None:
        raise HolousdError(
            "the USD schema registry was built before holousd registered its schemas: "
            "'import holousd' before opening any stage or querying Usd.SchemaRegistry (or set "
            f"PXR_PLUGINPATH_NAME={plugin_resources_dir()} in the environment)"
        )
    _registered = True
