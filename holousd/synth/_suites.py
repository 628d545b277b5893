"""Scene recipes: the ``demo``, ``bench`` and ``hard`` suites.

``hard`` has one scene per physical failure mode of reconstruction methods, named after it:

- ``stack``: floor -> table -> book -> mug (a support chain four deep).
- ``against_wall``: a cabinet pushed against a wall with a box pushed against the wall on top: backs never seen.
- ``thin``: a plate and books lying flat on a table (thin objects, hard to separate from their support).
- ``small_beside_large``: a small cube touching a large box, and a small ball beside a cabinet.
- ``touching_siblings``: a row of books and boxes touching each other on a table.
- ``shelf``: a multi-level shelf with objects on several boards.
- ``top_only``: a low bin wedged into a corner between two cabinets: only its top is ever visible.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable

import numpy as np

from holousd.synth._catalog import make_template
from holousd.synth._layout import PlacedObject, SceneBuilder, SceneSpec
from holousd.usd import BACKGROUND

__all__ = ["HARD_SCENES", "SUITES", "build_scene", "scene_names"]

_BENCH_SCENES = 6


def _req(obj: PlacedObject | None, what: str) -> PlacedObject:
    """A placement the recipe depends on; fails loudly (a recipe bug) when it did not fit."""
    if obj is None:
        raise RuntimeError(f"scene recipe could not place {what}; adjust the recipe")
    return obj


def _rng(seed: int, name: str) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(name.encode("utf-8"))])


def _decorate(b: SceneBuilder, parent: str, count: int, *, surface: int = 0, allow_stacks: bool = True) -> None:
    """Put ``count`` random small objects on ``parent``'s support ``surface``: singles, stacks and touching pairs."""
    rng = b.rng
    for _ in range(count):
        roll = rng.random()
        if allow_stacks and roll < 0.25:
            base = b.place(make_template(rng.choice(["book", "box"]), rng), parent, surface=surface)
            if base is not None:
                b.place(make_template(rng.choice(["mug", "bowl", "book", "ball"]), rng), base.name)
        elif roll < 0.45:
            first = b.place(make_template(rng.choice(["book", "box"]), rng), parent, surface=surface)
            if first is not None:
                b.place_touching(make_template(rng.choice(["book", "box"]), rng), first.name)
        else:
            b.place(
                make_template(rng.choice(["mug", "bowl", "plate", "bottle", "ball", "book", "box"]), rng),
                parent,
                surface=surface,
            )


def _table_with_chair(b: SceneBuilder, category: str = "table") -> str | None:
    rng = b.rng
    x, y, _ = b.room.size
    table = b.place(
        make_template(category, rng),
        BACKGROUND,
        gap=0.6,
        at=(rng.uniform(-0.15, 0.15) * x, rng.uniform(-0.15, 0.15) * y),
        quarter=int(rng.integers(2)),
    )
    if table is None:
        return None
    if category == "table":
        chair = make_template("chair", rng)
        r = table.footprint
        hx = chair.size[0] / 2
        side = int(rng.integers(2))
        v = r[2] - 0.08 - hx if side == 0 else r[3] + 0.08 + hx
        b.place(
            chair, BACKGROUND, at=((r[0] + r[1]) / 2 + rng.uniform(-0.15, 0.15), v), quarter=0 if side else 2, gap=0.05
        )
    return table.name


def _bench(index: int) -> Callable[[int], SceneSpec]:
    def build(seed: int) -> SceneSpec:
        name = f"bench_{index:02d}"
        b = SceneBuilder(name, _rng(seed, name))
        rng = b.rng
        table = _table_with_chair(b, "table" if rng.random() < 0.75 else "coffee_table")
        walls = list(rng.permutation(["+x", "-x", "+y", "-y"]))
        kinds = list(
            rng.choice(["shelf", "cabinet", "sofa", "cabinet", "shelf"], size=int(rng.integers(2, 4)), replace=False)
        )
        placed = []
        for kind, wall in zip(kinds, walls, strict=False):
            obj = b.against_wall(make_template(kind, rng), wall, wall_gap=float(rng.choice([0.0, 0.03])))
            if obj is not None:
                placed.append(obj)
        if table:
            _decorate(b, table, int(rng.integers(3, 5)))
        for obj in placed:
            if obj.category == "shelf":
                boards = rng.permutation(len(obj.template.surfaces) - 1)[:2]
                for s in boards:
                    _decorate(b, obj.name, int(rng.integers(1, 3)), surface=int(s), allow_stacks=False)
            elif obj.category == "cabinet":
                _decorate(b, obj.name, int(rng.integers(1, 3)))
            elif obj.category == "sofa" and rng.random() < 0.6:
                b.place(make_template(rng.choice(["ball", "book", "box"]), rng), obj.name)
        if rng.random() < 0.5:
            b.place(make_template("box", rng, size=(0.35, 0.3, 0.3)), BACKGROUND, gap=0.3)
        return b.build(f"procedural room {index}: furniture against the walls, a table, small objects and stacks")

    return build


def _demo(seed: int) -> SceneSpec:
    b = SceneBuilder("demo", _rng(seed, "demo"), room_size=(4.6, 4.0, 2.6), strict=True)
    rng = b.rng
    table = b.place(make_template("table", rng), BACKGROUND, at=(0.1, -0.2), quarter=0, gap=0.5)
    assert table is not None
    book = b.place(make_template("book", rng), table.name, at=(-0.2, 0.0), quarter=0)
    assert book is not None
    b.place(make_template("mug", rng), book.name, at=(0.0, 0.0), quarter=1)
    b.place_touching(make_template("box", rng, size=(0.14, 0.12, 0.12)), book.name, side="+u", quarter=0)
    b.place(make_template("plate", rng), table.name, at=(0.3, 0.1))
    shelf = b.against_wall(make_template("shelf", rng, boards=3), "+y", along=0.2, wall_gap=0.0)
    assert shelf is not None
    b.place(make_template("bottle", rng), shelf.name, surface=1)
    b.place(make_template("bowl", rng), shelf.name, surface=0)
    cabinet = b.against_wall(make_template("cabinet", rng), "+x", along=0.6, wall_gap=0.0)
    assert cabinet is not None
    b.place(make_template("ball", rng, size=(0.07,)), cabinet.name)
    return b.build("one room showing everything: stack, touching siblings, thin plate, shelf, object against a wall")


def _stack(seed: int) -> SceneSpec:
    b = SceneBuilder("stack", _rng(seed, "stack"), strict=True)
    rng = b.rng
    table = b.place(make_template("table", rng), BACKGROUND, at=(0.0, 0.0), quarter=0)
    assert table is not None
    book = b.place(make_template("book", rng), table.name, at=(0.05, 0.0), quarter=0)
    assert book is not None
    b.place(make_template("mug", rng), book.name, at=(0.0, 0.0), quarter=int(rng.integers(4)))
    box = b.place(make_template("box", rng, size=(0.22, 0.18, 0.12)), table.name, at=(-0.3, 0.05), quarter=0)
    assert box is not None
    book2 = b.place(make_template("book", rng, size=(0.18, 0.13, 0.03)), box.name, at=(0.0, 0.0), quarter=0)
    assert book2 is not None
    b.place(make_template("bowl", rng, size=(0.04, 0.06, 0.05)), book2.name, at=(0.0, 0.0))
    b.against_wall(make_template("cabinet", rng), "+y")
    b.focus = [table.name]
    return b.build("support chains: floor -> table -> book -> mug and table -> box -> book -> bowl")


def _against_wall(seed: int) -> SceneSpec:
    b = SceneBuilder("against_wall", _rng(seed, "against_wall"), strict=True)
    rng = b.rng
    cabinet = b.against_wall(make_template("cabinet", rng), "+y", along=0.5, wall_gap=0.0)
    assert cabinet is not None
    d = cabinet.template.surfaces[0]
    box = make_template("box", rng, size=(0.3, 0.2, 0.25))
    _req(
        b.place(box, cabinet.name, at=(-0.1 * (d.x1 - d.x0), d.y1 - 0.1), quarter=0), "box"
    )  # back flush with the wall
    book = make_template("book", rng)
    _req(b.place(book, cabinet.name, at=(0.3 * (d.x1 - d.x0), d.y1 - book.size[1] / 2), quarter=0), "book")
    shelf = b.against_wall(make_template("shelf", rng), "-x", along=0.5, wall_gap=0.0)
    assert shelf is not None
    _req(
        b.place(
            make_template("box", rng, size=(0.2, 0.15, 0.18)),
            shelf.name,
            surface=1,
            at=(0.0, shelf.template.surfaces[1].y1 - 0.075),
            quarter=0,
        ),
        "box on the shelf",
    )
    b.place(make_template("table", rng), BACKGROUND, at=(0.3, -0.4), gap=0.5)
    return b.build("objects pushed against walls: their backs are never observed")


def _thin(seed: int) -> SceneSpec:
    b = SceneBuilder("thin", _rng(seed, "thin"), strict=True)
    rng = b.rng
    table = b.place(make_template("table", rng), BACKGROUND, at=(0.0, 0.0), quarter=0)
    assert table is not None
    _req(b.place(make_template("plate", rng, size=(0.12, 0.012)), table.name, at=(-0.3, 0.1)), "plate")
    _req(b.place(make_template("book", rng, size=(0.21, 0.15, 0.018)), table.name, at=(0.0, 0.12), quarter=1), "book")
    _req(
        b.place(make_template("book", rng, size=(0.24, 0.17, 0.025)), table.name, at=(-0.05, -0.15), quarter=0), "book"
    )
    _req(b.place(make_template("plate", rng, size=(0.1, 0.015)), table.name, at=(0.3, -0.1)), "plate")
    b.against_wall(make_template("shelf", rng, boards=3), "+y")
    b.focus = [table.name]
    return b.build("thin objects lying flat: plates and books on a table")


def _small_beside_large(seed: int) -> SceneSpec:
    b = SceneBuilder("small_beside_large", _rng(seed, "small_beside_large"), strict=True)
    rng = b.rng
    table = b.place(make_template("table", rng), BACKGROUND, at=(0.0, 0.0), quarter=0)
    assert table is not None
    big = b.place(make_template("box", rng, size=(0.4, 0.35, 0.35)), table.name, at=(-0.1, 0.0), quarter=0)
    assert big is not None
    b.place_touching(make_template("box", rng, size=(0.04, 0.04, 0.04)), big.name, side="+u", quarter=0)
    cabinet = b.against_wall(make_template("cabinet", rng), "+x", along=0.5, wall_gap=0.02)
    assert cabinet is not None
    r = cabinet.footprint
    b.place(
        make_template("box", rng, size=(0.05, 0.05, 0.05)),
        BACKGROUND,
        at=(r[0] + 0.1, r[2] - 0.025),
        quarter=0,
        gap=-1e-6,
    )
    b.focus = [table.name]
    return b.build("small objects touching large ones: a 4 cm cube beside a 40 cm box, a 5 cm cube beside a cabinet")


def _touching_siblings(seed: int) -> SceneSpec:
    b = SceneBuilder("touching_siblings", _rng(seed, "touching_siblings"), strict=True)
    rng = b.rng
    table = b.place(make_template("table", rng), BACKGROUND, at=(0.0, 0.0), quarter=0)
    assert table is not None
    w = table.template.surfaces[0].x1 - table.template.surfaces[0].x0
    prev = _req(
        b.place(make_template("book", rng, size=(0.16, 0.22, 0.035)), table.name, at=(-w / 2 + 0.12, 0.0), quarter=0),
        "book",
    )
    for category, size in (("box", (0.15, 0.14, 0.12)), ("book", (0.2, 0.15, 0.04)), ("box", (0.12, 0.12, 0.18))):
        prev = _req(
            b.place_touching(make_template(category, rng, size=size), prev.name, side="+u", quarter=0), category
        )
    b.against_wall(make_template("cabinet", rng), "-y")
    b.focus = [table.name]
    return b.build("a row of books and boxes touching each other on a table")


def _shelf_scene(seed: int) -> SceneSpec:
    b = SceneBuilder("shelf", _rng(seed, "shelf"), strict=True)
    rng = b.rng
    shelf = b.against_wall(make_template("shelf", rng, boards=4), "+y", along=0.5, wall_gap=0.0)
    assert shelf is not None
    b.place(make_template("book", rng), shelf.name, surface=0, quarter=0)
    b.place(make_template("box", rng, size=(0.2, 0.2, 0.15)), shelf.name, surface=0, quarter=0)
    b.place(make_template("bowl", rng), shelf.name, surface=1)
    b.place(make_template("bottle", rng, size=(0.035, 0.18)), shelf.name, surface=2)
    b.place(make_template("mug", rng), shelf.name, surface=2, quarter=0)
    b.place(make_template("ball", rng, size=(0.07,)), shelf.name, surface=3)
    b.place(make_template("coffee_table", rng), BACKGROUND, at=(0.0, -0.5), gap=0.5)
    b.focus = [shelf.name]
    return b.build("a four-board shelf with objects on several boards")


def _top_only(seed: int) -> SceneSpec:
    b = SceneBuilder("top_only", _rng(seed, "top_only"), strict=True)
    rng = b.rng
    x, y, _ = b.room.size
    bw, bd, bh = 0.45, 0.4, 0.45
    cab_d = 0.45
    # the bin sits in the (+x, +y) corner; cabinet A against the +y wall covers its -x side,
    # cabinet B against the +x wall covers its -y side (B's depth equals the bin's width)
    b.place(
        make_template("box", rng, size=(bw, bd, bh)),
        BACKGROUND,
        at=(x / 2 - bw / 2, y / 2 - bd / 2),
        quarter=0,
        gap=-1e-6,
        name="bin",
    )
    cab_a = make_template("cabinet", rng, size=(0.8, cab_d, 0.8))
    b.place(cab_a, BACKGROUND, at=(x / 2 - bw - 0.4, y / 2 - cab_d / 2), quarter=0, gap=-1e-6)
    cab_b = make_template("cabinet", rng, size=(0.8, bw, 0.85))
    b.place(cab_b, BACKGROUND, at=(x / 2 - bw / 2, y / 2 - bd - 0.4), quarter=3, gap=-1e-6)
    b.place(make_template("table", rng), BACKGROUND, at=(-0.4, -0.3), gap=0.5)
    b.focus = ["bin"]
    b.close = ["bin"]
    return b.build("a low bin wedged in a corner between two cabinets: only its top is ever visible")


HARD_SCENES: dict[str, Callable[[int], SceneSpec]] = {
    "stack": _stack,
    "against_wall": _against_wall,
    "thin": _thin,
    "small_beside_large": _small_beside_large,
    "touching_siblings": _touching_siblings,
    "shelf": _shelf_scene,
    "top_only": _top_only,
}
"""One scene per failure mode, by name."""

SUITES: dict[str, dict[str, Callable[[int], SceneSpec]]] = {
    "demo": {"demo": _demo},
    "bench": {f"bench_{i:02d}": _bench(i) for i in range(_BENCH_SCENES)},
    "hard": HARD_SCENES,
}
"""Scene recipes of each suite: name -> function(seed) -> SceneSpec."""


def scene_names(suite: str) -> list[str]:
    """Scene names of ``suite``."""
    return list(SUITES[suite])


def build_scene(suite: str, name: str, seed: int) -> SceneSpec:
    """Lay out scene ``name`` of ``suite`` for ``seed``."""
    return SUITES[suite][name](seed)
