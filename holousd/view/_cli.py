"""Sub-command of the view domain: ``holousd view``."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from holousd._argtypes import HelpFormatter

__all__ = ["add_commands"]


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register ``view`` and ``bench-view`` on the ``holousd`` parser."""
    view = subparsers.add_parser(
        "view",
        help="browser viewer and editor: splats or meshes, support tree, move objects, live physics",
        description="Serve the scene on a web page (viser): every node's Gaussian splats (or its coloured mesh), "
        "the object list and the support tree. Pick an object from the list or click its mesh, move and turn it "
        "with the gizmo; 'Save edits' writes the moved poses to an edit layer over the scene (the layers below "
        "stay byte-identical); 'Drop' and 'Push selected' simulate every rigid body with Newton from the edited "
        "state and play the motion as it is computed; 'Keep final poses' makes where things came to rest the "
        "edit; 'Save motion' writes the motion as a time-sampled layer that holousd render and USD viewers play. "
        "Needs viser (pip install -e '.[view]'). Stop with Ctrl-C.",
        formatter_class=HelpFormatter,
    )
    view.add_argument("scene", type=Path, metavar="SCENE", help="scene file (.usda/.usdc/.usd), or an edit layer")
    view.add_argument("--port", type=int, default=8080, help="port of the page (taken: the next free one)")
    view.add_argument("--host", default="127.0.0.1",
                      help="interface to listen on (0.0.0.0: reachable from other machines)")  # fmt: skip
    view.add_argument("--edit-layer", type=Path, default=None, metavar="FILE",
                      help="where 'Save edits' writes (default: SCENE_edit.usda beside the scene, or "
                      "SCENE_edit2.usda ... when taken); an existing file is replaced only if it is an edit layer "
                      "over SCENE")  # fmt: skip
    view.add_argument("--seconds", type=float, default=3.0, help="simulated time of a drop or push, s")
    view.add_argument("--solver", choices=("xpbd", "mujoco"), default="xpbd", help="solver of drop and push")
    view.add_argument("--hz", type=float, default=240.0,
                      help="simulation step rate, 1/s (960 is the stability verdict's XPBD rate, about 4x "
                      "slower)")  # fmt: skip
    view.add_argument("--push-speed", type=float, default=1.0,
                      help="speed given to a pushed object, m/s, along the camera's horizontal view "
                      "direction")  # fmt: skip
    view.add_argument("--serve-for", type=float, default=None, metavar="SECONDS",
                      help="stop after this many seconds (scripts, smoke tests); default: until Ctrl-C")  # fmt: skip
    view.set_defaults(handler=_view)

    bench = subparsers.add_parser(
        "bench-view",
        help="viewer benchmark: seconds until the page has the scene, and drop simulation speed",
        description="Start 'holousd view SCENE' in a new process, connect a page client and time the server's start, "
        "the first node's splats at the client and the whole page (every node and control; the target is 5 s), "
        "then simulate a drop of the scene and time it. Writes DIR/bench_view.json.",
        formatter_class=HelpFormatter,
    )
    bench.add_argument("scene", type=Path, metavar="SCENE", help="scene file (.usda/.usdc/.usd)")
    bench.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder for bench_view.json")
    bench.add_argument("--seconds", type=float, default=1.0, help="simulated time of the timed drop, s")
    bench.add_argument("--hz", type=float, default=240.0, help="simulation step rate of the timed drop, 1/s")
    bench.set_defaults(handler=_bench)


def _need_viser(command: str) -> None:
    from holousd._errors import HolousdError

    try:
        import viser  # noqa: F401
    except ImportError as exc:
        raise HolousdError(f"holousd {command} needs viser, which is not installed: pip install -e '.[view]' "
                           "(or pip install viser)") from exc  # fmt: skip


def _bench(args: argparse.Namespace) -> int:
    from holousd._errors import HolousdError

    _need_viser("bench-view")
    if min(args.seconds, args.hz) <= 0:
        raise HolousdError(f"--seconds ({args.seconds}) and --hz ({args.hz}) must be positive")
    from ._bench import bench_view

    path = bench_view(args.scene, args.out, seconds=args.seconds, hz=args.hz,
                      log=lambda line: print(f"bench-view: {line}", file=sys.stderr, flush=True))  # fmt: skip
    print(path.read_text())
    return 0


def _view(args: argparse.Namespace) -> int:
    from holousd._errors import HolousdError

    _need_viser("view")
    if min(args.seconds, args.push_speed, args.hz) <= 0:
        raise HolousdError(f"--seconds ({args.seconds}), --push-speed ({args.push_speed}) and --hz ({args.hz}) "
                           "must be positive")
    from . import ViewConfig, ViewServer, ViewSession

    start = time.perf_counter()

    def log(line: str) -> None:
        print(f"[view {time.perf_counter() - start:6.1f}s] {line}", file=sys.stderr, flush=True)

    config = ViewConfig(seconds=args.seconds, solver=args.solver, hz=args.hz, push_speed=args.push_speed,
                        edit_layer=args.edit_layer)  # fmt: skip
    session = ViewSession(args.scene, config, log=log)
    splats = sum(len(n.splats.centres) for n in session.nodes.values() if n.splats is not None)
    log(f"{args.scene}: {len(session.nodes)} nodes, {splats} splats")
    server = ViewServer(session, host=args.host, port=args.port, log=log)
    log(f"open {server.url} in a browser (Ctrl-C to stop)")
    try:
        deadline = None if args.serve_for is None else time.monotonic() + args.serve_for
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    unsaved = session.unsaved()
    if unsaved:
        log(f"not saved: the moves of {', '.join(unsaved)} (press 'Save edits' before stopping)")
    return 0
