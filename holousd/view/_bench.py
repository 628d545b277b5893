"""``holousd bench-view``: how soon the viewer's page has the scene, and how fast drop simulates, as JSON."""

from __future__ import annotations

import json
import os
import queue
import re
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from holousd._errors import HolousdError

__all__ = ["FIRST_FRAME_TARGET_S", "bench_view"]

FIRST_FRAME_TARGET_S = 5.0
"""The target: every node's splats at a client at most this long after ``holousd view`` starts, s."""
STARTUP_TIMEOUT_S = 120.0
"""How long ``holousd view`` may take to print its address before the benchmark gives up, s."""


def bench_view(scene: str | os.PathLike[str], out: str | os.PathLike[str], *, seconds: float = 1.0,
               hz: float = 240.0, log: Callable[[str], None] | None = None) -> Path:  # fmt: skip
    """Start ``holousd view SCENE`` as a user would (a new process), connect a page client, and time: the server
    ready (its URL printed), the first node's splats at the client, and the whole page (every node and control);
    then simulate a drop of the scene for ``seconds`` at ``hz`` and time it. Writes ``OUT/bench_view.json``.

    Returns:
        The JSON file written.
    """
    from holousd._atomic import atomic_path
    from holousd._tasks import machine_info

    from ._client import PageClient
    from ._session import ViewConfig, ViewSession

    say = log or (lambda _line: None)
    scene = Path(scene).absolute()
    out = Path(out)
    session = ViewSession(scene, ViewConfig(seconds=seconds, hz=hz))  # checks the scene before anything is timed
    with_splats = sum(n.splats is not None for n in session.nodes.values())
    say(f"{scene.name}: {len(session.nodes)} nodes, {with_splats} with splats; starting holousd view")
    start = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", "holousd.cli", "view", str(scene), "--port", "0",
                                "--serve-for", "300"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                               text=True)  # fmt: skip
    lines: queue.Queue[str | None] = queue.Queue()

    def drain() -> None:  # all of the child's stderr, so that it never blocks on a full pipe
        for line in process.stderr:  # type: ignore[union-attr]
            lines.put(line)
        lines.put(None)

    threading.Thread(target=drain, daemon=True).start()
    try:
        port, said = None, []
        deadline = time.perf_counter() + STARTUP_TIMEOUT_S
        while port is None and time.perf_counter() < deadline:
            try:
                line = lines.get(timeout=max(0.0, deadline - time.perf_counter()))
            except queue.Empty:
                break
            if line is None:
                raise HolousdError(f"{scene}: holousd view stopped before serving the page (exit {process.wait()}): "
                                   + " / ".join(said[-3:]))  # fmt: skip
            said.append(line.strip())
            found = re.search(r"open http://[^:\s]+:(\d+)", line)
            port = int(found.group(1)) if found else None
        if port is None:
            raise HolousdError(f"{scene}: holousd view printed no address within {STARTUP_TIMEOUT_S:.0f} s; run "
                               f"'holousd view {scene}' to see why")  # fmt: skip
        ready = time.perf_counter() - start
        client = PageClient(port)
        client.camera([3.0, 0.0, 1.5], [0.0, 0.0, 0.5])
        first: float | None = None

        def seen(messages: list[dict[str, Any]]) -> bool:
            nonlocal first
            if first is None and any(m["type"] == "GaussianSplatsMessage" for m in messages):
                first = time.perf_counter() - start
            splats = sum(m["type"] == "GaussianSplatsMessage" for m in messages)
            return splats >= with_splats and any(m["type"] == "GuiButtonMessage" and m["props"]["label"] ==
                                                 "Save motion" for m in messages)  # fmt: skip

        client.receive(seen, timeout=120.0)
        complete = time.perf_counter() - start
        client.close()
    finally:
        process.terminate()
        process.wait(timeout=30)
    splats_text = f"first splats {first:.2f} s" if first is not None else "no splats"
    say(f"page: server ready {ready:.2f} s, {splats_text}, whole page {complete:.2f} s")
    t0 = time.perf_counter()
    motion = session.simulate("drop")
    wall = time.perf_counter() - t0
    simulated = float(motion.times[-1])
    moved = max((float(((p[-1].translation - p[0].translation) ** 2).sum() ** 0.5) for p in motion.poses.values()),
                default=0.0)  # fmt: skip
    say(f"drop: {simulated:.2f} s simulated in {wall:.1f} s ({wall / simulated:.1f} s per simulated second)")
    result = {
        "command": " ".join(["holousd", "bench-view", str(scene), "--out", str(out), "--seconds", f"{seconds:g}",
                             "--hz", f"{hz:g}"]),
        "date": time.strftime("%Y-%m-%d", time.gmtime()), "machine": machine_info(), "scene": str(scene),
        "nodes": len(session.nodes), "nodes_with_splats": with_splats,
        "splats": sum(len(n.splats.centres) for n in session.nodes.values() if n.splats is not None),
        "server_ready_s": ready, "first_splats_s": first, "page_complete_s": complete,
        "first_frame_target_s": FIRST_FRAME_TARGET_S, "first_frame_target_met": complete <= FIRST_FRAME_TARGET_S,
        "drop": {"hz": hz, "simulated_s": simulated, "wall_s": wall, "wall_per_simulated_s": wall / simulated,
                 "objects": len(motion.poses), "furthest_moved_cm": 100.0 * moved},
    }  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    target = out / "bench_view.json"
    with atomic_path(target) as tmp:
        Path(tmp).write_text(json.dumps(result, indent=2) + "\n")
    return target
