"""``holousd view``: the browser viewer and editor, on viser.

The page shows every node's Gaussian splats (or its coloured mesh), the object list and the support tree. Pick
an object (list or click on its mesh), move and turn it with the gizmo; "save edits" writes the moved poses as an
edit layer over the scene; "drop" and "push" run Newton from the edited state and play the motion as it is
computed (splats and meshes follow their objects); "save motion" writes it as a time-sampled layer.
"""

from __future__ import annotations

import threading
import time
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np

from holousd._errors import HolousdError
from holousd.usd import BACKGROUND, Pose

from ._session import Motion, ViewSession

__all__ = ["ViewServer"]

_SHOW = ("splats", "meshes", "both")


def _wxyz(pose: Pose) -> np.ndarray:
    x, y, z, w = pose.orientation
    return np.array([w, x, y, z])


def _from_wxyz(position: Any, wxyz: Any) -> Pose:
    w, x, y, z = (float(v) for v in wxyz)
    return Pose(translation=np.asarray(position, dtype=np.float64), orientation=np.array([x, y, z, w]))


class ViewServer:
    """A viser server showing one :class:`ViewSession`.

    Args:
        session: The scene being viewed and edited.
        host: Interface to listen on (``127.0.0.1``: this machine only).
        port: Port (0: any free one; see :attr:`port`).
        log: Receives one line per action.
    """

    def __init__(self, session: ViewSession, *, host: str = "127.0.0.1", port: int = 8080,
                 log: Callable[[str], None] | None = None) -> None:  # fmt: skip
        import viser

        self.session = session
        self._log = log or (lambda _line: None)
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.scene.set_up_direction("+z")
        eye, target = session.home_view()
        self.server.initial_camera.position = tuple(float(v) for v in eye)
        self.server.initial_camera.look_at = tuple(float(v) for v in target)
        self._lock = threading.Lock()  # one simulation at a time
        self._stop = threading.Event()
        self._frames: dict[str, Any] = {}
        self._splats: dict[str, Any] = {}
        self._meshes: dict[str, Any] = {}
        self.selected: str | None = None
        self._gizmo: Any = None
        self._build_scene()
        self._build_gui()

    @property
    def port(self) -> int:
        """The port the page is served on."""
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.port}"

    # ------------------------------------------------------------------ scene
    def _build_scene(self) -> None:
        import trimesh

        scene = self.server.scene
        for name, node in self.session.nodes.items():
            frame = scene.add_frame(f"/nodes/{name}", show_axes=False, position=node.pose.translation,
                                    wxyz=_wxyz(node.pose))  # fmt: skip
            self._frames[name] = frame
            if node.splats is not None:
                s = node.splats
                self._splats[name] = scene.add_gaussian_splats(
                    f"/nodes/{name}/splats", centers=s.centres, covariances=s.covariances, rgbs=s.rgb,
                    opacities=s.opacity,
                )  # fmt: skip
            if node.mesh is not None:
                tm = trimesh.Trimesh(node.mesh.points, node.mesh.faces, process=False)
                if node.mesh_rgb is not None:
                    rgba = np.concatenate([node.mesh_rgb, np.ones((len(node.mesh_rgb), 1))], axis=1)
                    tm.visual.vertex_colors = (255 * rgba).round().astype(np.uint8)
                handle = scene.add_mesh_trimesh(f"/nodes/{name}/mesh", tm, visible=node.splats is None)
                if name != BACKGROUND:
                    handle.on_click(lambda _event, n=name: self.select(n))
                self._meshes[name] = handle

    def _show_edited(self) -> None:
        self._place_all({name: node.pose for name, node in self.session.nodes.items()})

    def _place_all(self, poses: dict[str, Pose]) -> None:
        """Move nodes' frames (their splats and meshes follow) in one update of the page."""
        with self.server.atomic():
            for name, pose in poses.items():
                self._frames[name].position = pose.translation
                self._frames[name].wxyz = _wxyz(pose)

    def show(self, what: str) -> None:
        """Show ``splats``, ``meshes`` or ``both`` (a node without splats always shows its mesh)."""
        if what not in _SHOW:
            raise HolousdError(f"unknown display {what!r}; use one of {', '.join(_SHOW)}")
        for name, handle in self._meshes.items():
            handle.visible = what != "splats" or name not in self._splats
        for handle in self._splats.values():
            handle.visible = what != "meshes"

    # ------------------------------------------------------------------ gui
    def _build_gui(self) -> None:
        gui = self.server.gui
        objects = [n for n in self.session.nodes if n != BACKGROUND]
        gui.add_markdown(f"**{self.session.path.name}**: {len(objects)} objects")
        self._show = gui.add_dropdown("Show", _SHOW, initial_value="splats" if self._splats else "meshes")
        self._show.on_update(lambda _e: self.show(self._show.value))
        self.show(self._show.value)
        self._pick = gui.add_dropdown("Object", ("(none)", *objects), initial_value="(none)")
        self._pick.on_update(lambda _e: self.select(None if self._pick.value == "(none)" else self._pick.value))
        with gui.add_folder("Edit"):
            self._save = gui.add_button("Save edits")
            self._save.on_click(lambda _e: self._guarded(self.save))
            self._reset = gui.add_button("Reset object")
            self._reset.on_click(lambda _e: self._guarded(self.reset))
        with gui.add_folder("Physics"):
            self._drop = gui.add_button("Drop (gravity)")
            self._drop.on_click(lambda _e: self.start_simulation("drop"))
            self._push = gui.add_button("Push selected")
            self._push.on_click(lambda e: self.start_simulation("push", _view_direction(e)))
            self._stop_button = gui.add_button("Stop")
            self._stop_button.on_click(lambda _e: self._stop.set())
            self._replay = gui.add_button("Replay")
            self._replay.on_click(lambda _e: self._guarded(self.replay))
            self._keep = gui.add_button("Keep final poses")
            self._keep.on_click(lambda _e: self._guarded(self.keep))
            self._save_motion = gui.add_button("Save motion")
            self._save_motion.on_click(lambda _e: self._guarded(self.save_motion))
            self._progress = gui.add_progress_bar(0.0, animated=False)
        self._status = gui.add_markdown("Pick an object to move it.")
        with gui.add_folder("Support tree"):
            self._tree = gui.add_markdown(self._tree_text())

    def _tree_text(self) -> str:
        lines = self.session.tree_lines()
        return "```\n" + "\n".join(lines) + "\n```" if lines else "(no support relations)"

    def _say(self, line: str) -> None:
        self._status.content = line
        self._log(line)

    def _guarded(self, action: Callable[[], object]) -> None:
        """Run a button's action; while a simulation runs the scene is not edited (Stop first)."""
        if self._lock.locked():
            self._say("a simulation is running: wait for it or press Stop")
            return
        try:
            action()
        except HolousdError as exc:
            self._say(f"error: {exc}")
        except Exception as exc:  # noqa: BLE001 - the page must say something went wrong, not go quiet
            self._internal_error(exc)

    def _internal_error(self, exc: Exception, what: str = "") -> None:
        """An unexpected error: its traceback to the terminal, one line on the page."""
        self._log(traceback.format_exc())
        self._say(f"{what}internal error ({type(exc).__name__}: {exc}); the traceback is in the terminal")

    # ------------------------------------------------------------------ actions (also the Python API)
    def select(self, name: str | None) -> None:
        """Select an object: the gizmo appears at its origin (None: deselect)."""
        if self._gizmo is not None:
            self._gizmo.remove()
            self._gizmo = None
        self.selected = name
        if self._lock.locked():  # the motion streams on; no gizmo to move things with meanwhile
            return
        self._show_edited()  # back from a played motion to the edited poses
        if self._pick.value != (name or "(none)"):
            self._pick.value = name or "(none)"
        if name is None:
            return
        pose = self.session.nodes[name].pose
        gizmo = self.server.scene.add_transform_controls("/gizmo", scale=0.3, depth_test=False,
                                                         position=pose.translation, wxyz=_wxyz(pose))  # fmt: skip

        @gizmo.on_update
        def _(event: Any) -> None:
            self.move(name, _from_wxyz(event.target.position, event.target.wxyz))

        self._gizmo = gizmo
        node = self.session.nodes[name]
        self._say(f"{name}: on {node.parent or 'nothing'}, "
                  + (f"{node.mass_kg:.2f} kg" if node.mass_kg else "static"))  # fmt: skip

    def move(self, name: str, pose: Pose) -> None:
        """Move an object (as the gizmo does); not while a simulation runs."""
        if self._lock.locked():
            return
        self.session.move(name, pose)
        self._place_all({name: pose})

    def reset(self) -> None:
        """Put the selected object (none selected: every object) back where the scene had it."""
        self.session.reset(self.selected)
        self._show_edited()
        if self.selected is not None:
            self.select(self.selected)
        self._tree.content = self._tree_text()

    def save(self) -> None:
        path = self.session.save()
        self._tree.content = self._tree_text()
        self._say(f"saved {len(self.session.moved())} moved object(s) to {path.name}")

    def start_simulation(self, kind: str, direction: np.ndarray | None = None) -> threading.Thread | None:
        """Run a drop or a push in the background, streaming the motion to the page; None when one is running."""
        if not self._lock.acquire(blocking=False):
            self._say("a simulation is running: wait for it or press Stop")
            return None
        self._stop.clear()
        thread = threading.Thread(target=self._simulate, args=(kind, self.selected, direction), daemon=True)
        thread.start()
        return thread

    def _simulate(self, kind: str, selected: str | None, direction: np.ndarray | None) -> None:
        try:
            self._say(f"{kind}: building the model ...")
            if self._gizmo is not None:  # the object is about to move away from it
                self._gizmo.remove()
                self._gizmo = None

            def on_step(_t: float, poses: dict[str, Pose]) -> bool:
                self._place_all(poses)
                return self._stop.is_set()

            def progress(f: float) -> None:
                self._progress.value = 100.0 * f

            motion = self.session.simulate(kind, selected, direction, on_step=on_step, progress=progress)
            self._progress.value = 100.0
            self._say(_motion_text(motion) + ". Keep final poses to edit from there; pick an object to return to "
                      "the edited poses")
        except HolousdError as exc:
            self._show_edited()
            self._say(f"error: {exc}")
        except Exception as exc:  # noqa: BLE001 - a worker thread's error would otherwise leave the page waiting
            self._show_edited()
            self._internal_error(exc, f"{kind} failed: ")
        finally:
            self._lock.release()

    def replay(self, speed: float = 1.0) -> None:
        """Play the last motion again at ``speed`` times real time, then show the edited poses."""
        motion = self.session.motion
        if motion is None:
            raise HolousdError("nothing simulated yet: drop or push first")
        start = time.perf_counter()
        for k, t in enumerate(motion.times):
            if k % 16 and k != len(motion.times) - 1:
                continue
            delay = t / speed - (time.perf_counter() - start)
            if delay > 0:
                time.sleep(delay)
            self._place_all({name: poses[k] for name, poses in motion.poses.items()})

    def keep(self) -> None:
        """Take where the last motion left every object as the edited poses."""
        self.session.settle()
        self._show_edited()
        self._tree.content = self._tree_text()
        self._say(f"kept the final poses ({len(self.session.moved())} object(s) moved); save edits to write them")

    def save_motion(self) -> None:
        path = self.session.save_motion()
        self._say(f"saved the motion to {path.name} (holousd render plays it)")

    def close(self) -> None:
        self._stop.set()
        self.server.stop()


def _motion_text(motion: Motion) -> str:
    moved = {n: float(np.linalg.norm(p[-1].translation - p[0].translation)) for n, p in motion.poses.items()}
    far = max(moved, key=moved.__getitem__)
    dist = moved[far]
    what = f"push of {motion.pushed}" if motion.kind == "push" else "drop"
    return (f"{what}: {motion.times[-1]:.2f} s simulated{' (stopped)' if motion.stopped else ''}; "
            f"{far} moved furthest, {100 * dist:.1f} cm")  # fmt: skip


def _view_direction(event: Any) -> np.ndarray | None:
    """Horizontal direction the clicking client's camera looks along, or None."""
    client = getattr(event, "client", None)
    if client is None:
        return None
    camera = client.camera
    d = np.asarray(camera.look_at, dtype=np.float64) - np.asarray(camera.position, dtype=np.float64)
    d[2] = 0.0
    return d if np.linalg.norm(d) > 1e-6 else None
