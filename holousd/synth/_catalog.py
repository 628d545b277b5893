"""Parametric object templates: multi-part furniture and small objects, each built from convex parts.

Object frame: metres, Z up, origin at the centre of the bottom of the bounding box (the object rests on the
plane z = 0), the back of furniture faces +Y. Every part is a closed convex mesh; parts of one object overlap
by a millimetre or two so that their union is one watertight solid.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from holousd.synth._example import _box, _cylinder
from holousd.usd import MeshData

__all__ = ["SMALL_CATEGORIES", "FURNITURE_CATEGORIES", "SupportSurface", "Template", "Texture", "make_template"]

FURNITURE_CATEGORIES = ("table", "coffee_table", "shelf", "cabinet", "chair", "sofa")
"""Furniture the generator places on the floor."""
SMALL_CATEGORIES = ("book", "box", "mug", "bowl", "plate", "bottle", "ball")
"""Small objects the generator places on support surfaces."""
_OVERLAP = 0.002
"""How far joined parts of one object reach into each other, metres."""


@dataclass(kw_only=True)
class Texture:
    """A procedural solid texture evaluated in object coordinates."""

    pattern: str
    """'wood', 'checker', 'stripes', 'noise', 'tiles', 'plaster' or 'fabric'."""
    color: tuple[float, float, float]
    """Base albedo, linear [0, 1] RGB."""
    color2: tuple[float, float, float]
    """Second albedo of the pattern, [0, 1] RGB."""
    scale: float
    """Feature size of the pattern, metres."""
    seed: int
    """Seed of the pattern's noise."""


@dataclass(kw_only=True)
class SupportSurface:
    """An upward-facing rectangle of an object, in object coordinates, that other objects may rest on."""

    x0: float
    """Minimum x, metres."""
    x1: float
    """Maximum x, metres."""
    y0: float
    """Minimum y, metres."""
    y1: float
    """Maximum y, metres."""
    z: float
    """Height of the surface, metres."""
    clearance: float
    """Free height above the surface (to the next board or the ceiling), metres."""


@dataclass(kw_only=True)
class Template:
    """A placeable object: geometry, physical material, appearance and the surfaces it offers."""

    category: str
    """Object category ('table', 'book', ...)."""
    parts: list[MeshData]
    """Closed convex parts in object coordinates (their union is the object)."""
    size: np.ndarray
    """[3] extent of the bounding box, metres."""
    round: bool
    """True when the footprint is a disc (any yaw keeps it inside its bounding square)."""
    density: float
    """Material density, kg / m^3."""
    friction: float
    """Static and dynamic friction coefficient."""
    texture: Texture
    """Appearance."""
    surfaces: list[SupportSurface] = field(default_factory=list)
    """Surfaces other objects may rest on."""


def _frustum(r_bottom: float, r_top: float, height: float, segments: int = 24) -> MeshData:
    cyl = _cylinder(1.0, height, segments)
    points = cyl.points.copy()
    top = points[:, 2] > height / 2
    points[:, :2] *= np.where(top, r_top, r_bottom)[:, None]
    return MeshData(points=points, faces=cyl.faces)


def _ball(radius: float, flat: float = 0.25, rings: int = 8, segments: int = 16) -> MeshData:
    """A sphere of ``radius`` cut flat at the bottom (contact disc of radius ``flat * radius``), bottom at z=0."""
    theta0 = np.arcsin(flat)  # polar angle of the cut, measured from the bottom pole
    thetas = np.linspace(theta0, np.pi, rings + 1)[:-1]  # rings from the cut up to below the top pole
    angle = 2 * np.pi * np.arange(segments) / segments
    points = [[0.0, 0.0, radius * (1 - np.cos(theta0))]]  # centre of the flat bottom
    for t in thetas:
        r, z = radius * np.sin(t), radius * (1 - np.cos(t))
        points += [[r * np.cos(a), r * np.sin(a), z] for a in angle]
    points.append([0.0, 0.0, 2 * radius])  # top pole
    top = len(points) - 1
    faces = []
    for j in range(segments):  # bottom cap (normal -z)
        k = (j + 1) % segments
        faces.append([0, 1 + k, 1 + j])
    for i in range(len(thetas) - 1):
        a, b = 1 + i * segments, 1 + (i + 1) * segments
        for j in range(segments):
            k = (j + 1) % segments
            faces += [[a + j, a + k, b + k], [a + j, b + k, b + j]]
    last = 1 + (len(thetas) - 1) * segments
    for j in range(segments):
        k = (j + 1) % segments
        faces.append([last + j, last + k, top])
    points = np.array(points)
    points[:, 2] -= points[0, 2]  # the flat bottom at z = 0
    return MeshData(points=points, faces=np.array(faces))


def _placed(mesh: MeshData, offset: tuple[float, float, float]) -> MeshData:
    return MeshData(points=mesh.points + np.asarray(offset), faces=mesh.faces)


def _color(rng: np.random.Generator, palette: list[tuple[float, float, float]], jitter: float = 0.06) -> tuple:
    base = np.asarray(palette[int(rng.integers(len(palette)))])
    return tuple(float(c) for c in np.clip(base + rng.uniform(-jitter, jitter, 3), 0.02, 0.98))


def _texture(rng: np.random.Generator, pattern: str, palette: list, scale: float, contrast: float = 0.35) -> Texture:
    c = _color(rng, palette)
    shade = np.asarray(c) * (1 - contrast) if rng.random() < 0.7 else np.asarray(_color(rng, palette))
    return Texture(
        pattern=pattern,
        color=c,
        color2=tuple(float(v) for v in np.clip(shade, 0, 1)),
        scale=scale,
        seed=int(rng.integers(2**31)),
    )


_WOOD = [(0.55, 0.36, 0.2), (0.7, 0.52, 0.33), (0.4, 0.25, 0.14), (0.78, 0.66, 0.5)]
_PAINT = [(0.85, 0.85, 0.82), (0.3, 0.4, 0.5), (0.55, 0.6, 0.45), (0.75, 0.7, 0.6), (0.25, 0.25, 0.28)]
_FABRIC = [(0.35, 0.4, 0.55), (0.55, 0.3, 0.3), (0.45, 0.5, 0.4), (0.6, 0.58, 0.55)]
_BRIGHT = [
    (0.8, 0.15, 0.12),
    (0.15, 0.35, 0.75),
    (0.9, 0.75, 0.15),
    (0.2, 0.6, 0.3),
    (0.85, 0.45, 0.1),
    (0.55, 0.25, 0.6),
    (0.1, 0.55, 0.6),
]
_CERAMIC = [(0.92, 0.9, 0.86), (0.85, 0.8, 0.7), (0.6, 0.72, 0.8), (0.35, 0.3, 0.28)]


def _table(rng: np.random.Generator, height: float) -> Template:
    w, d = rng.uniform(0.9, 1.4), rng.uniform(0.6, 0.8)
    thick, leg, inset = rng.uniform(0.03, 0.045), rng.uniform(0.045, 0.06), 0.04
    top = _box((w, d, thick), (0.0, 0.0, height - thick / 2))
    leg_h = height - thick + _OVERLAP
    legs = [
        _box((leg, leg, leg_h), (sx * (w / 2 - inset - leg / 2), sy * (d / 2 - inset - leg / 2), leg_h / 2))
        for sx in (-1, 1)
        for sy in (-1, 1)
    ]
    return Template(
        category="table" if height > 0.6 else "coffee_table",
        parts=[top, *legs],
        size=np.array([w, d, height]),
        round=False,
        density=650.0,
        friction=0.6,
        texture=_texture(rng, "wood", _WOOD, rng.uniform(0.03, 0.06)),
        surfaces=[SupportSurface(x0=-w / 2, x1=w / 2, y0=-d / 2, y1=d / 2, z=height, clearance=1.0)],
    )


def _shelf(rng: np.random.Generator, boards: int | None = None) -> Template:
    w, d = rng.uniform(0.7, 1.0), rng.uniform(0.3, 0.36)
    n = boards or int(rng.integers(3, 5))
    spacing = rng.uniform(0.34, 0.4)
    t, side, back = 0.02, 0.02, 0.012
    plinth = 0.06
    h = plinth + n * spacing + t
    parts = [_box((side, d, h), (sx * (w / 2 - side / 2), 0.0, h / 2)) for sx in (-1, 1)]
    parts.append(_box((w - 2 * side + 2 * _OVERLAP, back, h), (0.0, d / 2 - back / 2, h / 2)))
    surfaces = []
    inner_w = w - 2 * side
    for i in range(n + 1):
        z_top = plinth + i * spacing + t if i < n else h
        parts.append(_box((inner_w + 2 * _OVERLAP, d - back + _OVERLAP, t), (0.0, -back / 2, z_top - t / 2)))
        if i < n:
            surfaces.append(
                SupportSurface(
                    x0=-inner_w / 2, x1=inner_w / 2, y0=-d / 2, y1=d / 2 - back, z=z_top, clearance=spacing - t
                )
            )
    surfaces.append(SupportSurface(x0=-w / 2, x1=w / 2, y0=-d / 2, y1=d / 2, z=h, clearance=0.5))
    return Template(
        category="shelf",
        parts=parts,
        size=np.array([w, d, h]),
        round=False,
        density=550.0,
        friction=0.6,
        texture=_texture(rng, "wood", _WOOD + _PAINT[:2], rng.uniform(0.03, 0.05)),
        surfaces=surfaces,
    )


def _cabinet(rng: np.random.Generator, size: tuple[float, float, float] | None = None) -> Template:
    w, d, h = size or (rng.uniform(0.6, 1.0), rng.uniform(0.4, 0.5), rng.uniform(0.7, 0.95))
    plinth, recess, top_t = 0.07, 0.03, 0.025
    body = _box(
        (w, d, h - plinth - top_t + _OVERLAP), (0.0, 0.0, plinth + (h - plinth - top_t + _OVERLAP) / 2 - _OVERLAP / 2)
    )
    base = _box((w - 2 * recess, d - 2 * recess, plinth + _OVERLAP), (0.0, 0.0, (plinth + _OVERLAP) / 2))
    top = _box((w, d, top_t), (0.0, 0.0, h - top_t / 2))
    return Template(
        category="cabinet",
        parts=[base, body, top],
        size=np.array([w, d, h]),
        round=False,
        density=500.0,
        friction=0.6,
        texture=_texture(rng, "noise", _PAINT, rng.uniform(0.05, 0.12), 0.2),
        surfaces=[SupportSurface(x0=-w / 2, x1=w / 2, y0=-d / 2, y1=d / 2, z=h, clearance=1.0)],
    )


def _chair(rng: np.random.Generator) -> Template:
    s, seat_h, t, leg = rng.uniform(0.42, 0.48), rng.uniform(0.44, 0.48), 0.04, 0.035
    back_h, back_t = rng.uniform(0.35, 0.45), 0.03
    seat = _box((s, s, t), (0.0, 0.0, seat_h - t / 2))
    leg_h = seat_h - t + _OVERLAP
    legs = [
        _box((leg, leg, leg_h), (sx * (s / 2 - leg / 2), sy * (s / 2 - leg / 2), leg_h / 2))
        for sx in (-1, 1)
        for sy in (-1, 1)
    ]
    back = _box((s, back_t, back_h + _OVERLAP), (0.0, s / 2 - back_t / 2, seat_h + (back_h + _OVERLAP) / 2 - _OVERLAP))
    return Template(
        category="chair",
        parts=[seat, *legs, back],
        size=np.array([s, s, seat_h + back_h]),
        round=False,
        density=600.0,
        friction=0.6,
        texture=_texture(rng, "wood", _WOOD, rng.uniform(0.03, 0.05)),
        surfaces=[SupportSurface(x0=-s / 2, x1=s / 2, y0=-s / 2, y1=s / 2 - back_t, z=seat_h, clearance=0.6)],
    )


def _sofa(rng: np.random.Generator) -> Template:
    w, d = rng.uniform(1.5, 2.0), rng.uniform(0.8, 0.9)
    seat_h, back_h, arm_h = rng.uniform(0.4, 0.45), rng.uniform(0.75, 0.85), rng.uniform(0.55, 0.62)
    back_t, arm_t = 0.18, 0.16
    base = _box(
        (w - 2 * arm_t + 2 * _OVERLAP, d - back_t + _OVERLAP, seat_h), (0.0, -back_t / 2 + _OVERLAP / 2, seat_h / 2)
    )
    back = _box((w, back_t, back_h), (0.0, d / 2 - back_t / 2, back_h / 2))
    arms = [
        _box((arm_t, d - back_t + _OVERLAP, arm_h), (sx * (w / 2 - arm_t / 2), -back_t / 2 + _OVERLAP / 2, arm_h / 2))
        for sx in (-1, 1)
    ]
    inner = w / 2 - arm_t
    return Template(
        category="sofa",
        parts=[base, back, *arms],
        size=np.array([w, d, back_h]),
        round=False,
        density=200.0,
        friction=0.8,
        texture=_texture(rng, "fabric", _FABRIC, rng.uniform(0.01, 0.02), 0.25),
        surfaces=[SupportSurface(x0=-inner, x1=inner, y0=-d / 2, y1=d / 2 - back_t, z=seat_h, clearance=0.6)],
    )


def _small(rng: np.random.Generator, category: str, size: tuple[float, ...] | None = None) -> Template:
    """Small objects; ``size`` overrides the random dimensions (category-specific meaning)."""
    if category == "book":
        w, d, t = size or (rng.uniform(0.15, 0.24), rng.uniform(0.11, 0.17), rng.uniform(0.02, 0.045))
        parts, extent, rnd = [_box((w, d, t), (0.0, 0.0, t / 2))], (w, d, t), False
        density, tex = 700.0, _texture(rng, "stripes", _BRIGHT, rng.uniform(0.01, 0.03), 0.4)
        surfaces = [SupportSurface(x0=-w / 2, x1=w / 2, y0=-d / 2, y1=d / 2, z=t, clearance=0.5)]
    elif category == "box":
        w, d, h = size or (rng.uniform(0.08, 0.3), rng.uniform(0.08, 0.25), rng.uniform(0.06, 0.22))
        parts, extent, rnd = [_box((w, d, h), (0.0, 0.0, h / 2))], (w, d, h), False
        density, tex = 250.0, _texture(rng, "checker", _BRIGHT + _PAINT, rng.uniform(0.02, 0.05), 0.3)
        surfaces = [SupportSurface(x0=-w / 2, x1=w / 2, y0=-d / 2, y1=d / 2, z=h, clearance=0.5)]
    elif category == "mug":
        r, h = size or (rng.uniform(0.035, 0.045), rng.uniform(0.09, 0.11))
        body = _cylinder(r, h)
        handle = _box((0.012, 0.02, 0.6 * h), (r + 0.006 - _OVERLAP, 0.0, 0.5 * h))
        parts, extent, rnd = [body, handle], (2 * r + 0.012, 2 * r, h), False
        density, tex, surfaces = 900.0, _texture(rng, "noise", _CERAMIC + _BRIGHT, 0.02, 0.15), []
    elif category == "bowl":
        rb, rt, h = size or (rng.uniform(0.04, 0.05), rng.uniform(0.07, 0.09), rng.uniform(0.05, 0.07))
        parts, extent, rnd = [_frustum(rb, rt, h)], (2 * rt, 2 * rt, h), True
        density, tex, surfaces = 700.0, _texture(rng, "noise", _CERAMIC, 0.02, 0.15), []
    elif category == "plate":
        r, t = size or (rng.uniform(0.1, 0.13), rng.uniform(0.012, 0.02))
        parts, extent, rnd = [_cylinder(r, t, 32)], (2 * r, 2 * r, t), True
        density, tex, surfaces = 2000.0, _texture(rng, "noise", _CERAMIC, 0.03, 0.1), []
    elif category == "bottle":
        r, h = size or (rng.uniform(0.03, 0.04), rng.uniform(0.15, 0.22))
        neck_r, neck_h = 0.35 * r, 0.3 * h
        parts = [_cylinder(r, h), _placed(_cylinder(neck_r, neck_h + _OVERLAP), (0.0, 0.0, h - _OVERLAP))]
        extent, rnd = (2 * r, 2 * r, h + neck_h), True
        density, tex, surfaces = 400.0, _texture(rng, "stripes", _BRIGHT, 0.03, 0.3), []
    elif category == "ball":
        (r,) = size or (rng.uniform(0.05, 0.1),)
        ball = _ball(r)
        parts, extent, rnd = [ball], (2 * r, 2 * r, float(ball.points[:, 2].max())), True
        density, tex, surfaces = 150.0, _texture(rng, "checker", _BRIGHT, r * 0.6, 0.5), []
    else:
        raise ValueError(f"unknown small-object category {category!r}; choose one of {SMALL_CATEGORIES}")
    return Template(
        category=category,
        parts=parts,
        size=np.asarray(extent, dtype=np.float64),
        round=rnd,
        density=density,
        friction=0.5,
        texture=tex,
        surfaces=surfaces,
    )


def _normalised(template: Template) -> Template:
    """Shift the parts so the bounding box is centred in x, y with its bottom at z = 0; set ``size``."""
    points = np.concatenate([p.points for p in template.parts])
    lo, hi = points.min(axis=0), points.max(axis=0)
    shift = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    template.parts = [_placed(p, tuple(shift)) for p in template.parts]
    for s in template.surfaces:
        s.x0, s.x1, s.y0, s.y1, s.z = s.x0 + shift[0], s.x1 + shift[0], s.y0 + shift[1], s.y1 + shift[1], s.z + shift[2]
    template.size = hi - lo
    return template


def make_template(category: str, rng: np.random.Generator, **kwargs: object) -> Template:
    """Build a template of ``category`` with random dimensions drawn from ``rng``.

    Keyword arguments: ``size`` (small objects, cabinets), ``boards`` (shelves).
    """
    return _normalised(_make(category, rng, **kwargs))


def _make(category: str, rng: np.random.Generator, **kwargs: object) -> Template:
    if category == "table":
        return _table(rng, rng.uniform(0.72, 0.76))
    if category == "coffee_table":
        return _table(rng, rng.uniform(0.4, 0.46))
    if category == "shelf":
        return _shelf(rng, kwargs.get("boards"))  # type: ignore[arg-type]
    if category == "cabinet":
        return _cabinet(rng, kwargs.get("size"))  # type: ignore[arg-type]
    if category == "chair":
        return _chair(rng)
    if category == "sofa":
        return _sofa(rng)
    return _small(rng, category, kwargs.get("size"))  # type: ignore[arg-type]
