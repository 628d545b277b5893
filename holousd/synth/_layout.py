"""Scene layout: a room, furniture on its floor and small objects on support surfaces, by real support relations.

Every object rests exactly on one support surface of its parent (the floor of the room, a table top, a shelf
board, a book...): its bottom (z = 0 in object coordinates) lies in the surface plane and its footprint lies
entirely inside the surface rectangle, so a box rests flat with its centre of mass over the support. Objects
turn about Z by multiples of 90 degrees relative to their parent (round objects turn freely), so footprints are
axis-aligned rectangles in the parent frame and non-overlap is exact. Siblings placed flush against each other
touch along a face; such pairs are recorded as beside.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from holousd.synth._catalog import SupportSurface, Template, Texture
from holousd.synth._example import _box
from holousd.usd import BACKGROUND, MeshData, Pose

__all__ = ["BOXY", "PlacedObject", "Room", "SceneBuilder", "SceneSpec"]

BOXY = ("book", "box", "cabinet", "shelf", "sofa")
"""Categories whose footprint is a full rectangle at the support plane (they may be placed touching)."""
_TOUCH_TOL = 1e-6
"""Gap below which two footprints count as touching, metres."""


@dataclass(kw_only=True)
class Room:
    """The static room shell (the background node): a hollow box with floor at z = 0."""

    size: np.ndarray
    """[3] interior extent (x, y, height), metres; the interior spans [-x/2, x/2] x [-y/2, y/2] x [0, height]."""
    wall: float = 0.1
    """Thickness of floor, walls and ceiling, metres."""
    floor_texture: Texture
    """Appearance of the floor."""
    wall_texture: Texture
    """Appearance of the walls."""
    ceiling_texture: Texture
    """Appearance of the ceiling."""

    def mesh(self) -> MeshData:
        """Watertight hollow box (outer minus inner), world coordinates; inner faces point into the room."""
        import manifold3d

        def solid(mesh: MeshData) -> manifold3d.Manifold:
            return manifold3d.Manifold(
                manifold3d.Mesh(vert_properties=mesh.points.astype(np.float32), tri_verts=mesh.faces.astype(np.uint32))
            )

        x, y, h = self.size
        t = self.wall
        outer = _box((x + 2 * t, y + 2 * t, h + 2 * t), (0.0, 0.0, h / 2))
        inner = _box((x, y, h), (0.0, 0.0, h / 2))
        out = (solid(outer) - solid(inner)).to_mesh()
        return MeshData(points=np.asarray(out.vert_properties)[:, :3], faces=np.asarray(out.tri_verts))

    def slabs(self) -> list[MeshData]:
        """The same shell as six disjoint convex boxes (floor, ceiling, four walls), world coordinates.

        Their union is exactly :meth:`mesh`'s solid; as collider parts every simulator treats them as hulls,
        which is cheaper than triangle-mesh contact and avoids hulling the hollow shell into a filled box.
        """
        x, y, h = self.size
        t = self.wall
        return [
            _box((x + 2 * t, y + 2 * t, t), (0.0, 0.0, -t / 2)),  # floor
            _box((x + 2 * t, y + 2 * t, t), (0.0, 0.0, h + t / 2)),  # ceiling
            _box((t, y + 2 * t, h), (-(x + t) / 2, 0.0, h / 2)),  # -x wall (full depth, owns the corners)
            _box((t, y + 2 * t, h), ((x + t) / 2, 0.0, h / 2)),  # +x wall
            _box((x, t, h), (0.0, -(y + t) / 2, h / 2)),  # -y wall
            _box((x, t, h), (0.0, (y + t) / 2, h / 2)),  # +y wall
        ]


@dataclass(kw_only=True)
class PlacedObject:
    """An object of the scene with its world pose and support relations."""

    name: str
    """Prim name under /World/Objects."""
    instance_id: int
    """Instance id in the masks (1..N)."""
    template: Template
    """Geometry, material and appearance."""
    pose: Pose
    """Object-to-world pose."""
    parent: str
    """Name of the node it rests on ('background' for the floor)."""
    surface: int
    """Index of the parent's support surface it rests on (-1 for the floor)."""
    footprint: tuple[float, float, float, float]
    """(u0, u1, v0, v1) rectangle it covers in the parent's frame (world x, y for the floor), metres."""
    beside: list[str] = field(default_factory=list)
    """Siblings it touches side by side."""

    @property
    def category(self) -> str:
        """Template category."""
        return self.template.category

    def world_parts(self) -> list[np.ndarray]:
        """Vertices of each convex part in world coordinates ([P_i, 3] each)."""
        return [self.pose.apply(p.points) for p in self.template.parts]


@dataclass(kw_only=True)
class SceneSpec:
    """A complete procedural scene: room, objects, support tree and what the scene is meant to exercise."""

    name: str
    """Scene name (folder name)."""
    description: str
    """One line saying what the scene exercises."""
    room: Room
    """The static room."""
    objects: list[PlacedObject]
    """Objects in instance-id order."""
    focus: list[str] = field(default_factory=list)
    """Objects the camera path must look at (default: all furniture)."""
    close: list[str] = field(default_factory=list)
    """Objects the camera path views from nearby and above."""

    def by_name(self, name: str) -> PlacedObject:
        """The object called ``name``."""
        for obj in self.objects:
            if obj.name == name:
                return obj
        raise KeyError(name)

    def beside_pairs(self) -> list[tuple[str, str]]:
        """Sorted unique (a, b) name pairs of touching siblings, a < b."""
        return sorted({tuple(sorted((o.name, b))) for o in self.objects for b in o.beside})  # type: ignore[misc]


def _yaw_quat(yaw: float) -> np.ndarray:
    return np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])


def _overlap(a: tuple, b: tuple, gap: float) -> bool:
    """True when rectangles a and b come closer than ``gap`` (negative gap allows that much overlap)."""
    return a[0] < b[1] + gap and b[0] < a[1] + gap and a[2] < b[3] + gap and b[2] < a[3] + gap


class SceneBuilder:
    """Places objects one by one; every placement either succeeds exactly or returns None.

    Args:
        name: Scene name.
        rng: Random generator driving every choice.
        room_size: Interior (x, y, height) in metres; random when None.
        textures: Room textures (floor, wall, ceiling); random when None.
        strict: Raise when a placement does not fit (hand-written recipes) instead of returning None.
    """

    def __init__(
        self,
        name: str,
        rng: np.random.Generator,
        room_size: tuple[float, float, float] | None = None,
        textures: tuple[Texture, Texture, Texture] | None = None,
        strict: bool = False,
    ) -> None:
        self.name = name
        self.strict = strict
        self.rng = rng
        size = np.asarray(room_size or (rng.uniform(4.4, 5.6), rng.uniform(3.8, 4.8), 2.6), dtype=np.float64)
        floor, wall, ceiling = textures or self._room_textures()
        self.room = Room(size=size, floor_texture=floor, wall_texture=wall, ceiling_texture=ceiling)
        self.objects: list[PlacedObject] = []
        self._counts: dict[str, int] = {}
        self.focus: list[str] = []
        self.close: list[str] = []

    def _room_textures(self) -> tuple[Texture, Texture, Texture]:
        rng = self.rng
        floor_kind = "tiles" if rng.random() < 0.4 else "wood"
        floor_col = [(0.62, 0.45, 0.3), (0.5, 0.38, 0.28), (0.7, 0.68, 0.62), (0.45, 0.45, 0.48)][int(rng.integers(4))]
        floor = Texture(
            pattern=floor_kind,
            color=floor_col,
            color2=tuple(0.7 * np.asarray(floor_col)),
            scale=float(rng.uniform(0.25, 0.4) if floor_kind == "tiles" else rng.uniform(0.08, 0.15)),
            seed=int(rng.integers(2**31)),
        )
        wall_col = [(0.88, 0.86, 0.8), (0.78, 0.82, 0.85), (0.85, 0.8, 0.72), (0.8, 0.85, 0.78)][int(rng.integers(4))]
        wall = Texture(
            pattern="plaster",
            color=wall_col,
            color2=tuple(0.85 * np.asarray(wall_col)),
            scale=0.3,
            seed=int(rng.integers(2**31)),
        )
        ceiling = Texture(
            pattern="plaster",
            color=(0.93, 0.93, 0.92),
            color2=(0.85, 0.85, 0.84),
            scale=0.5,
            seed=int(rng.integers(2**31)),
        )
        return floor, wall, ceiling

    # ------------------------------------------------------------------ helpers
    def _name(self, category: str) -> str:
        self._counts[category] = self._counts.get(category, 0) + 1
        return f"{category}_{self._counts[category]}"

    def _siblings(self, parent: str, surface: int) -> list[PlacedObject]:
        return [o for o in self.objects if o.parent == parent and o.surface == surface]

    def _surface(self, parent: str, surface: int) -> tuple[SupportSurface, Pose, float]:
        """Support rectangle in the parent's frame, the parent's pose and the parent's world yaw."""
        if parent == BACKGROUND:
            x, y, h = self.room.size
            return SupportSurface(x0=-x / 2, x1=x / 2, y0=-y / 2, y1=y / 2, z=0.0, clearance=h), Pose(), 0.0
        obj = self._get(parent)
        q = obj.pose.orientation
        return obj.template.surfaces[surface], obj.pose, float(2 * np.arctan2(q[2], q[3]))

    def _get(self, name: str) -> PlacedObject:
        for obj in self.objects:
            if obj.name == name:
                return obj
        raise KeyError(f"{self.name}: no object {name!r} placed yet")

    @staticmethod
    def _half(template: Template, quarter: int) -> tuple[float, float]:
        sx, sy = template.size[0] / 2, template.size[1] / 2
        if template.round:
            r = max(sx, sy)
            return r, r
        return (sy, sx) if quarter % 2 else (sx, sy)

    def _fits(
        self, rect: tuple, parent: str, surface: int, support: SupportSurface, gap: float, touching: str | None = None
    ) -> bool:
        if rect[0] < support.x0 - 1e-9 or rect[1] > support.x1 + 1e-9:
            return False
        if rect[2] < support.y0 - 1e-9 or rect[3] > support.y1 + 1e-9:
            return False
        for other in self._siblings(parent, surface):
            g = -_TOUCH_TOL if other.name == touching else gap
            if _overlap(rect, other.footprint, g):
                return False
        return True

    def _commit(
        self, template: Template, parent: str, surface: int, rect: tuple, quarter: int, name: str | None
    ) -> PlacedObject:
        support, parent_pose, parent_yaw = self._surface(parent, surface)
        u, v = (rect[0] + rect[1]) / 2, (rect[2] + rect[3]) / 2
        rel_yaw = quarter * np.pi / 2
        if template.round:
            rel_yaw = float(self.rng.uniform(0, 2 * np.pi)) if template.category != "ball" else 0.0
        world = parent_pose.apply(np.array([[u, v, support.z]]))[0]
        pose = Pose(translation=world, orientation=_yaw_quat(parent_yaw + rel_yaw))
        obj = PlacedObject(
            name=name or self._name(template.category),
            instance_id=len(self.objects) + 1,
            template=template,
            pose=pose,
            parent=parent,
            surface=-1 if parent == BACKGROUND else surface,
            footprint=rect,
        )
        self.objects.append(obj)
        return obj

    # ------------------------------------------------------------------ placement
    def _checked(self, obj: PlacedObject | None, what: str) -> PlacedObject | None:
        if obj is None and self.strict:
            raise RuntimeError(f"{self.name}: the recipe could not place {what}; adjust the recipe")
        return obj

    def place(self, template: Template, parent: str = BACKGROUND, **kwargs: object) -> PlacedObject | None:
        """Rest ``template`` on ``parent``'s support ``surface`` at ``at`` (centre in the parent frame) or at a
        random free spot; None when it does not fit. ``gap`` is the minimum distance to siblings, metres.

        Keyword arguments: ``surface``, ``at``, ``quarter`` (quarter turns about Z relative to the parent),
        ``gap``, ``name``, ``tries``.
        """
        return self._checked(self._place(template, parent, **kwargs), f"a {template.category} on {parent}")  # type: ignore[arg-type]

    def place_touching(self, template: Template, other: str, **kwargs: object) -> PlacedObject | None:
        """Rest ``template`` on the same surface as ``other``, flush against one of its sides ('+u', '-u',
        '+v', '-v'; random when None) so that the two touch along a face; None when it does not fit.

        Keyword arguments: ``side``, ``quarter``, ``gap``, ``name``, ``tries``.
        """
        return self._checked(self._touching(template, other, **kwargs), f"a {template.category} beside {other}")  # type: ignore[arg-type]

    def against_wall(self, template: Template, wall: str | None = None, **kwargs: object) -> PlacedObject | None:
        """Rest furniture on the floor with its back (+Y) towards ``wall`` ('+x', '-x', '+y', '-y'), ``wall_gap``
        metres from it (0: pushed against it), at fraction ``along`` of the free length (random when None).

        Keyword arguments: ``along``, ``wall_gap``, ``gap``, ``name``.
        """
        return self._checked(self._wall(template, wall, **kwargs), f"a {template.category} against wall {wall}")  # type: ignore[arg-type]

    def _place(
        self,
        template: Template,
        parent: str = BACKGROUND,
        *,
        surface: int = 0,
        at: tuple[float, float] | None = None,
        quarter: int | None = None,
        gap: float = 0.02,
        name: str | None = None,
        tries: int = 200,
    ) -> PlacedObject | None:
        if parent == BACKGROUND:
            surface = -1
        support, _, _ = self._surface(parent, max(surface, 0))
        if template.size[2] > support.clearance - 0.01:
            return None
        for _ in range(tries if at is None else 1):
            q = int(self.rng.integers(4)) if quarter is None else quarter
            hx, hy = self._half(template, q)
            if at is None:
                lo_u, hi_u = support.x0 + hx + 0.005, support.x1 - hx - 0.005
                lo_v, hi_v = support.y0 + hy + 0.005, support.y1 - hy - 0.005
                if lo_u > hi_u or lo_v > hi_v:
                    return None
                u, v = self.rng.uniform(lo_u, hi_u), self.rng.uniform(lo_v, hi_v)
            else:
                u, v = at
            rect = (u - hx, u + hx, v - hy, v + hy)
            if self._fits(rect, parent, surface, support, gap):
                return self._commit(template, parent, surface, rect, q, name)
        return None

    def _touching(
        self,
        template: Template,
        other: str,
        *,
        side: str | None = None,
        quarter: int | None = None,
        gap: float = 0.02,
        name: str | None = None,
        tries: int = 60,
    ) -> PlacedObject | None:
        ref = self._get(other)
        if template.round or template.category not in BOXY or ref.category not in BOXY:
            raise ValueError(f"{self.name}: only box-like objects ({', '.join(BOXY)}) are placed touching")
        support, _, _ = self._surface(ref.parent, max(ref.surface, 0))
        if template.size[2] > support.clearance - 0.01:
            return None
        r = ref.footprint
        for _ in range(tries):
            s = side or ["+u", "-u", "+v", "-v"][int(self.rng.integers(4))]
            q = int(self.rng.integers(4)) if quarter is None else quarter
            hx, hy = self._half(template, q)
            if s in ("+u", "-u"):
                u = r[1] + hx if s == "+u" else r[0] - hx
                span = min(hy, (r[3] - r[2]) / 2)
                v = self.rng.uniform(r[2] + span - hy, r[3] - span + hy) if hy * 2 <= r[3] - r[2] else (r[2] + r[3]) / 2
                v = float(np.clip(v, r[2] - hy + 0.3 * span, r[3] + hy - 0.3 * span))
            else:
                v = r[3] + hy if s == "+v" else r[2] - hy
                span = min(hx, (r[1] - r[0]) / 2)
                u = self.rng.uniform(r[0] + span - hx, r[1] - span + hx) if hx * 2 <= r[1] - r[0] else (r[0] + r[1]) / 2
                u = float(np.clip(u, r[0] - hx + 0.3 * span, r[1] + hx - 0.3 * span))
            rect = (u - hx, u + hx, v - hy, v + hy)
            if self._fits(rect, ref.parent, ref.surface, support, gap, touching=other):
                return self._commit(template, ref.parent, ref.surface, rect, q, name)
        return None

    def _wall(
        self,
        template: Template,
        wall: str | None = None,
        *,
        along: float | None = None,
        wall_gap: float = 0.03,
        gap: float = 0.05,
        name: str | None = None,
    ) -> PlacedObject | None:
        x, y, _ = self.room.size
        for _ in range(40 if along is None else 1):
            w = wall or ["+x", "-x", "+y", "-y"][int(self.rng.integers(4))]
            # quarter turns that put object +Y towards the wall: +y -> 0, -x -> 1, -y -> 2, +x -> 3
            q = {"+y": 0, "-x": 1, "-y": 2, "+x": 3}[w]
            hx, hy = self._half(template, q)
            t = self.rng.uniform(0.1, 0.9) if along is None else along
            if w in ("+y", "-y"):
                u = -x / 2 + hx + t * (x - 2 * hx)
                v = y / 2 - wall_gap - hy if w == "+y" else -y / 2 + wall_gap + hy
            else:
                v = -y / 2 + hy + t * (y - 2 * hy)
                u = x / 2 - wall_gap - hx if w == "+x" else -x / 2 + wall_gap + hx
            obj = self._place(template, BACKGROUND, at=(u, v), quarter=q, gap=gap, name=name)
            if obj is not None:
                return obj
        return None

    # ------------------------------------------------------------------ result
    def build(self, description: str) -> SceneSpec:
        """Record beside pairs, check the layout (support, containment, no interpenetration) and return it."""
        for obj in self.objects:
            obj.beside = []
        for i, a in enumerate(self.objects):
            for b in self.objects[i + 1 :]:
                if a.parent != b.parent or a.surface != b.surface:
                    continue
                ra, rb = a.footprint, b.footprint
                if not (a.category in BOXY and b.category in BOXY):
                    continue
                touch_u = min(abs(ra[1] - rb[0]), abs(rb[1] - ra[0])) < _TOUCH_TOL
                touch_v = min(abs(ra[3] - rb[2]), abs(rb[3] - ra[2])) < _TOUCH_TOL
                span_v = min(ra[3], rb[3]) - max(ra[2], rb[2])
                span_u = min(ra[1], rb[1]) - max(ra[0], rb[0])
                if (touch_u and span_v > 1e-4) or (touch_v and span_u > 1e-4):
                    a.beside.append(b.name)
                    b.beside.append(a.name)
        spec = SceneSpec(
            name=self.name,
            description=description,
            room=self.room,
            objects=list(self.objects),
            focus=list(self.focus),
            close=list(self.close),
        )
        check_layout(spec)
        return spec


def check_layout(spec: SceneSpec, tol: float = 1e-6) -> None:
    """Assert the physical validity of a layout; raises ValueError naming the offending objects.

    Checks that parts of different objects never overlap in volume (axis-aligned part boxes: exact for the
    boxes of the catalogue, conservative for round parts), that every object lies inside the room and that its
    bottom lies exactly on its parent's support plane.
    """
    x, y, h = spec.room.size
    boxes = []
    for obj in spec.objects:
        for points in obj.world_parts():
            boxes.append((obj.name, points.min(axis=0), points.max(axis=0)))
        lo = min(b[1][2] for b in boxes if b[0] == obj.name)
        if obj.parent == BACKGROUND:
            support_z = 0.0
        else:
            parent = spec.by_name(obj.parent)
            support_z = parent.pose.apply(np.array([[0.0, 0.0, parent.template.surfaces[obj.surface].z]]))[0, 2]
        if abs(lo - support_z) > 1e-6:
            raise ValueError(f"{spec.name}: {obj.name} bottom at z={lo:.6f}, its support plane is at {support_z:.6f}")
        all_pts = np.concatenate(obj.world_parts())
        if (
            all_pts[:, 0].min() < -x / 2 - tol
            or all_pts[:, 0].max() > x / 2 + tol
            or all_pts[:, 1].min() < -y / 2 - tol
            or all_pts[:, 1].max() > y / 2 + tol
            or all_pts[:, 2].max() > h + tol
        ):
            raise ValueError(f"{spec.name}: {obj.name} reaches outside the room")
    for i, (na, lo_a, hi_a) in enumerate(boxes):
        for nb, lo_b, hi_b in boxes[i + 1 :]:
            if na == nb:
                continue
            depth = np.minimum(hi_a, hi_b) - np.maximum(lo_a, lo_b)
            if np.all(depth > 1e-5):
                raise ValueError(f"{spec.name}: {na} and {nb} interpenetrate (overlap {depth.min():.4f} m)")
