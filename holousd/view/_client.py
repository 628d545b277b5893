"""A minimal client of the viewer's page, for its tests and ``holousd bench-view``: it speaks the page's websocket
protocol as the browser does (it sends msgpack messages; the server's frames are zstd-compressed msgpack followed by
raw binary buffers, which this client does not need)."""

from __future__ import annotations

import time
from collections.abc import Callable

import msgspec
import viser
import zstandard
from websockets.sync.client import connect

__all__ = ["PageClient"]


class PageClient:
    """Connects to the page at ``port`` on this machine and keeps every message the server sent."""

    def __init__(self, port: int) -> None:
        self.ws = connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"], max_size=None,
                          open_timeout=20)
        self.messages: list[dict] = []
        self._zstd = zstandard.ZstdDecompressor()

    def camera(self, position, look_at) -> None:
        """Report this client's camera (a page does so first; the server counts it as connected from then on)."""
        self.send("ViewerCameraMessage", wxyz=[1.0, 0.0, 0.0, 0.0], position=list(position), fov=1.0, near=0.01,
                  far=100.0, image_height=480, image_width=640, look_at=list(look_at), up_direction=[0.0, 0.0, 1.0])

    def receive(self, until: Callable[[list[dict]], object], timeout: float = 30.0) -> list[dict]:
        """Read messages until ``until(all messages so far)`` is true; TimeoutError after ``timeout`` s."""
        end = time.monotonic() + timeout
        while not until(self.messages):
            left = end - time.monotonic()
            if left <= 0:
                kinds = sorted({m["type"] for m in self.messages})
                raise TimeoutError(f"no such message in {timeout} s; got types {kinds}; status {self.status()}")
            try:
                raw = self.ws.recv(timeout=left)
            except TimeoutError:
                continue
            size = int.from_bytes(raw[:8], "little")
            comp = int.from_bytes(raw[8:16], "little")
            inner = msgspec.msgpack.decode(self._zstd.decompress(raw[16:16 + comp], max_output_size=size))
            self.messages.extend(inner["messages"])
        return self.messages

    def of_type(self, kind: str) -> list[dict]:
        return [m for m in self.messages if m["type"] == kind]

    def status(self) -> list[str]:
        """Every text the page's markdown elements were set to, in order."""
        return [m["updates"]["_markdown"] for m in self.of_type("GuiUpdateMessage") if "_markdown" in m["updates"]]

    def gui(self, kind: str, label: str) -> dict:
        return next(m for m in self.of_type(kind) if m["props"]["label"] == label)

    def choose(self, label: str, value: str) -> None:
        self.send("GuiUpdateMessage", uuid=self.gui("GuiDropdownMessage", label)["uuid"], updates={"value": value})

    def send(self, type_: str, **fields: object) -> None:
        self.ws.send(msgspec.msgpack.encode({"type": type_, **fields}))

    def click(self, label: str) -> None:
        uuid = self.gui("GuiButtonMessage", label)["uuid"]
        self.send("GuiUpdateMessage", uuid=uuid, updates={"value": True})

    def close(self) -> None:
        self.ws.close()
