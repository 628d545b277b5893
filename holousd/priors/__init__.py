"""Completion priors: proposals for every object's unseen geometry, and how well each explains the observations.

The proposers (:func:`make_proposer`; built in: ``stage1``, ``extrude``, ``symmetry``, ``primitive``,
``visual_hull``, and ``learned`` for a model from a weights path; plug-ins under the entry-point group
``holousd.completion``) turn an object's evidence (:func:`object_evidence`) into candidate shapes;
:func:`observation_energy` scores each against every frame (E_obs). :func:`propose` does both for a list of
proposers. The physics tree search that chooses among them is the stage after the fit.

Depth priors (:func:`make_depth_prior`; built in: ``stereo``, multi-view stereo from the colour frames, and
``learned``, a monocular depth network from a weights path; plug-ins under ``holousd.depth``) give a capture
without depth a depth channel (:func:`with_depth_prior`).
"""

from __future__ import annotations

from typing import Any

from holousd.priors._api import (
    ENTRY_POINT_GROUP,
    Candidate,
    CompletionProposer,
    FrameEvidence,
    ObjectEvidence,
    available_proposers,
    make_proposer,
)
from holousd.priors._depth import (
    DEPTH_ENTRY_POINT_GROUP,
    DepthPrior,
    available_depth_priors,
    make_depth_prior,
    with_depth_prior,
)
from holousd.priors._energy import Limit, ObservationEnergy, observation_energy, scored_among, seen_through_limit
from holousd.priors._evidence import object_evidence, object_neighbours

__all__ = [
    "DEPTH_ENTRY_POINT_GROUP",
    "DepthPrior",
    "ENTRY_POINT_GROUP",
    "BUILTIN",
    "Candidate",
    "CompletionProposer",
    "FrameEvidence",
    "ObjectEvidence",
    "Limit",
    "ObservationEnergy",
    "available_depth_priors",
    "available_proposers",
    "make_depth_prior",
    "make_proposer",
    "object_evidence",
    "object_neighbours",
    "observation_energy",
    "propose",
    "scored_among",
    "seen_through_limit",
    "with_depth_prior",
]

BUILTIN = ("stage1", "extrude", "symmetry", "primitive", "visual_hull")
"""The proposers that need no weights, in the order :func:`propose` runs them by default."""


def propose(evidence: ObjectEvidence, proposers: list[str | CompletionProposer] | None = None, *, k: int = 2,
            seed: int = 0, options: dict[str, dict[str, Any]] | None = None, max_seen_through: float = 0.05,
            max_obs_gain: float | None = None) -> list[tuple[Candidate, ObservationEnergy]]:  # fmt: skip
    """Candidates of every proposer (``k`` each, seeded), each with its E_obs, in proposer order.

    Args:
        evidence: The object's evidence.
        proposers: Names (or proposer objects); default :data:`BUILTIN`.
        k: Candidates per proposer at most.
        seed: Seed of every proposer (the same seed gives the same candidates).
        options: Keyword arguments per proposer name (``{"learned": {"weights": "model.pt"}}``).
        max_seen_through: Rejection limit of E_obs; once the first ``stage1`` candidate (the fitted shape,
            never rejected) is scored, relative to its own share (:func:`seen_through_limit`).
        max_obs_gain: Reject a candidate whose E_obs exceeds the fitted shape's by more than this (None: no
            such limit; :func:`scored_among`).
    """
    out = []
    limit, fitted = max_seen_through, False
    for entry in proposers or list(BUILTIN):
        proposer = make_proposer(entry, **(options or {}).get(entry, {})) if isinstance(entry, str) else entry
        for candidate in proposer.propose(evidence, k, seed):
            energy, limit = scored_among(candidate, evidence, limit, baseline=not fitted,
                                         max_seen_through=max_seen_through, max_obs_gain=max_obs_gain)  # fmt: skip
            fitted = fitted or candidate.proposer == "stage1"
            out.append((candidate, energy))
    return out
