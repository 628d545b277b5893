"""Depth priors for captures without depth (holousd.priors._depth): multi-view stereo from the colour frames, a
monocular network from a weights path, plug-ins; on hard/stack rendered small (24 frames at 96x72)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from holousd._errors import HolousdError
from holousd.cli import main
from holousd.geometry._stereo import StereoConfig, consistent, stereo_depth
from holousd.io import Observations, write
from holousd.priors import _depth as depth_module
from holousd.priors import available_depth_priors, make_depth_prior, with_depth_prior
from holousd.usd import SceneGraph
from tests.test_sensor import _stack_capture


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> Observations:
    obs, _ = _stack_capture(tmp_path_factory.mktemp("stack"))
    return obs


@pytest.fixture(scope="module")
def stack_rgb(stack: Observations, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Every other frame of the capture written without its depth and normals (colour, masks and poses only)."""
    from holousd.stages._cli import drop_depth

    folder = tmp_path_factory.mktemp("rgb") / "stack"
    write(drop_depth(stack.subset(range(0, 24, 2))), folder, format="native")
    return folder


def test_stereo_gives_metric_depth_where_the_frames_agree(stack: Observations) -> None:
    frames = list(range(0, 24, 2))
    estimated = with_depth_prior(stack, make_depth_prior("stereo"), frames)
    assert estimated.depth_kind == "metric" and estimated.metadata["depth_prior"] == "stereo"
    kept, errors = [], []
    for i in frames:
        depth, truth = estimated.depth(i), stack.depth(i)
        sel = (depth > 0) & (truth > 0)
        kept.append(sel.mean())
        errors.append(np.abs(depth[sel] - truth[sel]) / truth[sel])
    error = np.concatenate(errors)
    # measured: 14% of the pixels, median error 2.1% of the depth (a pixel at 96x72 is ~2.5 cm at 2 m)
    assert np.mean(kept) > 0.08, np.mean(kept)
    assert np.median(error) < 0.04, np.median(error)
    assert np.mean(error > 0.2) < 0.1
    # estimated once per frame: the same array comes back
    assert estimated.depth(frames[0]) is estimated.depth(frames[0])


def test_large_frames_are_swept_smaller_and_the_depth_comes_back_at_full_size(stack: Observations) -> None:
    prior = make_depth_prior("stereo", max_side="48")  # 96x72 swept at 48x36: memory and time grow with pixels
    depth, truth = prior.estimate(stack, 6), stack.depth(6)
    assert depth.shape == truth.shape
    sel = (depth > 0) & (truth > 0)
    assert sel.mean() > 0.03, sel.mean()
    assert np.median(np.abs(depth[sel] - truth[sel]) / truth[sel]) < 0.08


def test_stereo_keeps_nothing_on_a_textureless_frame_or_where_neighbours_disagree(stack: Observations) -> None:
    config = StereoConfig()
    h, w = stack.height, stack.width
    flat = np.broadcast_to(np.linspace(90, 110, w, dtype=np.float32)[None, :, None], (h, w, 3)).astype(np.uint8)
    images = {0: flat, 2: flat.copy(), 4: flat.copy()}
    swept = stereo_depth(0, images, stack.intrinsics, stack.poses, [2, 4], config, stack.mask(0))
    assert not swept.depth.any()  # a white wall matches every depth equally: no depth, not a guess
    # a neighbour that puts every point 20% farther confirms almost none of them (a few land by chance on a
    # surface that far behind)
    truth = {i: stack.depth(i) for i in (0, 2)}
    agreed = np.count_nonzero(consistent(0, truth, stack.intrinsics, stack.poses, [2], config))
    wrong = {0: truth[0], 2: truth[2] * 1.2}
    assert np.count_nonzero(consistent(0, wrong, stack.intrinsics, stack.poses, [2], config)) < 0.05 * agreed


def test_fit_without_depth_uses_stereo_and_places_objects_better_than_the_masks_alone(
    stack_rgb: Path, stack: Observations, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert stack.root is not None
    truth = SceneGraph.open(stack.root / "gt" / "scene.usda")

    def centre_error(folder: Path) -> float:
        scene = SceneGraph.open(folder / "10_fit.usda")
        errors = []
        for node in (n for n in scene.nodes() if n.role == "object"):
            fitted = scene.get_pose(node.name).apply(scene.get_mesh(node.name).points)
            true = truth.get_pose(node.name).apply(truth.get_mesh(node.name).points)
            errors.append(np.linalg.norm((fitted.min(0) + fitted.max(0)) / 2 - (true.min(0) + true.max(0)) / 2))
        return float(np.mean(errors))

    args = ["--preset", "fast", "--iterations", "1", "--seed", "0", "--threads", "1", "--no-progress"]
    cheap = ["--depth-option", "max_planes=96"]  # of the 256 the wide baselines ask for: a third of the time
    assert main(["fit", str(stack_rgb), "--out", str(tmp_path / "stereo"), *args, *cheap]) == 0
    err = capsys.readouterr().err
    assert "has no depth; estimating it with the stereo prior (12 frames)" in err
    assert "depth: stereo (metric) gave" in err
    report = json.loads((tmp_path / "stereo" / "fit_report.json").read_text())
    assert report["depth"] == "metric" and report["depth_prior"] == "stereo"
    assert all(o["faces"] > 0 and o["watertight"] for o in report["objects"])
    assert main(["fit", str(stack_rgb), "--out", str(tmp_path / "masks"), "--depth", "capture", *args]) == 0
    masks = json.loads((tmp_path / "masks" / "fit_report.json").read_text())
    assert masks["depth"] == "none" and masks["depth_prior"] is None
    stereo_error, masks_error = centre_error(tmp_path / "stereo"), centre_error(tmp_path / "masks")
    assert stereo_error < 0.5 * masks_error, (stereo_error, masks_error)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--depth", "kinect"], "depth prior 'kinect': none by that name; available: stereo, learned"),
        (["--depth", "learned"], "depth prior 'learned' needs weights=PATH"),
        (["--depth", "learned", "--depth-option", "weights=/nonexistent/model.pt2"], "no such weights file"),
        (["--depth", "stereo", "--depth-option", "window"], "--depth-option 'window': write KEY=VALUE"),
        (["--depth", "stereo", "--depth-option", "window=4"], "window 4 must be odd"),
        (["--depth", "stereo", "--depth-option", "planes=9"], "unknown option 'planes'"),
        (["--depth", "capture", "--depth-option", "window=5"], "no depth prior runs"),
        (["--depth", "stereo", "--depth-option", "max_planes=0"], "need 3 <= min_planes <= max_planes"),
        (["--no-depth", "--depth", "stereo"], "--no-depth with --depth stereo: choose one"),
    ],
)
def test_bad_depth_options_are_refused_before_anything_is_written(
    stack_rgb: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    out = tmp_path / "out"
    assert main(["fit", str(stack_rgb), "--out", str(out), "--preset", "fast", *argv]) != 0
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err, err
    assert not out.exists() or not any(out.iterdir())


class _TinyDepthNet:
    """What the test saves as a 'learned' monocular depth network: depth = 1 + 2 * (1 - green)."""

    @staticmethod
    def build():  # noqa: ANN205 - a torch module
        import torch

        class Net(torch.nn.Module):
            def forward(self, x: torch.Tensor) -> torch.Tensor:
                return 1.0 + 2.0 * (1.0 - x[:, 1:2])

        return Net()


def test_learned_depth_prior_loads_a_saved_network_from_the_path_it_is_given(stack: Observations,
                                                                              tmp_path: Path) -> None:  # fmt: skip
    import torch

    weights = tmp_path / "depth_net.pt"
    torch.jit.save(torch.jit.script(_TinyDepthNet.build()), str(weights))
    prior = make_depth_prior("learned", weights=str(weights))
    assert prior.kind == "relative"
    estimated = with_depth_prior(stack, prior)
    assert estimated.depth_kind == "relative" and estimated.metadata["depth_prior"] == "learned"
    green = stack.rgb(3)[..., 1].astype(np.float32) / 255.0
    np.testing.assert_allclose(estimated.depth(3), 1.0 + 2.0 * (1.0 - green), atol=1e-5)
    inverse = make_depth_prior("learned", weights=str(weights), output="inverse", kind="metric")
    np.testing.assert_allclose(inverse.estimate(stack, 3), 1.0 / (1.0 + 2.0 * (1.0 - green)), rtol=1e-5)
    assert inverse.kind == "metric"
    with pytest.raises(HolousdError, match="output=inverse needs kind=metric"):
        make_depth_prior("learned", weights=str(weights), output="inverse")
    with pytest.raises(HolousdError, match="kind 'absolute'"):
        make_depth_prior("learned", weights=str(weights), kind="absolute")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a model")
    with pytest.raises(HolousdError, match="corrupt.pt: not a saved model"):
        make_depth_prior("learned", weights=str(corrupt))

    class Squeeze(torch.nn.Module):
        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return x[:, :1, ::2, ::2]

    small = tmp_path / "small.pt"
    torch.jit.save(torch.jit.script(Squeeze()), str(small))
    with pytest.raises(HolousdError, match=r"small.pt: the network returned shape \(36, 48\) for a 96x72 frame"):
        make_depth_prior("learned", weights=str(small)).estimate(stack, 0)


def test_depth_prior_plug_ins_register_under_their_entry_point_group(monkeypatch: pytest.MonkeyPatch,
                                                                     stack: Observations) -> None:  # fmt: skip
    class Flat:
        name, kind = "flat", "metric"

        def __init__(self, level: str = "2.0") -> None:
            self.level = float(level)

        def estimate(self, obs: Observations, i: int) -> np.ndarray:
            return np.full((obs.height, obs.width), self.level, np.float32)

    class EntryPoint:
        def __init__(self, name: str, target: object) -> None:
            self.name, self.value, self._target = name, f"tests:{name}", target

        def load(self) -> object:
            if self._target is None:
                raise ImportError("no module named flat_depth")
            return self._target

    points = {"flat": EntryPoint("flat", Flat), "broken": EntryPoint("broken", None),
              "notaprior": EntryPoint("notaprior", lambda: object())}  # fmt: skip
    monkeypatch.setattr(depth_module, "_entry_points", lambda: points)
    assert available_depth_priors() == ["stereo", "learned", "broken", "flat", "notaprior"]
    estimated = with_depth_prior(stack, make_depth_prior("flat", level="1.5"), frames=[0])
    assert estimated.depth_kind == "metric" and float(estimated.depth(5).max()) == 1.5
    with pytest.raises(HolousdError, match=r"depth prior 'broken' \(tests:broken\): cannot be loaded"):
        make_depth_prior("broken")
    with pytest.raises(HolousdError, match="not a depth prior"):
        make_depth_prior("notaprior")
    with pytest.raises(HolousdError, match="bad options"):
        make_depth_prior("flat", colour="red")


def test_video_sensor_has_no_depth_channel(tmp_path: Path) -> None:
    from holousd.io import load
    from holousd.synth import SENSORS, SynthConfig, generate_suite

    assert SENSORS["video"].has_depth is False and SENSORS["phone"].has_depth is True
    generate_suite("hard", tmp_path, SynthConfig(frames=3, width=32, height=24, progress=False, sensor="video"),
                   scenes=["stack"])  # fmt: skip
    obs = load(tmp_path / "stack")
    assert not obs.has_depth and not obs.has_normals and obs.has_masks
    graph = json.loads((tmp_path / "stack" / "gt" / "graph.json").read_text())
    assert graph["capture"]["sensor"]["name"] == "video" and graph["capture"]["sensor"]["has_depth"] is False


def test_a_relative_prior_anchored_to_stereo_gives_dense_metric_depth(monkeypatch: pytest.MonkeyPatch,
                                                                      stack: Observations) -> None:  # fmt: skip
    class Affine:
        """A 'monocular network' that knows the true depth up to a scale and shift (relative, as such nets are)."""

        name, kind = "affine", "relative"

        def estimate(self, obs: Observations, i: int) -> np.ndarray:
            truth = obs.depth(i)
            return np.where(truth > 0, 0.4 * truth + 1.5, 0.0).astype(np.float32)

    class EntryPoint:
        name, value = "affine", "tests:affine"

        def load(self) -> object:
            return Affine

    monkeypatch.setattr(depth_module, "_entry_points", lambda: {"affine": EntryPoint()})
    prior = make_depth_prior("affine", anchor="stereo")
    assert prior.kind == "metric" and prior.name == "affine+stereo"
    depth, truth = prior.estimate(stack, 6), stack.depth(6)
    stereo_only = make_depth_prior("stereo").estimate(stack, 6)
    sel = (depth > 0) & (truth > 0)
    assert sel.sum() > 0.95 * (truth > 0).sum() > 5 * np.count_nonzero(stereo_only)  # dense, not stereo's fifth
    assert np.median(np.abs(depth[sel] - truth[sel]) / truth[sel]) < 0.02
    with pytest.raises(HolousdError, match="anchor=stereo is for a relative prior"):
        make_depth_prior("stereo", anchor="stereo")
    with pytest.raises(HolousdError, match="anchor 'lidar'"):
        make_depth_prior("affine", anchor="lidar")
