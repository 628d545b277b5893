"""Bad input never costs the user data and never prints a traceback.

A corpus of damaged captures, scene files and command lines, made from one small synth capture. Every case runs
the real command (``holousd.cli.main``) against an output folder that already holds a valid earlier result, and
asserts exit code 2, one error line that names the file (or option) and the fix, no traceback, and an output
folder that is byte-for-byte what it was. Then what is not an error: depth pixels without a measurement are
ignored with a warning, a capture whose depth holds none is fitted from its masks, and a stage that fails
mid-run puts the output folder back.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from holousd.cli import main
from holousd.stages import _pipeline
from holousd.stages._pipeline import preset, reconstruct
from holousd.synth import SynthConfig, generate_suite

FRAMES, SIZE = 8, 48


def _tiny() -> _pipeline.PipelineConfig:
    cfg = preset("fast", progress=False, threads=1)
    return replace(cfg, fit=replace(cfg.fit, iterations=0, render_frames=4, fusion_frames=4),
                   appearance=replace(cfg.appearance, iterations=2, frames=2))  # fmt: skip


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth")
    generate_suite("demo", out, SynthConfig(frames=FRAMES, width=SIZE, height=SIZE, progress=False))
    shutil.rmtree(out / "demo" / "gt")  # a capture as a user has it
    return out / "demo"


@pytest.fixture(scope="module")
def previous(capture: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A valid earlier result in the output folder: the observe layer and scene.usda of the clean capture."""
    out = tmp_path_factory.mktemp("previous") / "recon"
    reconstruct(capture, out, _tiny(), until="observe", log=lambda _: None)
    (out / "notes.txt").write_text("the user's own file\n")
    return out


def _snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every file's bytes and every folder (None) under ``folder``."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() if p.is_file() else None for p in folder.rglob("*")}


# ----------------------------------------------------------------------------------------------- mutations
def _manifest(cap: Path) -> dict:
    return json.loads((cap / "observations.json").read_text())


def _write_manifest(cap: Path, data: dict) -> None:
    (cap / "observations.json").write_text(json.dumps(data))


def _edit_manifest(edit: Callable[[dict], None]) -> Callable[[Path], None]:
    def apply(cap: Path) -> None:
        data = _manifest(cap)
        edit(data)
        _write_manifest(cap, data)

    return apply


def _edit_pose(frame: int, edit: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def apply(data: dict) -> None:
        pose = np.array(data["frames"][frame]["camera_to_world"], dtype=float)
        data["frames"][frame]["camera_to_world"] = edit(pose).tolist()

    return _edit_manifest(apply)


def _edit_intrinsics(edit: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def apply(data: dict) -> None:
        data["intrinsics"] = edit(np.array(data["intrinsics"], dtype=float)).tolist()

    return _edit_manifest(apply)


def _file(cap: Path, channel: str, frame: int = 3) -> Path:
    return cap / _manifest(cap)["frames"][frame][channel]


def _delete(channel: str) -> Callable[[Path], None]:
    return lambda cap: _file(cap, channel).unlink()


def _garbage(channel: str) -> Callable[[Path], None]:
    return lambda cap: _file(cap, channel).write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 3)


def _truncate(channel: str) -> Callable[[Path], None]:
    def apply(cap: Path) -> None:
        path = _file(cap, channel)
        path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])

    return apply


def _image(channel: str, make: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def apply(cap: Path) -> None:
        path = _file(cap, channel)
        Image.fromarray(make(np.asarray(Image.open(path)))).save(path)

    return apply


def _mask_edit(edit: Callable[[np.ndarray, int], np.ndarray], frames: range | None = None) -> Callable[[Path], None]:
    def apply(cap: Path) -> None:
        for i in frames if frames is not None else range(FRAMES):
            path = _file(cap, "mask", i)
            mask = np.asarray(Image.open(path)).astype(np.int32)
            Image.fromarray(edit(mask, i).astype(np.uint16)).save(path)

    return apply


def _npy_depth(values: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    """Depth as float32 .npy files (metres), transformed by ``values``."""

    def apply(cap: Path) -> None:
        data = _manifest(cap)
        for i, frame in enumerate(data["frames"]):
            png = cap / frame["depth"]
            depth = np.asarray(Image.open(png)).astype(np.float32) / 1000.0
            npy = png.with_suffix(".npy")
            np.save(npy, values(depth) if i == 3 else depth)
            png.unlink()
            frame["depth"] = npy.relative_to(cap).as_posix()
        _write_manifest(cap, data)

    return apply


def _drop_key(key: str, frame: int | None = None) -> Callable[[Path], None]:
    def apply(data: dict) -> None:
        for i, entry in enumerate(data["frames"]):
            if frame is None or i == frame:
                entry.pop(key, None)

    return _edit_manifest(apply)


def _as_format(fmt: str, then: Callable[[Path], None]) -> Callable[[Path], Path]:
    """Rewrite the capture in another layout (into a sibling folder), then damage it; returns the new folder."""

    def apply(cap: Path) -> Path:
        from holousd.io import load, write

        dest = cap.parent / f"{cap.name}_{fmt}"
        write(load(cap), dest, format=fmt)
        then(dest)
        return dest

    return apply


def _nerfstudio_nan(cap: Path) -> None:
    data = json.loads((cap / "transforms.json").read_text())
    data["frames"][2]["transform_matrix"][0][3] = float("nan")
    (cap / "transforms.json").write_text(json.dumps(data))


def _bare_video(cap: Path) -> Path:
    folder = cap.parent / "video_only"
    folder.mkdir()
    (folder / "room.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(64))
    return folder / "room.mp4"


@dataclass(frozen=True)
class Case:
    """One damaged capture and what the one-line error must say."""

    name: str
    damage: Callable[[Path], Path | None]
    expect: tuple[str, ...]
    """Substrings of the error line (the file it names, what is wrong, the fix)."""


def _pose(m: list[list[float]]) -> Callable[[np.ndarray], np.ndarray]:
    return lambda pose: pose @ np.array(m, dtype=float)


CAPTURE_CASES = [
    Case("rgb missing", _delete("rgb"), ("rgb/000003.png", "missing", "restore it")),
    Case("rgb corrupt", _garbage("rgb"), ("rgb/000003.png", "cannot be decoded", "corrupt")),
    Case("rgb truncated", _truncate("rgb"), ("rgb/000003.png", "cannot be decoded")),
    Case("rgb wrong size", _image("rgb", lambda a: a[:20, :30]), ("rgb/000003.png", "30x20", "resize")),
    Case("rgb one colour", _image("rgb", lambda a: np.zeros_like(a)), ("rgb/000003.png", "empty frame")),
    Case("mask missing", _delete("mask"), ("masks/000003.png", "missing")),
    Case("mask corrupt", _garbage("mask"), ("masks/000003.png", "cannot be decoded")),
    Case("mask wrong size", _mask_edit(lambda m, i: m[:, :-4], range(3, 4)), ("masks/000003.png", "same size")),
    Case("mask is colour", _image("mask", lambda a: np.stack([a.astype(np.uint8)] * 3, -1)),
         ("masks/000003.png", "single-channel")),
    Case("mask id not declared",
         _mask_edit(lambda m, i: np.where(np.arange(m.size).reshape(m.shape) < 400, 77, m) if i == 5 else m),
         ("masks/000005.png", "instance id 77", "400 pixels", "instance list")),
    Case("declared id never seen", _mask_edit(lambda m, i: np.where(m == 3, 0, m)), ("[3]", "mug_1", "never appear")),
    Case("depth wrong shape", _image("depth", lambda a: a[:, :-8]), ("depth/000003.png", "depth has shape")),
    Case("depth corrupt", _garbage("depth"), ("depth/000003.png", "cannot be decoded")),
    Case("depth missing", _delete("depth"), ("depth/000003.png", "missing")),
    Case("depth 8-bit colour", _image("depth", lambda a: np.stack([(a % 256).astype(np.uint8)] * 3, -1)),
         ("depth/000003.png", "16-bit")),
    Case("depth negative", _npy_depth(lambda d: -d), ("depth/000003.npy", "negative", "flip its sign")),
    Case("depth npy corrupt", lambda cap: (_npy_depth(lambda d: d)(cap), _file(cap, "depth").write_bytes(b"xx")),
         ("depth/000003.npy", "cannot be read")),
    Case("depth npy of strings", _npy_depth(lambda d: np.full(d.shape, "a")), ("depth/000003.npy", "dtype")),
    Case("normals wrong shape", _image("normal", lambda a: a[:-6]), ("normals/000003.png", "normals have shape")),
    Case("normals corrupt", _garbage("normal"), ("normals/000003.png", "cannot be decoded")),
    Case("manifest truncated", lambda cap: (cap / "observations.json").write_text('{"format": "holousd-obs'),
         ("observations.json", "not valid JSON")),
    Case("manifest not an object", lambda cap: (cap / "observations.json").write_text("[1, 2]"),
         ("observations.json", "JSON object")),
    Case("manifest wrong format", _edit_manifest(lambda d: d.update(format="other")),
         ("observations.json", "'format'")),
    Case("manifest from the future", _edit_manifest(lambda d: d.update(version=99)),
         ("observations.json", "version 99", "upgrade holousd")),
    Case("manifest without width", _edit_manifest(lambda d: d.pop("width")), ("observations.json", "'width'")),
    Case("manifest without frames", _edit_manifest(lambda d: d.update(frames=[])), ("observations.json", "no frames")),
    Case("frame without pose", _drop_key("camera_to_world", 4), ("observations.json", "frames[4]", "camera_to_world")),
    Case("pose NaN", _edit_pose(6, lambda p: np.where(np.eye(4) > 0, np.nan, p)),
         ("observations.json", "frame 6", "'000006'", "NaN")),
    Case("pose scaled", _edit_pose(2, _pose([[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]])),
         ("observations.json", "frame 2", "not rigid", "orthonormal")),
    Case("pose mirrored", _edit_pose(2, _pose([[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])),
         ("frame 2", "determinant", "right-handed")),
    Case("pose last row", _edit_pose(1, lambda p: p + np.array([[0] * 4] * 3 + [[0, 0, 1, 0]])),
         ("frame 1", "last row")),
    Case("pose 3x4", _edit_pose(1, lambda p: p[:3]), ("frames[1]", "shape [3, 4]", "[4, 4]")),
    Case("intrinsics negative focal", _edit_intrinsics(lambda k: k * [[-1], [1], [1]]), ("focal", "positive")),
    Case("intrinsics other resolution", _edit_intrinsics(lambda k: k * [[4], [4], [1]]), ("principal point",)),
    Case("intrinsics NaN", _edit_intrinsics(lambda k: k * np.nan), ("intrinsics", "NaN")),
    Case("duplicate frame ids", _edit_manifest(lambda d: d["frames"][1].update(id=d["frames"][0]["id"])),
         ("duplicate frame ids",)),
    Case("depth without its manifest entry", _edit_manifest(lambda d: d.pop("depth")),
         ("observations.json", "'depth'")),
    Case("one frame without a mask", _drop_key("mask", 5), ("observations.json", "7 of 8", "'mask'")),
    Case("no masks", _drop_key("mask"), ("no instance masks", "masks/")),
    Case("masks only background", _mask_edit(lambda m, i: np.zeros_like(m)), ("never appear",)),
    Case("input missing", lambda cap: cap.parent / "no_such_capture", ("no_such_capture", "no such folder")),
    Case("input not a capture", lambda cap: (cap.parent / "empty").mkdir() or cap.parent / "empty",
         ("empty", "not a capture", "FORMAT.md")),
    Case("video without side files", _bare_video, ("room.mp4", "cameras.json", "FORMAT.md")),
    Case("nerfstudio pose NaN", _as_format("nerfstudio", _nerfstudio_nan), ("transforms.json", "frame 2", "NaN")),
    Case("nerfstudio truncated", _as_format("nerfstudio", lambda d: (d / "transforms.json").write_text('{"fr')),
         ("transforms.json", "not valid JSON")),
    Case("monosdf cameras corrupt", _as_format("monosdf", lambda d: (d / "cameras.npz").write_bytes(b"PK\x03\x04")),
         ("cameras.npz",)),
]


def _run(argv: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _error_line(err: str, command: str) -> str:
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.startswith(f"holousd {command}: error: ")]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("case", CAPTURE_CASES, ids=[c.name for c in CAPTURE_CASES])
def test_damaged_capture_is_refused_and_output_kept(case: Case, capture: Path, previous: Path, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture) -> None:  # fmt: skip
    cap = tmp_path / "capture"
    shutil.copytree(capture, cap)
    damaged = case.damage(cap)
    source = damaged if isinstance(damaged, Path) else cap
    out = tmp_path / "recon"
    shutil.copytree(previous, out)
    before = _snapshot(out)
    code, _, err = _run(["reconstruct", str(source), "--out", str(out), "--preset", "fast", "--no-progress"], capsys)
    line = _error_line(err, "reconstruct")
    assert code == 2, err
    for text in case.expect:
        assert text in line, (text, line)
    assert "pxrInternal" not in line and "Error in '" not in line
    assert _snapshot(out) == before


# ----------------------------------------------------------------------------------------------- output paths
def _readonly(folder: Path) -> Callable[[], None]:
    """Make ``folder`` unwritable, also for root (the immutable attribute); returns the undo."""
    import os

    if os.geteuid() != 0:
        folder.chmod(0o555)
        return lambda: folder.chmod(0o755)
    if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(folder)]).returncode != 0:
        pytest.skip("running as root on a file system without chattr +i: no way to make a folder read-only")
    return lambda: subprocess.run(["chattr", "-i", str(folder)], check=True)


OUT_COMMANDS = {
    "reconstruct": lambda cap, out: ["reconstruct", str(cap), "--out", str(out), "--preset", "fast"],
    "fit": lambda cap, out: ["fit", str(cap), "--out", str(out), "--preset", "fast"],
    "synth": lambda cap, out: ["synth", "--suite", "demo", "--out", str(out), "--frames", "2",
                               "--resolution", "16x16"],  # fmt: skip
    "example": lambda cap, out: ["example", str(out)],
    "demo": lambda cap, out: ["demo", "--out", str(out)],
    "export": lambda cap, out: ["export", str(cap.parent / "example" / "scene.usda"), "--sim", str(out / "sim.usda")],
    "render": lambda cap, out: ["render", str(cap.parent / "example" / "scene.usda"), "--out", str(out)],
    "simulate": lambda cap, out: ["simulate", str(cap.parent / "example" / "scene.usda"), "--seconds", "0.1",
                                  "--out", str(out / "motion.usda")],  # fmt: skip
    "bench-physics": lambda cap, out: ["bench-physics", "--out", str(out)],
}
_FILE_OUTPUT = {"export", "simulate"}
"""Commands whose output path above is a file inside ``out``."""


@pytest.fixture()
def example_beside(capture: Path, example_dir: Path, tmp_path: Path) -> Path:
    """The clean capture beside a copy of the example scene (tmp/capture, tmp/example)."""
    cap = tmp_path / "capture"
    shutil.copytree(capture, cap)
    shutil.copytree(example_dir, tmp_path / "example")
    return cap


@pytest.mark.parametrize("command", list(OUT_COMMANDS))
@pytest.mark.parametrize("problem", ["existing file", "under a file", "read-only"])
def test_bad_output_path_is_refused(command: str, problem: str, example_beside: Path, tmp_path: Path,
                                    capsys: pytest.CaptureFixture) -> None:  # fmt: skip
    blocker = tmp_path / "blocker"
    if problem == "existing file":  # a file where the output folder goes; for a file output: a folder
        if command in _FILE_OUTPUT:
            (blocker / ("sim.usda" if command == "export" else "motion.usda")).mkdir(parents=True)
        else:
            blocker.write_text("keep me\n")
        out = blocker
    elif problem == "under a file":
        blocker.write_text("keep me\n")
        out = blocker / "sub"
    else:
        blocker.mkdir()
        (blocker / "keep.txt").write_text("keep me\n")
        out = blocker / "recon" if command in ("reconstruct", "fit", "export", "simulate") else blocker
    def state() -> dict[str, bytes | None]:
        return _snapshot(tmp_path / "example") | ({"blocker": blocker.read_bytes()} if blocker.is_file()
                                                  else _snapshot(blocker))  # fmt: skip

    before = state()
    undo = _readonly(blocker) if problem == "read-only" else (lambda: None)
    try:
        code, _, err = _run(OUT_COMMANDS[command](example_beside, out), capsys)
    finally:
        undo()
    line = _error_line(err, command)
    assert code == 2, err
    assert str(blocker) in line
    fixes = {"existing file": ("is an existing folder; give a file name" if command in _FILE_OUTPUT
                               else "is an existing file; give a folder",),
             "under a file": ("is a file, not a folder",),
             "read-only": ("not permitted", "permission denied", "read-only")}  # root / user / file system
    assert any(f in line for f in fixes[problem]), line
    assert state() == before
    if problem == "read-only":
        assert sorted(p.name for p in blocker.iterdir()) == ["keep.txt"]


def test_transaction_puts_back_files_links_and_folders(tmp_path: Path) -> None:
    import os

    from holousd._atomic import atomic_path, folder_transaction

    out = tmp_path / "out"
    (out / "assets" / "10_fit").mkdir(parents=True)
    (out / "00_observe.usda").write_text("observe\n")
    (out / "real.usda").write_text("real\n")
    (out / "scene.usda").symlink_to("real.usda")
    (out / "assets" / "10_fit" / "a.npz").write_bytes(b"grid")
    (out / "report.txt").write_text("not ours\n")
    before = _snapshot(out)
    with pytest.raises(RuntimeError, match="late"):
        with folder_transaction(out, _pipeline.OUTPUT_PATTERNS):
            with atomic_path(out / "scene.usda") as tmp:  # replaces the link by a file
                tmp.write_text("new scene\n")
            (out / "00_observe.usda").write_text("changed in place\n")
            (out / "10_fit.usda").write_text("new layer\n")
            (out / "assets" / "10_fit" / "a.npz").unlink()
            (out / "assets" / "20_physics").mkdir()
            (out / "assets" / "20_physics" / "b.usdc").write_bytes(b"parts")
            (out / "report.txt").write_text("the user's, changed\n")
            raise RuntimeError("a stage failed late")
    after = _snapshot(out)
    assert after.pop("report.txt") == b"the user's, changed\n"  # outside the patterns: not ours to undo
    before.pop("report.txt")
    assert after == before and os.readlink(out / "scene.usda") == "real.usda"
    assert not [p for p in out.iterdir() if p.name.startswith(".holousd")]


def test_usdz_package_opens(example_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    package = tmp_path / "scene.usdz"
    assert _run(["export", str(example_dir / "scene.usda"), "--usdz", str(package)], capsys)[0] == 0
    code, out, err = _run(["info", str(package)], capsys)
    assert code == 0 and "5 nodes" in out, err


@pytest.mark.parametrize("argv, expect", [
    (["reconstruct", "cap", "--out", "o", "--preset", "quick"], "argument --preset: invalid choice: 'quick'"),
    (["reconstruct", "cap", "--out", "o", "--until", "never"], "argument --until: invalid choice: 'never'"),
    (["reconstruct", "cap"], "the following arguments are required: --out"),
    (["reconstruct", "cap", "--out", "o", "--threads", "0"], "argument --threads: expected a positive number"),
    (["synth", "--suite", "demo", "--out", "o", "--resolution", "big"], "argument --resolution"),
    (["bench", "--suite", "nope"], "argument --suite: invalid choice"),
    (["stability", "s.usda", "--seconds"], "argument --seconds: expected one argument"),
    (["nosuchcommand"], "argument COMMAND: invalid choice: 'nosuchcommand'"),
])  # fmt: skip
def test_command_line_misuse_is_one_line(argv: list[str], expect: str, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expect in err and "--help" in err, err


# ----------------------------------------------------------------------------------------------- scene files
def _scene_with(example_dir: Path, tmp_path: Path, edit: Callable[..., None]) -> Path:
    from holousd.usd import SceneGraph

    folder = tmp_path / "scene"
    shutil.copytree(example_dir, folder)
    scene = SceneGraph.open(folder / "scene.usda")
    edit(scene)
    scene.save()
    return folder / "scene.usda"


def _cycle(scene) -> None:  # noqa: ANN001
    scene.set_support("table", "mug")


def _dangling(scene) -> None:  # noqa: ANN001
    scene.stage.GetPrimAtPath("/World/Objects/box").GetRelationship("holo:beside").SetTargets(["/World/Objects/gone"])


def _massless(scene) -> None:  # noqa: ANN001
    from pxr import UsdPhysics

    UsdPhysics.MassAPI(scene.stage.GetPrimAtPath("/World/Objects/box")).GetMassAttr().Clear()
    scene.stage.GetPrimAtPath("/World/Objects/box").RemoveAPI(UsdPhysics.MassAPI)


@pytest.mark.parametrize("edit, expect", [(_cycle, "cycle"), (_dangling, "/World/Objects/gone"),
                                          (_massless, "/World/Objects/box")], ids=["cycle", "dangling", "massless"])
def test_export_of_a_broken_physics_scene_is_refused_unless_forced(edit: Callable, expect: str, example_dir: Path,
                                                                   tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture) -> None:  # fmt: skip
    scene = _scene_with(example_dir, tmp_path, edit)
    sim = tmp_path / "sim.usda"
    sim.write_text("#usda 1.0\n")  # an earlier export
    code, _, err = _run(["export", str(scene), "--sim", str(sim)], capsys)
    line = _error_line(err, "export")
    assert code == 2 and expect in line and "--force" in line, line
    assert sim.read_text() == "#usda 1.0\n"
    code, out, _ = _run(["export", str(scene), "--sim", str(sim), "--force"], capsys)
    assert code == 0 and f"wrote {sim}" in out and sim.read_text() != "#usda 1.0\n"


def test_info_says_a_body_without_mass_is_not_static(example_dir: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:  # fmt: skip
    scene = _scene_with(example_dir, tmp_path, _massless)
    code, out, err = _run(["info", str(scene)], capsys)
    assert code == 0
    row = next(line for line in out.splitlines() if line.startswith("box "))
    assert "unset!" in row and "static" not in row
    assert "static" in next(line for line in out.splitlines() if line.startswith("background "))
    assert "box: rigid body without an authored mass" in err
    _, out, _ = _run(["info", str(scene), "--json"], capsys)
    box = next(n for n in json.loads(out)["nodes"] if n["name"] == "box")
    assert box["dynamic"] is True and box["mass_kg"] is None


_CORRUPT = {
    "usda syntax": ("scene.usda", b'#usda 1.0\n(\n  upAxis = "Z"\n)\ndef Xform "World" {\n  double3 a = (1, 2\n'),
    "usda not usd": ("scene.usda", b"hello\n"),
    "usdc garbage": ("scene.usdc", b"PXR-USDC" + bytes(range(200))),
    "missing": ("gone.usda", None),
    "wrong extension": ("scene.txt", b"#usda 1.0\n"),
    "newer schema": ("scene.usda", b'#usda 1.0\n(\n  customLayerData = {\n    dictionary holousd = {\n'
                                   b'      int schemaVersion = 99\n    }\n  }\n)\n'),
}


@pytest.mark.filterwarnings("ignore:.*metersPerUnit is not authored")
@pytest.mark.parametrize("command", ["info", "validate", "export", "stability", "render"])
@pytest.mark.parametrize("kind", list(_CORRUPT))
def test_unreadable_scene_file_is_one_plain_line(command: str, kind: str, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture) -> None:  # fmt: skip
    name, data = _CORRUPT[kind]
    path = tmp_path / name
    if data is not None:
        path.write_bytes(data)
    out = tmp_path / "out"
    out.mkdir()
    (out / "sim.usda").write_text("#usda 1.0\n")
    argv = {"info": ["info", str(path)], "validate": ["validate", str(path)],
            "export": ["export", str(path), "--sim", str(out / "sim.usda")],
            "stability": ["stability", str(path), "--json"],
            "render": ["render", str(path), "--out", str(out)]}[command]  # fmt: skip
    before = _snapshot(out)
    code, stdout, err = _run(argv, capsys)
    line = _error_line(err, command)
    assert code == 2, err
    assert name in line and "pxrInternal" not in line and "Error in '" not in line and ".cpp" not in line, line
    expect = {"usda syntax": "syntax error at line 7", "usda not usd": "not a valid usda", "usdc garbage": "corrupt",
              "missing": "no such file", "wrong extension": "not a USD file", "newer schema": "schema version 99"}
    if not (command == "stability" and kind == "newer schema"):  # the physics reader does not need our schema
        assert expect[kind] in line, line
    assert _snapshot(out) == before and stdout == ""


def test_eval_of_a_missing_reconstruction(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code, _, err = _run(["eval", str(tmp_path / "nothing"), "--gt", str(tmp_path)], capsys)
    assert code == 2 and "nothing" in _error_line(err, "eval")


# ----------------------------------------------------------------------------------------------- not errors
def test_invalid_depth_pixels_are_counted_and_ignored(capture: Path, tmp_path: Path) -> None:
    from holousd.io import load

    cap = tmp_path / "capture"
    shutil.copytree(capture, cap)
    depth = {}

    def far_and_nan(d: np.ndarray) -> np.ndarray:
        d = d.copy()
        d[:10] = 10.0  # the renderer's far plane where nothing was hit
        d[10:12, :5] = np.nan
        depth["far"], depth["nan"] = int(d[:10].size), 10
        return d

    _npy_depth(far_and_nan)(cap)
    obs = load(cap)
    check = obs.validate()
    assert check.far_plane_m == pytest.approx(10.0) and check.far_plane_depth == depth["far"]
    assert check.nonfinite_depth == depth["nan"] and check.valid_depth > 0
    (warning,) = check.warnings
    assert f"{depth['far']} at the far plane (10 m" in warning and "10 NaN" in warning
    clean = obs.with_valid_depth(check).depth(3)
    assert np.all(clean[:10] == 0) and np.all(clean[10:12, :5] == 0) and np.isfinite(clean).all()
    assert np.array_equal(clean[12:], np.load(cap / "depth" / "000003.npy")[12:])
    # a far wall at one depth is not a far plane: nothing stands apart from it
    np.save(cap / "depth" / "000003.npy", np.full((SIZE, SIZE), 4.2, np.float32))
    assert load(cap).validate().far_plane_m is None


def test_far_plane_builds_no_phantom_room(capture: Path, tmp_path: Path) -> None:
    cap = tmp_path / "capture"
    shutil.copytree(capture, cap)

    def sky(d: np.ndarray) -> np.ndarray:
        return np.where(np.arange(d.shape[0])[:, None] < 12, np.float32(10.0), d)

    data = _manifest(cap)
    for frame in data["frames"]:  # every frame's top rows see "nothing"
        png = cap / frame["depth"]
        depth = sky(np.asarray(Image.open(png)).astype(np.float32) / 1000.0)
        Image.fromarray(np.rint(depth * 1000).astype(np.uint16)).save(png)
    lines: list[str] = []
    result = reconstruct(cap, tmp_path / "recon", _tiny(), until="fit", log=lines.append)
    assert any(line.startswith("warning: depth: ignoring") and "far plane (10 m" in line for line in lines), lines
    from holousd.usd import SceneGraph

    room = SceneGraph.open(result.scene_file).get_mesh("background").points
    assert np.abs(room[:, :2]).max() < 4.0  # the demo room is 4.6 x 4.0 m: no wall 10 m away


def test_capture_without_valid_depth_counts_as_one_without_depth(capture: Path, tmp_path: Path) -> None:
    from holousd.usd import SceneGraph

    cap = tmp_path / "capture"
    shutil.copytree(capture, cap)
    for path in (cap / "depth").iterdir():
        Image.fromarray(np.zeros((SIZE, SIZE), np.uint16)).save(path)
    lines: list[str] = []
    masks_only = replace(_tiny(), observe=_pipeline._observe.ObserveConfig(depth="capture"))
    result = reconstruct(cap, tmp_path / "recon", masks_only, until="fit", log=lines.append)
    assert any("none of the" in line and "counts as one without depth" in line for line in lines), lines
    assert not any("stereo" in line for line in lines), lines
    scene = SceneGraph.open(result.scene_file)
    faces = {name: len(scene.get_mesh(name).faces) for name in scene.objects()}
    assert len(faces) == 10 and min(faces.values()) > 0, faces
    result = reconstruct(cap, tmp_path / "recon", masks_only, until="fit", resume=True, log=lines.append)
    assert all(s.skipped for s in result.stages)
    # by default such a capture gets depth by stereo from its colour frames (a new setting: the stages run again)
    lines.clear()
    result = reconstruct(cap, tmp_path / "recon", _tiny(), until="fit", resume=True, log=lines.append)
    assert not any(s.skipped for s in result.stages)
    assert any("has no depth; estimating it with the stereo prior (4 frames)" in line for line in lines), lines
    scene = SceneGraph.open(result.scene_file)
    assert len(scene.objects()) == 10


def test_failing_stage_puts_the_output_folder_back(capture: Path, previous: Path, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture) -> None:  # fmt: skip
    out = tmp_path / "recon"
    shutil.copytree(previous, out)
    before = _snapshot(out)
    real_fit = _pipeline._fit.run

    def fit_then_fail(scene, obs, config):  # noqa: ANN001, ANN202
        real_fit(scene, obs, config)  # 10_fit.usda and assets/10_fit/ are on disk now
        raise RuntimeError("a bug in a stage")

    monkeypatch.setattr(_pipeline._fit, "run", fit_then_fail)
    monkeypatch.setattr(_pipeline, "preset", lambda *a, **k: _tiny())
    code, _, err = _run(["reconstruct", str(capture), "--out", str(out), "--preset", "fast"], capsys)
    assert code == 70 and "internal error (RuntimeError: a bug in a stage)" in err and "Traceback" not in err
    assert _snapshot(out) == before
    assert not [p for p in out.rglob("*") if p.name.startswith(".holousd")]
    code, _, err = _run(["reconstruct", str(capture), "--out", str(out), "--preset", "fast", "--verbose"], capsys)
    assert code == 70 and "Traceback" in err and "fit_then_fail" in err


def test_real_process_prints_no_traceback(tmp_path: Path) -> None:
    run = subprocess.run([sys.executable, "-m", "holousd.cli", "reconstruct", str(tmp_path / "none"), "--out",
                          str(tmp_path / "o")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr.strip().splitlines() == [f"holousd reconstruct: error: {tmp_path / 'none'}: no such folder; "
                                               "give the folder of a capture (or a video file)"]  # fmt: skip
    assert not (tmp_path / "o").exists()


_NOISY_INFO = """
import ctypes, os, sys
import holousd.cli
from holousd.usd._scene import SceneGraph

real = SceneGraph.summary

def noisy(self):
    os.write(1, b"native library progress on fd 1\\n")
    ctypes.CDLL(None).printf(b"buffered C stdio progress\\n")
    print("a Python library's print")
    return real(self)

SceneGraph.summary = noisy
sys.exit(holousd.cli.main(["info", sys.argv[1], "--json"]))
"""


def test_json_output_stays_parseable_when_libraries_print(example_dir: Path) -> None:
    run = subprocess.run([sys.executable, "-c", _NOISY_INFO, str(example_dir / "scene.usda")], capture_output=True,
                         text=True, timeout=120)  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert {n["name"] for n in json.loads(run.stdout)["nodes"]} == {"background", "table", "book", "mug", "box"}
    for noise in ("native library progress", "buffered C stdio progress", "a Python library's print"):
        assert noise in run.stderr and noise not in run.stdout


@pytest.mark.parametrize("command", ["info", "validate", "stability", "export"])
@pytest.mark.parametrize("damage", ["missing", "corrupt"])
def test_broken_layer_stack_is_named(command: str, damage: str, previous: Path, tmp_path: Path,
                                     capsys: pytest.CaptureFixture) -> None:  # fmt: skip
    out = tmp_path / "recon"
    shutil.copytree(previous, out)
    layer = out / "00_observe.usda"
    if damage == "missing":
        layer.unlink()
    else:
        layer.write_text("#usda 1.0\n(\n")
    before = _snapshot(out)
    argv = {"info": ["info"], "validate": ["validate"], "stability": ["stability"],
            "export": ["export", "--sim", str(out / "sim.usda")]}[command]  # fmt: skip
    code, stdout, err = _run([argv[0], str(out / "scene.usda"), *argv[1:]], capsys)
    line = _error_line(err, command)
    assert code == 2 and "00_observe.usda" in line and "Warning" not in err, err
    assert ("is missing" if damage == "missing" else "cannot be read as USD") in line
    assert _snapshot(out) == before
