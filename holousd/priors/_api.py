"""What a completion proposer gets and gives, and how proposers are found.

A proposer takes one object's evidence (:class:`ObjectEvidence`: its masks, depth and colours per frame, its
observed surface points, its fitted SDF and mesh, its support and neighbours) and returns up to ``k``
:class:`Candidate` shapes for the whole object, the sides no camera saw included, each a watertight mesh and its
SDF on the object's grid. Proposers are objects with a ``name`` and a ``propose(evidence, k, seed)`` method
(:class:`CompletionProposer`). The built-in ones need no weights; a plug-in registers a factory under the
entry-point group ``holousd.completion`` (in its ``pyproject.toml``: ``[project.entry-points."holousd.completion"]
my_prior = "my_package:make_proposer"``), called with the keyword arguments the user gives for it (a weights
path, a device). Nothing is ever downloaded: a learned prior reads the weights from the path it is given.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from holousd._errors import HolousdError
from holousd.usd._types import MeshData, Pose, SdfField

__all__ = [
    "ENTRY_POINT_GROUP",
    "Candidate",
    "CompletionProposer",
    "FrameEvidence",
    "ObjectEvidence",
    "available_proposers",
    "make_proposer",
]

ENTRY_POINT_GROUP = "holousd.completion"
"""Entry-point group under which completion plug-ins register a proposer factory."""


@dataclass(kw_only=True)
class FrameEvidence:
    """One frame as the object's proposers and scores read it."""

    index: int
    """Frame index in the capture."""
    intrinsics: np.ndarray
    """[3, 3] pinhole intrinsics, pixels."""
    camera_to_world: np.ndarray
    """[4, 4] camera-to-world (OpenCV camera)."""
    labels: np.ndarray
    """[H, W] int32 instance ids of the frame (0 = background)."""
    depth: np.ndarray | None = None
    """[H, W] float32 metric z-depth, 0 where there is no measurement; None without depth."""
    rgb: np.ndarray | None = None
    """[H, W, 3] uint8 colours, or None when not loaded."""


@dataclass(kw_only=True)
class ObjectEvidence:
    """Everything known about one object before its unseen geometry is proposed (world frame unless said)."""

    name: str
    """Node name."""
    instance_id: int
    """The object's id in the frames' instance masks."""
    pose: Pose
    """Object-to-world pose; candidate meshes and SDFs are in object coordinates."""
    mesh: MeshData
    """The stage-1 (fitted) mesh, object coordinates."""
    sdf: SdfField | None
    """The stage-1 SDF (object coordinates); its grid is the grid candidates' SDFs are sampled on."""
    frames: list[FrameEvidence]
    """The frames that see the object."""
    points: np.ndarray
    """[P, 3] observed surface points of the object: its masked depth pixels back-projected (world)."""
    support: str | None = None
    """The node it rests on (None: not known)."""
    support_height: float | None = None
    """Height of the support's surface under the object, metres (the floor for the room)."""
    neighbours: dict[str, MeshData] = field(default_factory=dict)
    """World meshes of the support and the objects around it."""


@dataclass(kw_only=True)
class Candidate:
    """One proposed complete shape of an object."""

    proposer: str
    """Name of the proposer that made it."""
    seed: int
    """Seed it was made with (the same seed gives the same candidate)."""
    mesh: MeshData
    """Watertight mesh, object coordinates."""
    sdf: SdfField | None = None
    """SDF on the object's grid, object coordinates (None when the object has no grid)."""
    note: str = ""
    """How it was made, one line (the symmetry plane, the primitive and its size, ...)."""


@runtime_checkable
class CompletionProposer(Protocol):
    """A completion prior: ``propose`` returns up to ``k`` candidates for the object (fewer when it has no more
    distinct ones, none when it does not apply)."""

    name: str

    def propose(self, evidence: ObjectEvidence, k: int, seed: int) -> list[Candidate]: ...


def _builtin() -> dict[str, Callable[..., CompletionProposer]]:
    from holousd.priors import _builtin as b

    return {"stage1": b.Stage1Proposer, "extrude": b.ExtrudeProposer, "symmetry": b.SymmetryProposer,
            "primitive": b.PrimitiveProposer, "visual_hull": b.VisualHullProposer,
            "learned": b.LearnedProposer}  # fmt: skip


def group_entry_points(group: str) -> dict[str, Any]:
    """The installed entry points of ``group``, by name."""
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=group)}


def plugin_names(builtin: dict[str, Any], found: dict[str, Any]) -> list[str]:
    """The built-in names, then the installed plug-ins' (``found``: entry points by name) not among them."""
    names = list(builtin)
    return names + sorted(n for n in found if n not in names)


def plugin_factory(what: str, name: str, builtin: dict[str, Any], found: dict[str, Any], group: str) -> Any:
    """The factory of the ``what`` (e.g. 'completion proposer') called ``name``: built in, or the entry point of
    that name in ``found`` loaded. Raises :class:`HolousdError` naming the choices, or the plug-in that fails."""
    if name in builtin:
        return builtin[name]
    entry = found.get(name)
    if entry is None:
        raise HolousdError(f"{what} {name!r}: none by that name; available: {', '.join(plugin_names(builtin, found))} "
                           f"(plug-ins register under the entry-point group {group!r})")  # fmt: skip
    try:
        return entry.load()
    except Exception as exc:  # noqa: BLE001 - a broken plug-in is the user's to fix: say which and why
        raise HolousdError(f"{what} {name!r} ({entry.value}): cannot be loaded ({exc}); reinstall the package that "
                           "provides it") from None  # fmt: skip


def _entry_points() -> dict[str, Any]:
    return group_entry_points(ENTRY_POINT_GROUP)


def available_proposers() -> list[str]:
    """Names of the built-in proposers, then the installed plug-ins'."""
    return plugin_names(_builtin(), _entry_points())


def make_proposer(name: str, **options: Any) -> CompletionProposer:
    """The proposer called ``name``: a built-in one, or a plug-in's factory called with ``options``.

    Raises:
        HolousdError: no proposer has that name, the plug-in cannot be loaded, or it does not make a proposer.
    """
    factory = plugin_factory("completion proposer", name, _builtin(), _entry_points(), ENTRY_POINT_GROUP)
    proposer = factory(**options)
    if not isinstance(proposer, CompletionProposer):
        raise HolousdError(f"completion proposer {name!r}: its factory returned {type(proposer).__name__}, which "
                           "has no name and propose(evidence, k, seed)")  # fmt: skip
    return proposer
