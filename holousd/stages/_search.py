"""s2 search: completion candidates for every object and the physics tree search along the support tree
(layer ``15_search.usda``, between the fit and the physics set-up).

For each object the completion proposers (:mod:`holousd.priors`: the stage-1 shape, support extrusion,
reflective symmetry, primitive fits, the visual hull, plug-ins and a learned prior from a weights path) give
candidate shapes of the whole object, the unseen sides included. Each candidate is scored by

- ``E_obs``: re-rendered into the frames that see the object, (1 - mask IoU) + depth residual / 5 cm +
  seen-through fraction; a candidate that puts matter where a camera saw through to what lies behind is
  rejected (:func:`holousd.priors.observation_energy`), on more than ``max_seen_through`` of its silhouette
  beyond what the stage-1 shape puts there, and so is one whose E_obs exceeds the stage-1 shape's by more than
  ``max_obs_gain``;
- ``E_stable``: the candidate on the shapes already chosen for its support chain, checked quasi-statically
  (:func:`holousd.physics.static_stability`: centre of mass over the support polygon, slope within friction):
  0 when it stands, else 1 + the distance outside in cm. A simulated check per candidate (Newton, 2 s of
  gravity) costs about a second on a CPU against a millisecond here; the scene's verdict stays the simulated
  protocol, and the closing report gives the agreement between the two;
- ``E_touch``: the gap (or sinking) between its base and its support's surface, cm;
- ``E_pene``: its intersection volume with its support and with the neighbours already placed, cm^3
  (manifold3d).

``total = w_obs E_obs + w_stable E_stable + w_touch E_touch + w_pene E_pene`` (:class:`SearchConfig`: weights
with their units and rationale); the lowest total that E_obs does not reject wins (the stage-1 shape when all
are rejected: the fit is what the observations support).

Modes (``mode``; the ablation rows of ``holousd bench --search``):

- ``tree``: breadth-first from the room along the support tree (:func:`holousd.graph.infer_relations` on the
  fitted meshes); each object is scored on its parent's chosen shape and among the neighbours already placed.
  When the lowest total of a child does not stand on its parent's chosen shape, its candidates are checked on the
  parent's top as the physics set-up will leave it (cut flat under the child, ``support_flatten``, and carried
  over where the fit left it open): with its centre of mass more than ``settle_beyond`` outside its contacts, the
  lowest total of those that stand there wins; when none does, the parent's other candidates are tried in order
  of their own total, and the first under which a child candidate stands and every child already placed on the
  parent still stands replaces the parent's choice, unless it explains the parent's pixels worse by more than the
  child's pixels allow (``revisit_obs_budget``); when none does and the child's footprint lies over its parent
  on less than ``to_room_share`` of it, the support edge is revisited: its candidates proposed again on the room,
  the lowest total of those that stand there moves it onto the room (recorded as its support).
- ``ground``: each object checked against the room only (the PhyRecon-like row): objects on the room are scored
  with every term against the floor; objects resting on other objects get E_obs alone (the room is all this
  mode knows of physics).
- ``none``: the stage-1 shapes are kept (the ObjectSDF++-like row); the layer records the mode and nothing else.

Work is spread over processes (``workers``, one per core by default) or Ray tasks (``ray``): proposing an object's
candidates, re-rendering them (E_obs) and standing them on the parent's chosen shape (E_stable, E_touch) need
that one choice and nothing else, so the objects of one depth of the support tree (a run of the breadth-first
order none of which rests on another of the run) go to the workers together, each worker keeping its proposers
(a learned prior's weights) loaded between tasks. E_pene against the neighbours placed so far, the choice and the
revisit follow here in breadth-first order; an object whose parent a revisit changed after its evidence was
gathered is proposed again on the parent's new shape. Any number of workers, or Ray, gives the same scene (a
plug-in proposer that reads ``evidence.neighbours`` sees the shapes chosen before the object's depth of the tree,
not those of its siblings chosen just before it).

The chosen candidate's mesh and SDF replace the fitted ones in the layer (the physics set-up then sets every
object on its support and derives its collider from that mesh). Every object records, in ``HoloEnergyAPI``, the
candidates tried (proposer and seed), each one's total and the chosen candidate's energies; the stage's wall time
is in the layer's stage record (a per-object time in the prims would make the same seed give different layers),
and ``progress`` prints each object's.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from holousd._errors import HolousdError
from holousd.usd._scene import BACKGROUND, SceneGraph
from holousd.usd._types import Energies, MeshData

__all__ = ["MODES", "SEARCH_LAYER", "CandidateScore", "ObjectChoice", "SearchConfig", "SearchResult", "run",
           "search"]  # fmt: skip

SEARCH_LAYER = "15_search.usda"
"""File name of the layer this stage writes."""
MODES = ("none", "ground", "tree")
"""Search modes: stage-1 shapes, each object against the room only, the full tree search."""
SOLVER = "quasi-static"
"""How the search's E_stable is measured (recorded in ``holo:energy:solver``)."""


@dataclass(kw_only=True)
class SearchConfig:
    """Settings of the search stage."""

    mode: str = "tree"
    """``tree`` (the method), ``ground`` (each object against the room only) or ``none`` (stage-1 shapes)."""
    proposers: tuple[str, ...] = ("stage1", "extrude", "symmetry", "primitive", "visual_hull")
    """Completion proposers, by name (built-in or a ``holousd.completion`` plug-in)."""
    proposer_options: dict[str, dict] = field(default_factory=dict)
    """Keyword arguments per proposer (``{"learned": {"weights": "/path/model.pt2"}}``)."""
    k: int = 2
    """Candidates per proposer at most."""
    seed: int = 0
    """Seed of every proposer and of the energies' surface samples."""
    max_frames: int = 24
    """Frames per object that E_obs re-renders into (evenly spaced over those that see it)."""
    w_obs: float = 1.0
    """Weight of E_obs (dimensionless): the unit of the total; one point of IoU lost costs 0.01."""
    w_stable: float = 2.0
    """Weight of E_stable (1 + cm outside the support polygon): a candidate that falls costs more than any
    observation term a plausible candidate has (E_obs of a fitted shape is about 0.2-0.6)."""
    w_touch: float = 0.1
    """Weight per cm of gap or sinking between base and support: the physics set-up closes up to a few cm by
    moving or cutting, so a gap only breaks ties."""
    w_pene: float = 0.02
    """Weight per cm^3 of intersection with the support (above ``parent_band``) and placed neighbours: 50 cm^3
    (a mug 1 cm into the box beside it) weighs as much as the whole observation term."""
    parent_band: float = 0.015
    """Height above a candidate's lowest point below which its intersection with its parent does not count in
    E_pene, metres: a base sunk into the top it rests on is E_touch (per cm), and the physics set-up cuts that
    top flat up to this deep under it (its ``top_depth``). Counted, hard/stack's book, a few mm into the table
    over its whole footprint, cost every candidate 0.5-1.1 on top of E_obs 0.2-0.3, and the search took the
    visual hull (E_obs 0.43), the one that sank least."""
    max_seen_through: float = 0.05
    """E_obs rejects a candidate whose silhouette is seen through on more than this share of its pixels beyond
    the stage-1 shape's own share, counted up to this share again (the fitted shape, first among the candidates,
    sets the baseline and is never rejected: at 2.4 cm cells a fitted table's legs and top edges are about a cell
    wider than the truth, and the fitted demo table itself had 6% of its silhouette seen through), and never on
    less than the stage-1 shape's own share (a phone capture's table, fitted 12% seen through)."""
    max_obs_gain: float | None = 0.25
    """E_obs rejects a candidate whose E_obs exceeds the stage-1 shape's by more than this (dimensionless: a
    quarter of its mask IoU, or 1.25 cm more depth residual on its own pixels): a completion must explain what
    was seen about as well as the fit does, however well it stands. Where the fitted shape does not stand
    (a table whose legs the refinement lost on a phone's noisy depth) the search had taken the visual hull,
    14 cm above the table top and 17 cm wider on every side (E_obs 1.23 against 0.92; the table's F1 87 -> 53),
    and on the phone's hard/thin four visual hulls, one with a mask IoU of 0.09 (the fit's: 0.77). On clean
    captures no chosen candidate comes within half of it (hard/fast: at most +0.15). None: no limit."""
    revisit: bool = True
    """``tree``: try the parent's other candidates when none of a child's stands (on the parent's chosen shape, nor
    on its top as the set-up will leave it: every candidate E_obs keeps is checked so when the lowest total does not
    stand, also for ``settle_beyond``)."""
    revisit_obs_budget: float | None = 0.25
    """``tree``: a revisit may make the parent explain what was seen of it worse only as much as the child may
    itself: the rise of the parent's E_obs, counted over the pixels the cameras saw of it (in E_obs' frames), at
    most this times the child's pixels (the E_obs each object may lose, ``max_obs_gain``, spent by the child on its
    parent). E_obs is each object's mean over its pixels where the method's sums over them, so that a child seen
    in a few pixels does not remake a parent seen in thousands: on bench_01's phone capture a book seen in 50
    pixels of three frames, fitted 44 cm wide, stood on no shape of the cabinet's but its visual hull (E_obs
    0.56 -> 0.78 over 14 000 pixels, 22 cm into the corner no camera saw), and the book still fell once set up.
    None: no limit."""
    to_room_share: float = 0.25
    """``tree``: a child with no candidate that stands on its parent (nor once set up, nor after the parent's
    revisit) whose fitted footprint lies over its parent on less than this share of it (rays straight down from
    its top, meeting the parent anywhere) is proposed again on the room, and moved there when one of those
    candidates stands (the support edge revisited, as the method's search does): hard/top_only's bin, seen
    only from above, hung 40 cm over the floor by the 1.3 cm of its 45 cm width over a bulge the fit gave its
    neighbour's hidden side (4% of its footprint), and fell whatever shape it took there. A child over its
    parent stays on it: a cup on a table is not carried down through the table, and on the phone captures of
    bench_00 and bench_02 a ball in a shelf's bottom compartment (fitted through its board) and a box over a
    hole the fit left in a shelf's board lie over their shelves on 49% and 45%."""
    settle_beyond: float = 1.0
    """``tree``: the lowest total of a child whose centre of mass lies more than this outside its contacts on
    the parent's chosen shape, cm (E_stable above 1 + this), gives way to the lowest total of those that stand on
    the parent's top as the set-up will leave it (``support_flatten``; carried over a hole the fit left). Nearer
    than that it stays: the set-up's own cuts move a contact's edge by millimetres to a centimetre, and hard/shelf's
    bottle (default preset; 0 cm outside, its two best candidates 0.02 apart) stood as chosen and fell as the one
    the quasi-static check said would stand once set up. bench_02's box over a hole in its shelf's board (fast):
    2.8 cm outside; the candidate with its bottom carried down whole stands there, in both simulators."""
    friction: float = 0.5
    """Friction coefficient of the quasi-static check (the stability protocol's)."""
    support_sink: float = 0.005
    """With ``support_flatten``: where every ray under a child falls more than ``max_gap`` through its
    parent's top (a hole the fit left, rays falling to the board below), the flat top the set-up carries over
    the hole lies this far below the child's bottom, metres (half the set-up's ``max_shift``)."""
    support_flatten: float = 0.015
    """A revisit replaces a parent's shape only when no candidate of the child stands on the parent as the
    physics set-up will leave its top (the same check chooses among a child's candidates, ``settle_beyond``):
    flat under the child where it lies within this of its highest point there, metres (the set-up's ``top_depth``;
    :func:`holousd.physics.static_stability`'s ``flatten``); the set-up makes a child stand that the fitted bumps
    tip. Without it, the demo's bowl (its centre of mass 1 mm outside its contacts on an 18 deg facet of the shelf's
    board) had the shelf swapped for its visual hull, 21 cm wider into the corner nobody saw (the shelf's F1 94 ->
    73). E_stable itself stays measured on the fitted shape:
    scored on the flattened top, hard/fast lost four objects to 5-10 deg tilts (98 -> 90% stable)."""
    provenance: str = "s2_search"
    """Writer name recorded on the nodes the stage changes."""
    progress: bool = False
    """Print one line per object on stderr (does not change the result)."""
    workers: int | None = None
    """Processes that propose and re-render candidates, the objects of one depth of the support tree at a time
    (None: one per core this process may use; 1: all in this process). Any number gives the same scene."""
    ray: str | None = None
    """Run those as Ray tasks instead: ``"local"``, ``"auto"`` or ``"HOST:PORT"`` (None: local processes)."""


@dataclass(kw_only=True)
class CandidateScore:
    """One candidate and its energies."""

    proposer: str
    seed: int
    note: str
    observation: float
    """E_obs."""
    rejected: bool
    """E_obs rejected it (matter where a camera saw through, or E_obs more than ``max_obs_gain`` above the
    fitted shape's)."""
    stable: float
    """E_stable (0: stands)."""
    touch_cm: float
    """|gap| between its base and the support, cm."""
    pene_cm3: float
    """Intersection volume with the support and placed neighbours, cm^3."""
    total: float
    """Weighted total (inf when rejected)."""

    @property
    def label(self) -> str:
        return f"{self.proposer}#{self.seed}"


@dataclass(kw_only=True)
class ObjectChoice:
    """What the search chose for one object."""

    name: str
    parent: str
    scores: list[CandidateScore]
    chosen: int
    """Index into ``scores``."""
    wall_s: float
    revisited: bool = False
    """The choice was made by a revisit: a parent's, changed when one of its children had no candidate that
    stands; that child's, the lowest total among its candidates that stand on the parent's new choice."""
    moved_to_room: str | None = None
    """The parent the support tree first gave, when the child was moved onto the room (``to_room_share``)."""
    stands_once_set_up: bool = False
    """The chosen candidate does not stand on the parent's chosen shape but does on its top as the physics set-up
    leaves it (see ``SearchConfig.settle_beyond``)."""
    pixels: int = 0
    """Pixels of the object in the frames E_obs re-renders into (its evidence; 0: not counted)."""
    revisit_refused: str = ""
    """The parent's candidate under which the child would stand and the revisit that ``revisit_obs_budget`` refused
    (empty: none)."""

    @property
    def best(self) -> CandidateScore:
        return self.scores[self.chosen]

    def runner_up(self) -> CandidateScore | None:
        """The lowest-total candidate other than the chosen one (None when there is none)."""
        others = [s for i, s in enumerate(self.scores) if i != self.chosen]
        return min(others, key=lambda s: s.total) if others else None


@dataclass(kw_only=True)
class SearchResult:
    """What :func:`search` did."""

    scene: SceneGraph
    mode: str
    choices: list[ObjectChoice]
    wall_s: float


def _world(pose, mesh: MeshData) -> MeshData:  # noqa: ANN001
    return MeshData(points=pose.apply(mesh.points), faces=mesh.faces)


class _Scorer:
    def __init__(self, config: SearchConfig, floor: float | None) -> None:
        self.config = config
        self.floor = floor

    def physics(self, world: MeshData, parent: str, parent_mesh: MeshData | None,
                neighbours: dict[str, MeshData]) -> tuple[float, float, float]:  # fmt: skip
        """(E_stable, touch cm, pene cm^3) of a world mesh on its parent."""
        stable, touch = self.standing(world, parent, parent_mesh)
        return stable, touch, self.penetration(world, parent, neighbours)

    def _body(self, world: MeshData, parent: str) -> tuple:
        from holousd.geometry._contact import cut_by_plane

        body = (world.points, world.faces)
        if parent == BACKGROUND and self.floor is not None and float(world.points[:, 2].min()) < self.floor:
            # what reaches under the floor, the physics set-up cuts away (its base cut): the check stands the
            # shape as it will be, not on the deepest of the legs the fit sank unevenly into the floor
            body = cut_by_plane(body, (0.0, 0.0, 1.0), self.floor)[0]
        return body

    def standing(self, world: MeshData, parent: str, parent_mesh: MeshData | None) -> tuple[float, float]:
        """(E_stable, touch cm) of a world mesh on its parent (the parent's shape alone: a worker's part)."""
        from holousd.physics._static import static_stability

        if parent == BACKGROUND and self.floor is not None:
            support = self.floor
        else:
            support = None if parent_mesh is None else (parent_mesh.points, parent_mesh.faces)
        verdict = static_stability(self._body(world, parent), support, friction=self.config.friction,
                                   seed=self.config.seed)  # fmt: skip
        return verdict.energy, 100.0 * abs(verdict.gap_m) if math.isfinite(verdict.gap_m) else 5.0

    def stands_once_set_up(self, world: MeshData, parent: str, parent_mesh: MeshData | None) -> bool:
        """Whether a world mesh stands on its parent's top as the physics set-up will leave it (flat under it)."""
        from holousd.physics._static import static_stability

        if parent == BACKGROUND or parent_mesh is None:
            return False  # the floor is flat already: nothing the set-up does changes the verdict
        return static_stability(self._body(world, parent), (parent_mesh.points, parent_mesh.faces),
                                friction=self.config.friction, seed=self.config.seed,
                                flatten=self.config.support_flatten, sink=self.config.support_sink).stands  # fmt: skip

    def penetration(self, world: MeshData, parent: str, neighbours: dict[str, MeshData]) -> float:
        """Intersection volume, cm^3, of a world mesh with its parent above its base band and the neighbours."""
        from holousd.geometry._contact import overlap

        body = self._body(world, parent)
        pene = 0.0
        base = float(world.points[:, 2].min()) + self.config.parent_band
        for other, mesh in neighbours.items():
            if other != BACKGROUND:  # the parent's top where the child sinks in is E_touch's and the set-up's
                above = base if other == parent else None
                pene += 1e6 * overlap(body, (mesh.points, mesh.faces), above=above).volume_m3
        return pene

    def total(self, e_obs: float, rejected: bool, stable: float, touch: float, pene: float) -> float:
        c = self.config
        if rejected:
            return math.inf
        return c.w_obs * e_obs + c.w_stable * stable + c.w_touch * touch + c.w_pene * pene


def _floor(scene: SceneGraph) -> float | None:
    """Height of the room's floor (the lowest large horizontal plane of the background mesh), or None."""
    from holousd._errors import SceneError
    from holousd.stages._physics_setup import _room_planes

    try:
        mesh = scene.get_mesh(BACKGROUND)
    except SceneError:
        return None
    if len(mesh.faces) == 0:
        return None
    return _room_planes(_world(scene.get_pose(BACKGROUND), mesh))[0]


def search(scene: SceneGraph, obs, config: SearchConfig | None = None,  # noqa: ANN001
           out_dir: str | Path | None = None, log: Callable[[str], None] | None = None) -> SearchResult:  # fmt: skip
    """Run the search on a fitted scene and write ``15_search.usda`` (see the module docstring)."""
    from holousd._tasks import TaskPool
    from holousd.graph import infer_relations
    from holousd.priors import object_evidence, object_neighbours

    config = config or SearchConfig()
    if config.mode not in MODES:
        raise HolousdError(f"search mode {config.mode!r}: choose one of {', '.join(MODES)}")
    for p in config.proposers:  # an unknown or broken proposer is refused before anything is written
        _proposer(p, config.proposer_options.get(p, {}))
    out_dir = Path(out_dir) if out_dir is not None else Path(scene.root_layer.realPath).parent
    start = time.perf_counter()
    names = [n for n in scene.objects() if _has_mesh(scene, n)]
    poses = {n: scene.get_pose(n) for n in names}
    fitted = {n: _world(poses[n], scene.get_mesh(n)) for n in names}
    floor = _floor(scene)
    relations = infer_relations({n: (m.points, m.faces) for n, m in fitted.items()}, floor=floor)
    scene.push_layer(out_dir / SEARCH_LAYER, provenance=config.provenance, replace=True)
    choices: list[ObjectChoice] = []
    if config.mode == "none":
        scene.save()
        return SearchResult(scene=scene, mode=config.mode, choices=choices, wall_s=time.perf_counter() - start)
    scorer = _Scorer(config, floor)
    known = dict(fitted)  # world meshes as fitted, the room's with them: read from the scene once, not per object
    if _has_mesh(scene, BACKGROUND):
        known[BACKGROUND] = _world(scene.get_pose(BACKGROUND), scene.get_mesh(BACKGROUND))
    placed: dict[str, MeshData] = {}  # world meshes of the chosen shapes
    candidates: dict[str, list] = {}  # name -> [(Candidate, world mesh)]
    by_name: dict[str, ObjectChoice] = {}
    ground = config.mode == "ground"
    specs = [(p, config.proposer_options.get(p, {})) for p in config.proposers]
    order = relations.breadth_first()

    def evidence(name: str, parent: str):  # noqa: ANN202 - ObjectEvidence
        return object_evidence(scene, obs, name, max_frames=config.max_frames, support=parent,
                               placed=None if ground else placed, floor=scorer.floor)  # fmt: skip

    with TaskPool(workers=_workers(config), ray=config.ray, memory_mb=2000.0) as pool:
        for wave in _waves(order, relations):
            # the costly part, proposing and re-rendering, needs only the parent's choice: spread over the workers
            gathered = {n: evidence(n, relations.support.get(n, BACKGROUND)) for n in wave}
            basis = {n: placed.get(relations.support.get(n, BACKGROUND)) for n in wave}
            outcomes = pool.run(_proposed, [(n, (specs, gathered[n], config.k, config.seed, config.max_seen_through,
                                                 scorer, ground, config.max_obs_gain)) for n in wave])  # fmt: skip
            for name, outcome in zip(wave, outcomes, strict=True):
                if not outcome.ok:
                    raise HolousdError(f"search, {name}: {outcome.error}")
                t0 = time.perf_counter()
                parent = relations.support.get(name, BACKGROUND)
                proposed, worker_s = outcome.value, outcome.wall_s
                if placed.get(parent) is not basis[name]:
                    # a sibling's revisit changed the parent's shape after this object's evidence was gathered:
                    # gather and propose again on the shape it rests on now (as one object at a time would)
                    proposed = _proposed(specs, evidence(name, parent), config.k, config.seed,
                                         config.max_seen_through, scorer, ground, config.max_obs_gain)  # fmt: skip
                near = {}
                if not ground:  # E_pene: the parent and the neighbours placed so far, this wave's included
                    around = object_neighbours(scene, name, support=parent, placed={**known, **placed})
                    near = {k: v for k, v in around.items() if k in placed or k == parent}
                found, scores = _scored(proposed, poses[name], parent, near, scorer, ground)
                if not scores:
                    continue
                tree = config.mode == "tree" and parent in by_name  # on an object whose shape is chosen
                chosen, settled = _choose(found, scores, parent, placed.get(parent) if tree else None, scorer,
                                          config.settle_beyond)  # fmt: skip
                choice = ObjectChoice(name=name, parent=parent, scores=scores, chosen=chosen, wall_s=0.0,
                                      pixels=_pixels(gathered[name]))  # fmt: skip
                if tree and config.revisit and settled == []:
                    _revisit(name, choice, found, by_name[parent], candidates[parent], relations, placed, scorer)
                    if not choice.revisited and _over_parent(fitted[name], placed[parent]) < config.to_room_share:
                        moved = _on_the_room(name, parent, evidence(name, BACKGROUND), specs, config, scorer,
                                             near, poses[name])  # near: the parent's chosen shape among them
                        if moved is not None:
                            moved[0].pixels, moved[0].revisit_refused = choice.pixels, choice.revisit_refused
                            choice, found = moved
                            relations.support[name] = BACKGROUND  # a later revisit of its parent: no sibling
                choice.stands_once_set_up = choice.best.stable > 0 and choice.chosen in (settled or ())
                placed[name] = found[choice.chosen][1]
                candidates[name] = found
                choice.wall_s = worker_s + time.perf_counter() - t0
                by_name[name] = choice
                choices.append(choice)
                if config.progress and log is not None:
                    b = choice.best
                    verdict = ("stands" if b.stable == 0 else "stands once set up" if choice.stands_once_set_up
                               else "does not stand")  # fmt: skip
                    if choice.moved_to_room is not None:
                        verdict += f", moved from {choice.moved_to_room} to the room"
                    if choice.revisit_refused:
                        verdict += f"; {choice.revisit_refused}"
                    log(f"search [{len(choices)}/{len(names)}] {name}: {b.label} (total {b.total:.2f}, {verdict}) "
                        f"of {len(scores)} in {choice.wall_s:.1f} s")
    for choice in choices:
        cand = candidates[choice.name][choice.chosen][0]
        if cand.proposer != "stage1":
            scene.set_mesh(choice.name, cand.mesh)
            if cand.sdf is not None:
                scene.set_sdf(choice.name, cand.sdf)
        b = choice.best
        scene.set_energies(choice.name, Energies(
            stable=b.stable, touch=b.touch_cm / 100.0, penetration=b.pene_cm3 * 1e-6, candidate=choice.chosen,
            observation=b.observation, total=b.total if math.isfinite(b.total) else -1.0,
            candidates=[s.label for s in choice.scores], totals=[s.total for s in choice.scores],
            solver=SOLVER, stands_once_set_up=choice.stands_once_set_up))  # fmt: skip
        scene.set_support(choice.name, choice.parent)
    scene.save()
    return SearchResult(scene=scene, mode=config.mode, choices=choices, wall_s=time.perf_counter() - start)


_WARM: dict[tuple[str, str], object] = {}
"""Proposers made in this process, by name and options: a worker keeps a learned prior's weights loaded."""


def _proposer(name: str, options: dict):  # noqa: ANN202 - CompletionProposer
    from holousd.priors import make_proposer

    key = (name, repr(sorted(options.items())))
    if key not in _WARM:
        _WARM[key] = make_proposer(name, **options)
    return _WARM[key]


def _proposed(specs: list[tuple[str, dict]], evidence, k: int, seed: int, max_seen_through: float,  # noqa: ANN001
              scorer: _Scorer, ground: bool, max_obs_gain: float | None = None,
              ) -> list[tuple[object, float, bool, tuple[float, float]]]:  # fmt: skip
    """Every proposer's candidates for one object with their E_obs and, on the parent's chosen shape, E_stable and
    touch: ``[(Candidate, E_obs, rejected, (E_stable, touch cm))]``, the fitted shape first (it sets the
    seen-through and the E_obs baselines: ``stage1`` must be the first proposer). A worker's task: it needs the
    object's evidence alone. ``ground``: an object on another gets E_obs alone (0, 0)."""
    from holousd.priors import scored_among

    parent = evidence.support or BACKGROUND
    physics = not (ground and parent != BACKGROUND)
    out: list[tuple[object, float, bool, tuple[float, float]]] = []
    limit = max_seen_through
    for name, options in specs:
        for cand in _proposer(name, options).propose(evidence, k, seed):
            e, limit = scored_among(cand, evidence, limit, baseline=not out, max_seen_through=max_seen_through,
                                    max_obs_gain=max_obs_gain)  # fmt: skip
            standing = (0.0, 0.0) if not physics else scorer.standing(
                _world(evidence.pose, cand.mesh), parent, evidence.neighbours.get(parent))  # fmt: skip
            out.append((cand, e.energy, e.rejected, standing))
    return out


def _waves(order: list[str], relations) -> list[list[str]]:  # noqa: ANN001
    """``order`` (breadth-first) cut into runs in which no object rests on another of the same run: each run's
    proposals need only choices made before it."""
    waves: list[list[str]] = []
    for name in order:
        if not waves or relations.support.get(name, BACKGROUND) in waves[-1]:
            waves.append([])
        waves[-1].append(name)
    return waves


def _workers(config: SearchConfig) -> int:
    from holousd._tasks import available_cores

    return max(1, config.workers) if config.workers is not None else available_cores()


def _has_mesh(scene: SceneGraph, name: str) -> bool:
    from holousd._errors import SceneError

    try:
        return len(scene.get_mesh(name).faces) > 0
    except SceneError:
        return False


def _pick(scores: list[CandidateScore]) -> int:
    """The lowest total not rejected; the stage-1 shape (or the first) when every candidate is rejected."""
    live = [i for i, s in enumerate(scores) if math.isfinite(s.total)]
    if live:
        return min(live, key=lambda i: (scores[i].total, i))
    stage1 = [i for i, s in enumerate(scores) if s.proposer == "stage1"]
    return stage1[0] if stage1 else 0


def _choose(found: list, scores: list[CandidateScore], parent: str, parent_mesh: MeshData | None,
            scorer: _Scorer, beyond: float) -> tuple[int, list[int] | None]:  # fmt: skip
    """The candidate a child gets on its parent's chosen shape (``parent_mesh``; None: on the room, or not the tree
    search): the lowest total (:func:`_pick`); when that does not stand there, those that stand on the parent's
    top as the set-up leaves it (:func:`_settled`) are found, also returned (None when not asked: an empty list
    means the parent is to be revisited), and when its centre of mass lies more than ``beyond`` cm outside its
    contacts (``SearchConfig.settle_beyond``), the lowest total of them is chosen."""
    chosen = _pick(scores)
    if parent_mesh is None or scores[chosen].stable <= 0:
        return chosen, None
    settled = _settled(found, scores, parent, parent_mesh, scorer)
    if settled and scores[chosen].stable > 1.0 + beyond:
        chosen = min(settled, key=lambda i: (scores[i].total, i))
    return chosen, settled


def _settled(found: list, scores: list[CandidateScore], parent: str, parent_mesh: MeshData | None,
             scorer: _Scorer) -> list[int]:  # fmt: skip
    """Indices of a child's candidates that E_obs keeps and that stand on the parent's chosen shape's top as the
    physics set-up leaves it (cut flat under the child, carried over where the fit left it open): asked when the
    lowest total does not stand on the shape as chosen. bench_02 (fast): a box over a hole the fit left in a
    shelf's middle board; none of its candidates stood over the hole, the lowest total carried only its front
    down onto the board's edge, and once the set-up had carried the board over the hole the box stood on that
    strip with its centre of mass behind it and tipped over; its bottom carried down whole stands there."""
    return [i for i, ((_, world), sc) in enumerate(zip(found, scores, strict=True))
            if math.isfinite(sc.total) and scorer.stands_once_set_up(world, parent, parent_mesh)]  # fmt: skip


def _scored(proposed: list, pose, parent: str, near: dict[str, MeshData], scorer: _Scorer,  # noqa: ANN001
            ground: bool) -> tuple[list, list[CandidateScore]]:  # fmt: skip
    """The proposed candidates (:func:`_proposed`) in the world (``pose``) with their scores on ``parent``: E_pene
    against ``near``; ``ground`` and an object on another: E_obs alone. ``([(Candidate, world mesh)], scores)``."""
    found, scores = [], []
    for cand, e_obs, rejected, standing in proposed:
        world = _world(pose, cand.mesh)
        if ground and parent != BACKGROUND:
            stable, touch, pene = 0.0, 0.0, 0.0
        else:
            (stable, touch), pene = standing, scorer.penetration(world, parent, near)
        scores.append(CandidateScore(proposer=cand.proposer, seed=cand.seed, note=cand.note, observation=e_obs,
                                     rejected=rejected, stable=stable, touch_cm=touch, pene_cm3=pene,
                                     total=scorer.total(e_obs, rejected, stable, touch, pene)))  # fmt: skip
        found.append((cand, world))
    return found, scores


def _over_parent(child: MeshData, parent: MeshData, rays: int = 256) -> float:
    """Share of ``child``'s footprint over ``parent`` (world meshes): rays cast straight down from its top at the
    xy of its surface samples (seeded), meeting ``parent`` anywhere below its top. A fit that ran the child's
    underside down through its parent's board (a ball in a shelf's bottom compartment, fitted 8 cm through it)
    is still over the parent."""
    import trimesh

    from holousd._sampling import evenly_spaced
    from holousd.geometry._contact import queryable

    if len(child.faces) == 0 or len(parent.faces) == 0:
        return 0.0
    body = trimesh.Trimesh(np.asarray(child.points, float), np.asarray(child.faces), process=False)
    points, _ = trimesh.sample.sample_surface(body, 8 * rays, seed=0)
    points = np.asarray(points, float)[evenly_spaced(len(points), rays)]
    origins = np.column_stack([points[:, :2], np.full(len(points), body.bounds[1, 2] + 1e-4)])
    target = queryable((parent.points, parent.faces))
    return float(target.ray.intersects_any(origins, np.tile([0.0, 0.0, -1.0], (len(origins), 1))).mean())


def _on_the_room(name: str, parent: str, evidence, specs: list[tuple[str, dict]],  # noqa: ANN001
                 config: SearchConfig, scorer: _Scorer, near: dict[str, MeshData],
                 pose) -> tuple[ObjectChoice, list] | None:  # noqa: ANN001  # fmt: skip
    """``name``'s candidates proposed again on the room (carried down to the floor), scored against the floor and
    the neighbours placed so far (``near``, its former parent among them): the choice of the lowest total among
    those that stand, or None when none does (the child stays on ``parent``, see ``to_room_share``)."""
    proposed = _proposed(specs, evidence, config.k, config.seed, config.max_seen_through, scorer, False,
                         config.max_obs_gain)  # fmt: skip
    found, scores = _scored(proposed, pose, BACKGROUND, near, scorer, ground=False)
    standing = [i for i, sc in enumerate(scores) if sc.stable == 0 and math.isfinite(sc.total)]
    if not standing:
        return None
    chosen = min(standing, key=lambda i: (scores[i].total, i))
    choice = ObjectChoice(name=name, parent=BACKGROUND, scores=scores, chosen=chosen, wall_s=0.0, revisited=True,
                          moved_to_room=parent)  # fmt: skip
    return choice, found


def _pixels(evidence) -> int:  # noqa: ANN001 - ObjectEvidence
    """Pixels of the object in its evidence's frames (those E_obs re-renders into)."""
    return int(sum(np.count_nonzero(f.labels == evidence.instance_id) for f in evidence.frames))


def _revisit(name: str, choice: ObjectChoice, found: list, parent_choice: ObjectChoice, parent_found: list,
             relations, placed: dict[str, MeshData], scorer: _Scorer) -> None:  # noqa: ANN001  # fmt: skip
    """No candidate of ``name`` stands on its parent's chosen shape: try the parent's other candidates (lowest
    total first); take the first under which one of the child's stands and every sibling placed on the parent
    still stands, and whose rise in E_obs over the parent's pixels the child's pixels pay for
    (``SearchConfig.revisit_obs_budget``; the first such one it refuses is named in ``choice.revisit_refused``)."""
    parent = parent_choice.name
    siblings = [s for s in relations.children(parent) if s in placed and s != name]
    order = sorted((i for i, s in enumerate(parent_choice.scores) if i != parent_choice.chosen
                    and math.isfinite(s.total)), key=lambda i: parent_choice.scores[i].total)  # fmt: skip
    budget = scorer.config.revisit_obs_budget
    for i in order:
        alt = parent_found[i][1]
        rise = parent_choice.scores[i].observation - parent_choice.best.observation
        over = budget is not None and min(choice.pixels, parent_choice.pixels) > 0 and (
            rise * parent_choice.pixels > budget * choice.pixels)
        if over and choice.revisit_refused:
            continue  # (refused already: only the first, the lowest total, is named)
        rescored = []
        for (_, world), s in zip(found, choice.scores, strict=True):
            stable, touch, pene = scorer.physics(world, parent, alt, {parent: alt})
            rescored.append((scorer.total(s.observation, s.rejected, stable, touch, pene), stable, touch, pene))
        standing = [j for j, r in enumerate(rescored) if r[1] == 0 and math.isfinite(r[0])]
        if not standing:
            continue
        if any(scorer.physics(placed[s], parent, alt, {parent: alt})[0] > 0 for s in siblings):
            continue
        if over:
            choice.revisit_refused = (f"{parent}'s {parent_choice.scores[i].label} would stand it, refused: its E_obs "
                                      f"+{rise:.2f} over {parent_choice.pixels} px against the child's "
                                      f"{choice.pixels} px (revisit_obs_budget)")  # fmt: skip
            continue
        parent_choice.chosen = i
        parent_choice.revisited = True
        placed[parent] = alt
        for j, r in enumerate(rescored):
            sc = choice.scores[j]
            sc.total, sc.stable, sc.touch_cm, sc.pene_cm3 = r
        choice.chosen = min(standing, key=lambda j: (rescored[j][0], j))
        choice.revisited = True
        return


def run(scene: SceneGraph, obs, config: SearchConfig | None = None,  # noqa: ANN001
        log: Callable[[str], None] | None = None) -> SceneGraph:  # fmt: skip
    """The pipeline's search stage: :func:`search`, returning the scene."""
    return search(scene, obs, config, log=log).scene
