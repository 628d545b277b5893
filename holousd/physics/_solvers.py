"""Solver registry: one stepping interface over Newton's XPBD and MuJoCo solvers.

``xpbd``: :class:`newton.solvers.SolverXPBD` with Newton's own collision pipeline (GJK/MPR on convex hulls,
triangle-mesh contacts for meshes). ``mujoco``: :class:`newton.solvers.SolverMuJoCo`, MuJoCo's C engine on CPU
(``use_mujoco_cpu``) or MuJoCo Warp on a GPU, with MuJoCo's *own* collision detection and soft-constraint
solver. Sharing nothing but the imported model, the two make an independent cross-check.
"""

from __future__ import annotations

import contextlib
import threading
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._errors import PhysicsInputError
from ._model import PhysicsModel

__all__ = ["SOLVERS", "SolverConfig", "Stepper", "make_stepper"]

SOLVERS = ("xpbd", "mujoco")
"""Solver names accepted everywhere a solver is chosen."""


@dataclass(kw_only=True)
class SolverConfig:
    """Which solver steps the model and its accuracy settings."""

    name: str = "xpbd"
    """Solver name, one of :data:`SOLVERS`."""
    iterations: int = 8
    """XPBD constraint iterations per step (MuJoCo uses its own defaults)."""
    mujoco_arena_mb: float = 256.0
    """MuJoCo (CPU): the arena that holds each step's contacts, constraints and solver scratch, MiB (allocated
    once). MuJoCo's own default, 13 MiB, holds some ten thousand contacts and their constraints; a scene of
    decomposed colliders makes more (the phone demo: 30-160 parts per object, 25 thousand contacts), MuJoCo then
    drops contacts every step ('Too many contacts') and bodies fall through what holds them (the phone demo's
    ball 78 cm through the cabinet's top: a verdict on the buffer, not on the scene). Contacts still dropped are
    reported (:attr:`Stepper.dropped_contacts`)."""
    mujoco_gap: float = 0.0
    """MuJoCo: every geom's contact ``gap``, metres. Newton hands MuJoCo its own broad-phase gap (Newton's
    ``ModelBuilder.rigid_gap``, 0.1 m) as the geoms' gap; MuJoCo 4.0's multi-point convex contacts (multiccd) then
    report penetrations where hulls only touch (a box's part flush with the shelf's 8.8 mm deep, pieces resting
    on a board 9-16 mm deep once they settle 0.5 mm) and throw what rests there: bench_00's box and book on its
    shelf tipped 17 and 82 degrees alone on the shelf, both stay within 1 mm and 1 degree at 0 (MuJoCo's own
    default, what a MuJoCo user loading the scene gets). XPBD keeps Newton's gap (its contact pipeline's)."""


class Stepper:
    """Advances a model one step at a time and exposes body poses and velocities as numpy arrays."""

    def __init__(self, pm: PhysicsModel, config: SolverConfig) -> None:
        """Create the solver, states and (for XPBD) the collision pipeline.

        Raises:
            PhysicsInputError: Unknown solver name.
        """
        import newton

        if config.name not in SOLVERS:
            raise PhysicsInputError(f"unknown solver {config.name!r}; choose one of {', '.join(SOLVERS)}")
        self.pm = pm
        self.name = config.name
        model = pm.model
        self._state_0 = model.state()
        self._state_1 = model.state()
        self._control = model.control()
        self._pipeline = None
        self._contacts = None
        self._arena_mb = config.mujoco_arena_mb
        self._fatal: tuple[type[BaseException], ...] = ()  # MuJoCo's FatalError, for MuJoCo (none catches nothing)
        self.contact_growths = 0
        """XPBD: times a step filled the contact buffer and it was doubled (see :meth:`step`); 0 for MuJoCo."""
        if config.name == "xpbd":
            restitution = any(m.restitution > 0.0 for m in pm.materials.values())
            self._solver = newton.solvers.SolverXPBD(
                model, iterations=config.iterations, enable_restitution=restitution
            )
            self._pipeline = newton.CollisionPipeline(model)
            self._contacts = self._pipeline.contacts()
        else:
            with warnings.catch_warnings():
                # Newton 1.8 pins mujoco ~=3.17 in metadata but runs with the installed 4.0; the warning is noise.
                warnings.filterwarnings("ignore", message="MuJoCo dependency version mismatch")
                # MuJoCo keeps its own solver iteration defaults; ``iterations`` is an XPBD setting.
                import mujoco

                self._fatal = (mujoco.FatalError,)
                with _arena(config.mujoco_arena_mb), _shape_gap(model, config.mujoco_gap):
                    self._solver = newton.solvers.SolverMuJoCo(
                        model, use_mujoco_cpu=pm.device == "cpu", enable_multiccd=True
                    )
        # Free-joint velocity slots of each body (MuJoCo integrates joint coordinates, not body twists).
        qd_start = model.joint_qd_start.numpy()
        child = model.joint_child.numpy()
        self._body_qd_start = np.full(model.body_count, -1, dtype=np.int64)
        for j in range(model.joint_count):
            self._body_qd_start[child[j]] = qd_start[j]

    @property
    def dropped_contacts(self) -> int:
        """Times MuJoCo (CPU) ran out of arena so far and dropped contacts or their constraints (each step it does
        counts; a constraint overflow drops every contact of that step); 0 for XPBD and MuJoCo Warp."""
        if self.name != "mujoco" or not getattr(self._solver, "use_mujoco_cpu", False):
            return 0
        import mujoco

        warning = self._solver.mj_data.warning
        return int(warning[int(mujoco.mjtWarning.mjWARN_CONTACTFULL)].number
                   + warning[int(mujoco.mjtWarning.mjWARN_CNSTRFULL)].number)  # fmt: skip

    @property
    def body_q(self) -> np.ndarray:
        """[B, 7] current body poses (px, py, pz, qx, qy, qz, qw), world frame, metres (a copy)."""
        return self._state_0.body_q.numpy().copy()

    @property
    def body_qd(self) -> np.ndarray:
        """[B, 6] current body twists (v_com m/s, omega rad/s), world frame (a copy)."""
        return self._state_0.body_qd.numpy().copy()

    def add_velocity(self, body: int, linear: np.ndarray, angular: np.ndarray | None = None) -> None:
        """Add a linear (m/s, at the centre of mass) and angular (rad/s) velocity to one body, world frame."""
        ang = np.zeros(3) if angular is None else np.asarray(angular, dtype=np.float64)
        delta = np.concatenate([np.asarray(linear, dtype=np.float64), ang])  # [6]
        qd = self._state_0.body_qd.numpy()
        qd[body] += delta
        self._write(self._state_0.body_qd, qd)
        if self.name == "mujoco":
            jqd = self._state_0.joint_qd.numpy()
            s = self._body_qd_start[body]
            jqd[s : s + 6] += delta  # free joint of a root body: parent frame = world, linear at the COM
            self._write(self._state_0.joint_qd, jqd)

    def scale_velocities(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """Multiply every body's linear / angular velocity by per-body factors ([B] each)."""
        if self.name == "xpbd":
            qd = self._state_0.body_qd.numpy()  # [B, 6] (v_com, omega), world
            qd[:, :3] *= linear[:, None]
            qd[:, 3:] *= angular[:, None]
            self._write(self._state_0.body_qd, qd)
        else:
            jqd = self._state_0.joint_qd.numpy()
            for b in np.flatnonzero((linear != 1.0) | (angular != 1.0)):
                s = self._body_qd_start[b]
                if s >= 0:
                    jqd[s : s + 3] *= linear[b]
                    jqd[s + 3 : s + 6] *= angular[b]
            self._write(self._state_0.joint_qd, jqd)

    def step(self, dt: float) -> None:
        """Advance by ``dt`` seconds (collision detection included).

        XPBD: Newton sizes its contact buffer from an estimate and drops the contacts past it, and a scene of
        decomposed colliders (a phone capture: 30-160 parts per object) finds more; what loses its contacts
        falls into what holds it and XPBD throws it out (hard/stack's phone capture: every body thrown tens of
        metres, 0% stable; 100% with the buffer large enough). When a step finds more contacts than the buffer
        holds, or fills it (the count stops at the buffer's size when the contacts it reduces overflow it), the
        buffer is doubled and the step's collision detection run again (``contact_growths``)."""
        self._state_0.clear_forces()
        if self._pipeline is not None:
            self._pipeline.collide(self._state_0, self._contacts)
            while int(self._contacts.rigid_contact_count.numpy()[0]) >= self._contacts.rigid_contact_max:
                import newton

                self._pipeline = newton.CollisionPipeline(self.pm.model,
                                                          rigid_contact_max=2 * self._contacts.rigid_contact_max)
                self._contacts = self._pipeline.contacts()
                self.contact_growths += 1
                self._pipeline.collide(self._state_0, self._contacts)
        try:
            self._solver.step(self._state_0, self._state_1, self._control, self._contacts, dt)
        except self._fatal as exc:  # MuJoCo's stack lives in its arena: too small a one ends the run
            raise PhysicsInputError(
                f"{self.pm.source}: MuJoCo ran out of its {self._arena_mb:g} MiB arena "
                f"({str(exc).splitlines()[0]}); raise SolverConfig.mujoco_arena_mb"
            ) from exc
        self._state_0, self._state_1 = self._state_1, self._state_0

    @staticmethod
    def _write(array: Any, values: np.ndarray) -> None:
        # On the CPU device .numpy() is a view, so in-place edits already landed; elsewhere copy back.
        if not array.device.is_cpu:
            array.assign(values)


_ARENA_LOCK = threading.Lock()


@contextlib.contextmanager
def _arena(mb: float) -> Iterator[None]:
    """MuJoCo models compiled within get an arena of ``mb`` MiB where their spec leaves it to MuJoCo (Newton
    builds and compiles the spec inside :class:`newton.solvers.SolverMuJoCo` and exposes no memory setting)."""
    import mujoco

    with _ARENA_LOCK:  # two threads building solvers at once must not keep each other's patch
        compile_ = mujoco.MjSpec.compile

        def compile_with_arena(spec, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
            if spec.memory == -1:
                spec.memory = int(mb * 1024 * 1024)
            return compile_(spec, *args, **kwargs)

        mujoco.MjSpec.compile = compile_with_arena
        try:
            yield
        finally:
            mujoco.MjSpec.compile = compile_


@contextlib.contextmanager
def _shape_gap(model: Any, gap: float) -> Iterator[None]:
    """Every shape of ``model`` has contact gap ``gap`` (metres) within; its own gaps again after (the MuJoCo solver
    reads them once, into its geoms, when it is built)."""
    saved = model.shape_gap.numpy().copy()
    model.shape_gap.fill_(gap)
    try:
        yield
    finally:
        model.shape_gap.assign(saved)


def make_stepper(pm: PhysicsModel, config: SolverConfig | None = None) -> Stepper:
    """Create a :class:`Stepper` for a built model."""
    return Stepper(pm, config or SolverConfig())
