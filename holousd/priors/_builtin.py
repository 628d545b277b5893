"""The built-in completion proposers (no weights) and the learned-prior adapter (weights from a path).

Every proposer works on a voxel occupancy in object coordinates, on the object's stage-1 grid (its voxel size)
grown to what the candidate needs (down to the support, across a symmetry plane), and turns it into a candidate
with :func:`_candidate`: the signed distance of the occupancy and its marching-cubes mesh (watertight, largest
component). Where the stage-1 shape is all a proposer has, it starts from that shape's inside (``sdf < 0``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from holousd._errors import HolousdError
from holousd.geometry._grid import VoxelGrid, sample_grid, signed_distance_from_occupancy
from holousd.geometry._meshing import mesh_from_sdf, meshed_only
from holousd.priors._api import Candidate, ObjectEvidence
from holousd.usd._types import SdfField

__all__ = ["ExtrudeProposer", "LearnedProposer", "PrimitiveProposer", "Stage1Proposer", "SymmetryProposer",
           "VisualHullProposer"]  # fmt: skip


# ----------------------------------------------------------------------------------------------- shared helpers
def _voxel(evidence: ObjectEvidence) -> float:
    if evidence.sdf is not None:
        return float(evidence.sdf.voxel_size)
    extent = float(np.ptp(evidence.mesh.points, axis=0).max()) if len(evidence.mesh.points) else 0.1
    return max(extent / 40.0, 1e-3)


_MAX_SAMPLES = 2_000_000
"""Largest candidate grid, samples: the voxel grows beyond the object's own for a grid reaching far (a small
object carried down to a support far below it), so that a proposer's memory stays bounded."""


def _grid(lo: np.ndarray, hi: np.ndarray, voxel: float) -> VoxelGrid:
    size = np.asarray(hi, float) - np.asarray(lo, float) + 4 * voxel
    voxel = max(voxel, float(np.prod(np.maximum(size, voxel)) / _MAX_SAMPLES) ** (1 / 3))
    return VoxelGrid.from_bounds(np.asarray(lo, float), np.asarray(hi, float), voxel, pad=2)


def _stage1_values(evidence: ObjectEvidence, points: np.ndarray) -> np.ndarray:
    """[P] the stage-1 shape's signed distance at object-coordinate points (its SDF, trilinear; without one, +-1
    from its mesh), negative inside."""
    if evidence.sdf is not None:
        sdf = evidence.sdf
        grid = VoxelGrid(origin=sdf.origin, voxel_size=sdf.voxel_size, shape=sdf.resolution)
        return sample_grid(sdf.grid, grid, points, outside=1.0) - float(sdf.iso_level)
    import trimesh

    from holousd.geometry._contact import inside

    found = inside(trimesh.Trimesh(evidence.mesh.points, evidence.mesh.faces, process=False), points)
    return np.where(found, -1.0, 1.0).astype(np.float32)


def _stage1_inside(evidence: ObjectEvidence, points: np.ndarray) -> np.ndarray:
    """[P] bool: object-coordinate points inside the stage-1 shape (its SDF, or its mesh without one)."""
    return _stage1_values(evidence, points) < 0


def _local(evidence: ObjectEvidence, world: np.ndarray) -> np.ndarray:
    inverse = np.linalg.inv(evidence.pose.matrix())
    return np.asarray(world, float) @ inverse[:3, :3].T + inverse[:3, 3]


def _upright(evidence: ObjectEvidence) -> bool:
    """True when the object's z axis is the world's (fitted poses are: rotation about z at most)."""
    rotation = evidence.pose.matrix()[:3, :3]
    return bool(abs(rotation[2, 2]) > 1 - 1e-6)


def _support_z(evidence: ObjectEvidence) -> float | None:
    """The support's surface height in object coordinates (None when not known or the object is tilted)."""
    if evidence.support_height is None or not _upright(evidence):
        return None
    return float(evidence.support_height - evidence.pose.matrix()[2, 3])


def _candidate(name: str, seed: int, occupied: np.ndarray, grid: VoxelGrid, note: str,
               max_faces: int | None = 4000, base: np.ndarray | None = None) -> Candidate | None:  # fmt: skip
    """The candidate of an occupancy on ``grid`` (object coordinates), its mesh simplified to about
    ``max_faces`` (within a voxel); None when it is empty. With ``base`` ([P] signed distance of the shape the
    occupancy grew from, the stage-1 shape's), that shape keeps its surface and only what ``occupied`` adds to it
    is a union of voxels: re-voxelising a fitted table grows its 4 cm legs and top by up to a voxel, enough for
    the grown shape to cover pixels the cameras saw through (rejected by E_obs)."""
    if not occupied.any():
        return None
    if base is None:
        sdf = signed_distance_from_occupancy(occupied.reshape(grid.shape), grid.voxel_size)
    else:
        reach = 3.0 * grid.voxel_size
        sdf = np.clip(np.asarray(base, np.float32), -reach, reach).reshape(grid.shape)
        added = occupied.reshape(grid.shape) & (sdf >= 0)
        if added.any():
            sdf = np.minimum(sdf, signed_distance_from_occupancy(added, grid.voxel_size))
    meshed = mesh_from_sdf(sdf, grid.origin, grid.voxel_size, max_faces=max_faces)
    if meshed is None or not meshed.watertight:
        return None
    sdf = meshed_only(sdf, grid.origin, grid.voxel_size, meshed.mesh)  # what the meshing dropped is not the shape
    return Candidate(proposer=name, seed=seed, mesh=meshed.mesh,
                     sdf=SdfField(grid=sdf, origin=grid.origin, voxel_size=grid.voxel_size), note=note)  # fmt: skip


def _stage1_bounds(evidence: ObjectEvidence) -> tuple[np.ndarray, np.ndarray]:
    points = np.asarray(evidence.mesh.points, float)
    lo, hi = points.min(axis=0), points.max(axis=0)
    if len(evidence.points):
        seen = _local(evidence, evidence.points)
        lo, hi = np.minimum(lo, seen.min(axis=0)), np.maximum(hi, seen.max(axis=0))
    return lo, hi


# ----------------------------------------------------------------------------------------------- proposers
class Stage1Proposer:
    """The stage-1 (fitted) shape itself: the candidate every search keeps to compare against."""

    name = "stage1"

    def propose(self, evidence: ObjectEvidence, k: int, seed: int) -> list[Candidate]:
        if k < 1 or len(evidence.mesh.faces) == 0:
            return []
        return [Candidate(proposer=self.name, seed=seed, mesh=evidence.mesh, sdf=evidence.sdf, note="as fitted")]


class ExtrudeProposer:
    """Support extrusion: the unseen lower part carried along gravity down to the support's surface.

    Candidate 1 carries every column of the stage-1 shape down to the support (an object whose sides were hidden);
    candidate 2 only the columns that already reach below half the object's height (legs and sides seen in part,
    continued to the floor; a table top's middle stays open). Needs an upright object and a known support."""

    name = "extrude"

    def propose(self, evidence: ObjectEvidence, k: int, seed: int) -> list[Candidate]:
        floor = _support_z(evidence)
        if floor is None or k < 1:
            return []
        lo, hi = _stage1_bounds(evidence)
        if floor >= hi[2]:
            return []
        lo = lo.copy()
        lo[2] = min(lo[2], floor)
        grid = _grid(lo, hi, _voxel(evidence))
        values = _stage1_values(evidence, grid.points())
        occupied = (values < 0).reshape(grid.shape)
        if not occupied.any():
            return []
        out = []
        for variant in ("all columns", "columns reaching below mid-height"):
            if len(out) >= k:
                break
            filled = _carried_down(occupied, grid, floor, legs_only=variant != "all columns")
            if filled is None:
                continue
            found = _candidate(self.name, seed, filled, grid, f"{variant} carried down to z = {floor:.3f} m",
                               base=values)  # fmt: skip
            if found is not None:
                out.append(found)
        return out


LEG_REACH = 0.1
"""A leg reaches below the median column's lowest sample by more than this share of the object's height above
its support (:func:`_carried_down`)."""
LEG_RISE = 0.25
"""Legs are looked for under a bulk whose median column's lowest sample lies more than this share of the
object's height above its support (a chair's seat fitted 46% up; a ball's columns 15%, a box sagging at one edge
14%, a bowl 1%: their sagging columns alone carried down made a stem under a ball, which then rolled off its
shelf, and a ledge under a mug, which tipped 10 deg; hard/shelf, default preset)."""


LEG_HOLD = 0.1
"""Under a compact object (not raised off its support), the columns reaching below the rest are its legs when the
base they make holds its centre of mass at least this share of its smaller width inside (:func:`_holds`)."""


def _holds(columns: np.ndarray, occupied: np.ndarray, grid: VoxelGrid) -> bool:
    """True when the footprint of ``columns`` [X, Y] (each a voxel wide) holds the centre of the ``occupied``
    [X, Y, Z] voxels ``LEG_HOLD`` of the occupied footprint's smaller width inside its convex hull."""
    from scipy.spatial import ConvexHull, QhullError

    half = 0.5 * grid.voxel_size
    ij = np.argwhere(columns)
    centres = grid.origin[:2] + grid.voxel_size * ij
    corners = np.concatenate([centres + [dx, dy] for dx in (-half, half) for dy in (-half, half)])
    cells = np.argwhere(occupied)
    centre = grid.origin[:2] + grid.voxel_size * cells[:, :2].mean(axis=0)
    width = float(np.min(np.ptp(cells[:, :2], axis=0))) * grid.voxel_size + grid.voxel_size
    try:
        hull = ConvexHull(corners)
    except (QhullError, ValueError):
        return False
    margin = -float(np.max(hull.equations[:, :2] @ centre + hull.equations[:, 2]))
    return margin >= LEG_HOLD * width


def _carried_down(occupied: np.ndarray, grid: VoxelGrid, floor: float, *, legs_only: bool) -> np.ndarray | None:
    """[X, Y, Z] ``occupied`` with its columns carried down to ``floor`` (object z): every occupied column, or
    (``legs_only``) those already reaching below half the shape's height above the floor and, under a bulk
    raised off the floor (its median column's lowest sample more than ``LEG_RISE`` of that height up), where
    some do, below the rest: more than ``LEG_REACH`` of that height under that sample (legs and sides seen in
    part; a table top's middle stays open, and so does a chair's seat fitted below its mid-height with the legs
    under it cut short); under a compact object, those below the rest too where their base holds its centre of
    mass (``LEG_HOLD``: feet; a bump under a ball is no base, and every column below mid-height is carried down).
    None when no column qualifies."""
    z = grid.origin[2] + grid.voxel_size * np.arange(grid.shape[2])
    has = occupied.any(axis=2)
    if not has.any():
        return None
    bottom = np.where(has, np.argmax(occupied, axis=2), grid.shape[2])  # lowest occupied sample per column
    top = float(z[np.nonzero(occupied.any(axis=(0, 1)))[0].max()])
    columns = has
    if legs_only:
        lowest = z[np.minimum(bottom, grid.shape[2] - 1)]
        columns = has & (lowest < floor + 0.5 * (top - floor))
        median = float(np.median(lowest[has]))
        reaching = columns & (lowest < median - LEG_REACH * (top - floor))
        if median > floor + LEG_RISE * (top - floor):
            columns = reaching if reaching.any() else columns
        elif reaching.any() and _holds(reaching, occupied, grid):
            columns = reaching
    if not columns.any():
        return None
    below = np.arange(grid.shape[2])[None, None, :] <= bottom[:, :, None]
    return occupied | (columns[:, :, None] & below & (z >= floor)[None, None, :])


def _footprint(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The smallest-area rectangle around [P, 2] points: its centre [2] and the angle of one side, radians."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        ring = points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        return points.mean(axis=0), 0.0
    best = (np.inf, 0.0, points.mean(axis=0))
    for a, b in zip(ring, np.roll(ring, -1, axis=0), strict=True):
        edge = b - a
        if not np.any(edge):
            continue
        angle = float(np.arctan2(edge[1], edge[0]))
        u, v = np.array([np.cos(angle), np.sin(angle)]), np.array([-np.sin(angle), np.cos(angle)])
        pu, pv = ring @ u, ring @ v
        area = float(np.ptp(pu) * np.ptp(pv))
        if area < best[0] - 1e-12:
            centre = 0.5 * (pu.min() + pu.max()) * u + 0.5 * (pv.min() + pv.max()) * v
            best = (area, angle, centre)
    return best[2], best[1]


class SymmetryProposer:
    """Reflective symmetry about vertical planes: the stage-1 shape united with its mirror image.

    Planes through the centre of the smallest rectangle around the shape's footprint (stage-1 mesh and observed
    points): first its two axes, as furniture is made (a table whose far legs no camera saw is mirrored across
    the plane between its seen and its unseen legs: the observed points mirrored land where nothing was
    observed, so a score alone would never pick it), then every 15 degrees about z (those more than 7.5 degrees
    from both axes). Each plane is scored by how well the observed surface points mirrored across it land on
    observed points (mean distance to the nearest, capped at 5 cm); the footprint's axes come first, best first,
    then the others, best first; ``k`` candidates (with the search's default k = 2, the two axes). The search's
    E_obs rejects a mirror image that puts matter where a camera saw through."""

    name = "symmetry"
    cap = 0.05

    def propose(self, evidence: ObjectEvidence, k: int, seed: int) -> list[Candidate]:
        from scipy.spatial import cKDTree

        if k < 1 or len(evidence.points) < 20 or not _upright(evidence):
            return []
        seen = _local(evidence, evidence.points)
        lo, hi = _stage1_bounds(evidence)
        centre_xy, angle = _footprint(np.concatenate([np.asarray(evidence.mesh.points, float)[:, :2], seen[:, :2]]))
        centre = np.array([*centre_xy, 0.5 * (lo[2] + hi[2])])
        tree = cKDTree(seen)
        axes = {round(float(np.degrees(angle)) % 180.0, 6), round((float(np.degrees(angle)) + 90.0) % 180.0, 6)}
        scored = []
        sweep = [d for d in range(0, 180, 15) if all(min(abs(d - a), 180.0 - abs(d - a)) > 7.5 for a in axes)]
        for degrees in sorted(axes) + sweep:
            a = np.radians(degrees)
            n = np.array([np.cos(a), np.sin(a), 0.0])
            mirrored = seen - 2.0 * ((seen - centre) @ n)[:, None] * n
            distance, _ = tree.query(mirrored)
            scored.append((degrees not in axes, float(np.minimum(distance, self.cap).mean()), degrees, n))
        scored.sort(key=lambda s: (s[0], s[1], s[2]))
        floor = _support_z(evidence)
        out = []
        for _, score, degrees, n in scored[:k]:
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            reflected = corners - 2.0 * ((corners - centre) @ n)[:, None] * n
            low = np.minimum(lo, reflected.min(0))
            if floor is not None and floor < hi[2]:
                low[2] = min(low[2], floor)
            grid = _grid(low, np.maximum(hi, reflected.max(0)), _voxel(evidence))
            pts = grid.points().astype(np.float64)
            mirror = pts - 2.0 * ((pts - centre) @ n)[:, None] * n
            values = np.minimum(_stage1_values(evidence, pts), _stage1_values(evidence, mirror))
            occupied = values < 0
            if floor is not None and floor < hi[2]:  # legs end where the fit ended them: carried down, as extrude
                legs = _carried_down(occupied.reshape(grid.shape), grid, floor, legs_only=True)
                occupied = occupied if legs is None else legs.reshape(-1)
            found = _candidate(self.name, seed, occupied, grid, base=values, note=
                               f"mirrored across the vertical plane at {degrees:.0f} deg through the footprint's "
                               f"centre (fit {100 * score:.1f} cm)")  # fmt: skip
            if found is not None:
                out.append(found)
        return out


class PrimitiveProposer:
    """Primitive fits to the observed surface points: an upright box (turned about z to the points' principal
    axes, and unturned) and an upright cylinder (least-squares circle), each from the support's surface (or the
    points' lowest) to their highest; ranked by the points' mean distance to the primitive's surface."""

    name = "primitive"

    def propose(self, evidence: ObjectEvidence, k: int, seed: int) -> list[Candidate]:
        if k < 1 or len(evidence.points) < 20 or not _upright(evidence):
            return []
        seen = _local(evidence, evidence.points)
        floor = _support_z(evidence)
        z0 = float(np.percentile(seen[:, 2], 1)) if floor is None else floor
        z1 = float(np.percentile(seen[:, 2], 99))
        if z1 <= z0:
            return []
        xy = seen[:, :2]
        centred = xy - xy.mean(0)
        _, _, axes = np.linalg.svd(centred, full_matrices=False)
        options = []
        for label, axis in (("box along the principal axes", axes[0]), ("box along the object axes", np.eye(2)[0])):
            u, v = axis / np.linalg.norm(axis), np.array([-axis[1], axis[0]]) / np.linalg.norm(axis)
            pu, pv = xy @ u, xy @ v
            bounds = (np.percentile(pu, [1, 99]), np.percentile(pv, [1, 99]))
            du = np.minimum(np.abs(pu - bounds[0][0]), np.abs(pu - bounds[0][1]))
            dv = np.minimum(np.abs(pv - bounds[1][0]), np.abs(pv - bounds[1][1]))
            dz = np.minimum(np.abs(seen[:, 2] - z0), np.abs(seen[:, 2] - z1))
            residual = float(np.minimum(np.minimum(du, dv), dz).mean())
            options.append((residual, label, ("box", u, v, bounds)))
        # circle: x^2 + y^2 + D x + E y + F = 0 in least squares (Kasa)
        a = np.column_stack([xy, np.ones(len(xy))])
        b = -(xy**2).sum(1)
        (d, e, f), *_ = np.linalg.lstsq(a, b, rcond=None)
        centre = np.array([-d / 2, -e / 2])
        radius_sq = float(centre @ centre - f)
        if radius_sq > 0:
            radius = float(np.sqrt(radius_sq))
            dr = np.abs(np.linalg.norm(xy - centre, axis=1) - radius)
            dz = np.minimum(np.abs(seen[:, 2] - z0), np.abs(seen[:, 2] - z1))
            options.append((float(np.minimum(dr, dz).mean()), "upright cylinder", ("cylinder", centre, radius)))
        options.sort(key=lambda o: o[0])
        out = []
        voxel = _voxel(evidence)
        for residual, label, shape in options[:k]:
            if shape[0] == "box":
                _, u, v, (bu, bv) = shape
                corners = np.array([bu[i] * u + bv[j] * v for i in (0, 1) for j in (0, 1)])
                lo = np.array([*corners.min(0), z0])
                hi = np.array([*corners.max(0), z1])
                grid = _grid(lo, hi, voxel)
                pts = grid.points().astype(np.float64)
                pu, pv = pts[:, :2] @ u, pts[:, :2] @ v
                occupied = (pu >= bu[0]) & (pu <= bu[1]) & (pv >= bv[0]) & (pv <= bv[1])
                size = f"{100 * (bu[1] - bu[0]):.0f} x {100 * (bv[1] - bv[0]):.0f} x {100 * (z1 - z0):.0f} cm"
            else:
                _, centre, radius = shape
                grid = _grid(np.array([*(centre - radius), z0]), np.array([*(centre + radius), z1]), voxel)
                pts = grid.points().astype(np.float64)
                occupied = np.linalg.norm(pts[:, :2] - centre, axis=1) <= radius
                size = f"radius {100 * radius:.1f} cm, height {100 * (z1 - z0):.0f} cm"
            occupied &= (pts[:, 2] >= z0) & (pts[:, 2] <= z1)
            found = _candidate(self.name, seed, occupied, grid, f"{label}, {size} (fit {100 * residual:.1f} cm)")
            if found is not None:
                out.append(found)
        return out


class VisualHullProposer:
    """Space carving from every frame: a voxel stays where some frame's mask shows the object and no more than
    ``tolerance`` of the frames saw through it (background, or depth beyond it by more than ``margin``); a voxel
    hidden behind other objects in every frame is unknown and stays where the stage-1 shape has it. Within the
    stage-1 shape's extent grown by ``grow`` metres, above the support."""

    name = "visual_hull"

    def __init__(self, margin: float = 0.02, grow: float = 0.1, tolerance: float = 0.1) -> None:
        self.margin = float(margin)
        self.grow = float(grow)
        self.tolerance = float(tolerance)  # fraction of seeing frames allowed to see through (mask noise)

    def propose(self, evidence: ObjectEvidence, k: int, seed: int) -> list[Candidate]:
        if k < 1 or not evidence.frames:
            return []
        lo, hi = _stage1_bounds(evidence)
        lo, hi = lo - self.grow, hi + self.grow
        floor = _support_z(evidence)
        if floor is not None:
            lo[2] = max(lo[2], floor)
        grid = _grid(lo, hi, _voxel(evidence))
        local = grid.points().astype(np.float64)
        world = evidence.pose.apply(local)
        hits = np.zeros(len(world), np.int32)
        through = np.zeros(len(world), np.int32)
        seen = np.zeros(len(world), np.int32)
        hidden = np.zeros(len(world), np.int32)
        for frame in evidence.frames:
            row, col, z, valid = _project(frame, world)
            label = frame.labels[row, col]
            seen += valid
            hits += valid & (label == evidence.instance_id)
            free = valid & (label == 0)
            behind = valid & (label != 0) & (label != evidence.instance_id)
            if frame.depth is not None:
                d = frame.depth[row, col]
                measured = d > 0
                free = valid & np.where(measured, d > z + self.margin, label == 0)
                behind &= ~measured | (d < z - self.margin)
            through += free
            hidden += behind
        # a cell hidden behind other objects in every frame that could see it is unknown: it stays where the
        # stage-1 shape has it (a shelf's board under the book lying on it is never in the shelf's mask)
        unknown = (hits == 0) & (hidden == seen) & _stage1_inside(evidence, local)
        kept = ((hits > 0) | unknown) & (through <= self.tolerance * np.maximum(seen, 1))
        if floor is not None:
            kept &= local[:, 2] >= floor
        return [c for c in [_candidate(self.name, seed, kept, grid, "carved from every frame")] if c is not None][:k]


def _project(frame, world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # noqa: ANN001
    """:meth:`holousd.geometry.Views.project` of ``world`` points into one :class:`FrameEvidence`."""
    from holousd.geometry._grid import Views

    views = Views(intrinsics=frame.intrinsics[None], poses=frame.camera_to_world[None], labels=frame.labels[None])
    return views.project(0, np.asarray(world, np.float32))


def _load_model(path: Path, device: str):  # noqa: ANN202 - a callable torch module
    """A model saved with ``torch.export.save`` (a .pt2 program; its grid dimensions exported dynamic) or, for
    older models, ``torch.jit.save``."""
    import warnings

    import torch

    try:
        return torch.export.load(str(path)).module().to(device)
    except Exception:  # noqa: BLE001, S110 - not an exported program: perhaps TorchScript
        pass
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            return torch.jit.load(str(path), map_location=device).eval()
    except Exception as exc:  # noqa: BLE001 - a corrupt or foreign file: say so, one line
        raise HolousdError(f"{path}: not a saved model ({type(exc).__name__}); save it with torch.export.save "
                           "(or torch.jit.save)") from None  # fmt: skip


class LearnedProposer:
    """A learned completion prior (a multi-view diffusion or image-to-3D model distilled to a voxel completer)
    loaded from ``weights``, a file the user gives (``torch.export.save``, or TorchScript); never downloaded.

    The model takes a [1, 2, X, Y, Z] float tensor on the candidate grid (channel 0: the stage-1 occupancy;
    channel 1: the voxels holding observed surface points) and returns [1, 1, X, Y, Z] occupancy logits; the
    candidates are its occupancy at the thresholds 0.5, 0.35 and 0.65 (in that order, ``k`` of them)."""

    name = "learned"

    def __init__(self, weights: str | Path | None = None, device: str = "cpu", grow: float = 0.1) -> None:
        if weights is None:
            raise HolousdError("completion proposer 'learned' needs weights=PATH (a saved model file); holousd "
                               "never downloads a model")  # fmt: skip
        path = Path(weights)
        if not path.is_file():
            raise HolousdError(f"{path}: no such weights file; give the saved completion model (torch.export.save)")
        self.model = _load_model(path, device)
        self.device = device
        self.grow = float(grow)
        self.weights = path

    def propose(self, evidence: ObjectEvidence, k: int, seed: int) -> list[Candidate]:
        import torch

        if k < 1:
            return []
        lo, hi = _stage1_bounds(evidence)
        grid = _grid(lo - self.grow, hi + self.grow, _voxel(evidence))
        pts = grid.points().astype(np.float64)
        first = _stage1_inside(evidence, pts).reshape(grid.shape)
        observed = np.zeros(grid.shape, bool)
        if len(evidence.points):
            idx = np.rint((_local(evidence, evidence.points) - grid.origin) / grid.voxel_size).astype(np.int64)
            ok = np.all((idx >= 0) & (idx < np.asarray(grid.shape)), axis=1)
            observed[tuple(idx[ok].T)] = True
        x = torch.from_numpy(np.stack([first, observed]).astype(np.float32))[None].to(self.device)
        torch.manual_seed(seed)
        with torch.no_grad():
            logits = self.model(x)
        if tuple(logits.shape) != (1, 1, *grid.shape):
            raise HolousdError(f"{self.weights}: the model returned shape {tuple(logits.shape)}, expected "
                               f"{(1, 1, *grid.shape)} (occupancy logits on the input grid)")  # fmt: skip
        prob = torch.sigmoid(logits)[0, 0].cpu().numpy()
        out = []
        for threshold in (0.5, 0.35, 0.65)[:k]:
            found = _candidate(self.name, seed, prob > threshold, grid, f"{self.weights.name} at p > {threshold}")
            if found is not None:
                out.append(found)
        return out
