"""Pictures (fpp_nodes/pictures.py): the colours mean what the scale bar says, invalid pixels
look invalid, the renderer draws surfaces, and the tools write the files."""

import subprocess
import sys

import cv2
import numpy as np
import pytest

from fpp_nodes import cli
from fpp_nodes import pictures as P
from fpp_nodes.core.calibration import CameraIntrinsics, back_project, default_calibration_path
from fpp_nodes.core.model import paper_model_path

H, W = 120, 160


def bar_ends(picture, width=W, top_offset=0):
    """The colour bar's colours at its top and bottom (the bar sits right of the picture)."""
    column = picture[top_offset + 20 : picture.shape[0] - 20, width + 18].astype(int)
    return column[0], column[-1]


def test_depth_shows_each_pixel_in_its_colour_near_red_and_nan_grey():
    depth = np.tile(np.linspace(1100, 1300, W), (H, 1))
    depth[:10, :10] = np.nan
    img = P.depth_picture(depth, 1100, 1300)
    assert img.dtype == np.uint8 and img.shape == (H, W + P.BAR_PANEL, 3)
    expected = P.depth_colours(depth, 1100, 1300)
    assert np.abs(img[:, :W].astype(int) - expected).max(axis=-1).mean() < 2  # one picture pixel per depth pixel
    near, far = img[60, 0].astype(int), img[60, W - 1 - W // 5].astype(int)
    assert near[2] > near[0] + 50 and far[0] > far[2] + 50  # near red, far blue (BGR)
    assert (img[:10, :10] == P.INVALID_BGR).all() and not (img[20:, :W] == P.INVALID_BGR).all(axis=-1).any()
    top, bottom = bar_ends(img)
    assert top[2] > top[0] + 50 and bottom[0] > bottom[2] + 50  # the bar: near (red) at the top
    lo, hi = P.depth_range(depth)  # default range: robust percentiles of the valid pixels
    assert 1100 < lo < 1105 and 1295 < hi < 1300


def test_error_is_neutral_where_prediction_equals_truth_and_signed_elsewhere():
    truth = np.full((H, W), 1200.0)
    pred = truth.copy()
    pred[:, 100:] += 0.5  # too far
    pred[:, 130:] -= 1.0  # too near
    truth[:20, :20] = np.nan
    img = P.error_picture(pred, truth, limit_mm=1.0)
    t = P.TITLE_HEIGHT
    assert img.shape == (H + t, W + P.BAR_PANEL, 3) and img.dtype == np.uint8
    neutral = img[t + 60, 50].astype(int)
    assert neutral.min() > 240 and neutral.max() - neutral.min() <= 3
    far, near = img[t + 60, 110].astype(int), img[t + 60, 140].astype(int)
    assert far[2] > far[0] + 40 and near[0] > near[2] + 40
    assert np.abs(img[t:, :W].astype(int) - P.error_colours(pred - truth, 1.0)).max(axis=-1).mean() < 2
    assert (img[t : t + 20, :20] == P.INVALID_BGR).all()
    top, bottom = bar_ends(img, top_offset=t)
    assert top[2] > top[0] + 50 and bottom[0] > bottom[2] + 50  # + (too far, red) at the top
    assert (img[:t, :W] < 128).any()  # the title is written


def plane(tilt_x: float) -> np.ndarray:
    """Organized cloud (mm) of a plane at 1200 mm, tilted by tilt_x mm of depth per mm of x."""
    cam = CameraIntrinsics(W, H, 200.0, 200.0, W / 2, H / 2)
    x = (np.arange(W) - W / 2) / 200.0
    depth = 1200.0 / (1 - tilt_x * x)[None, :].repeat(H, axis=0)
    return back_project(depth, cam), cam


def test_cloud_view_draws_a_surface_that_depends_on_its_shape():
    flat, cam = plane(0.0)
    tilted, _ = plane(0.4)
    a = P.cloud_view(flat, size=(200, 150))
    b = P.cloud_view(tilted, size=(200, 150))
    assert a.shape == (150, 200, 3) and a.dtype == np.uint8
    for img in (a, b):
        assert (img != 255).any(axis=-1).mean() > 0.15  # not blank
    assert np.abs(a.astype(int) - b.astype(int)).mean() > 10
    # a depth map with intrinsics is the same cloud
    np.testing.assert_array_equal(P.cloud_view(tilted[..., 2], cam, size=(200, 150)), b)
    with pytest.raises(ValueError):
        P.cloud_view(tilted[..., 2])


def test_cloud_view_shows_the_nearest_surface():
    """Two layers over the same x, y: head-on, the near one (red) must hide the far one (blue)."""
    far, _ = plane(0.0)
    near = far * (1100.0 / 1200.0)
    for layers in ([far, near], [near, far]):  # whichever comes first in the grid
        img = P.cloud_view(np.concatenate(layers, axis=0), size=(200, 150), tilt_deg=0, turn_deg=0, step=1)
        centre = img[75, 100].astype(int)
        assert centre[2] > centre[0] + 50  # near = red end of the colour map


def test_height_profile_draws_every_curve_in_its_colour():
    n = 200
    curves = {"ground truth": np.full(n, 1.0), "a": np.full(n, 2.0), "b": np.full(n, 3.0)}
    curves["b"][: n // 2] = np.nan  # a gap: nothing drawn there
    img = P.height_profile(7, curves, size=(640, 360), ylim=(0.0, 8.0))  # curves low, legend top right
    assert img.shape == (360, 640, 3) and img.dtype == np.uint8
    left, right = img[:, 70:300].astype(int), img[200:, 340:630].astype(int)
    for k, name in enumerate(curves):
        colour = np.array(P.PALETTE[k])
        hits = lambda part: int((np.abs(part - colour).max(axis=-1) <= 30).sum())  # noqa: E731
        if name == "b":
            assert hits(left) == 0 and hits(right) > 50
        else:
            assert hits(left) > 100, name


def test_side_by_side_and_profile_row():
    grey = np.zeros((100, 50), np.uint8)
    colour = np.zeros((50, 80, 3), np.uint8)
    img = P.side_by_side([grey, colour], ["a", "b"], gap=4)
    assert img.shape == (100 + P.TITLE_HEIGHT, 50 + 4 + 160, 3)
    assert P.side_by_side([grey, grey]).shape == (100, 106, 3)
    with pytest.raises(ValueError):
        P.side_by_side([grey], ["a", "b"])
    depth = np.full((H, W), 1200.0)
    depth[70:75, 40:120] = 1150.0  # an object crossing rows 70-74
    assert 70 <= P.profile_row(depth) <= 74


def test_fpp_reconstruct_writes_pictures_that_decode(tmp_path, capsys):
    scene, out = tmp_path / "scene", tmp_path / "out"
    assert cli.main(["simulate", "--scene", "objects", "--seed", "5", "--out", str(scene)]) == 0
    assert cli.main(["reconstruct", str(scene), "--calibration", default_calibration_path(), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    for name in ("depth.png", "error.png", "cloud.png", "profile.png"):
        img = cv2.imread(str(out / name))
        assert img is not None and img.ndim == 3 and min(img.shape[:2]) >= 200, name
        assert str(out / name) in printed
    assert (
        cli.main(
            [
                "evaluate",
                str(out / "depth_mm.npy"),
                str(scene / "depth_gt_mm.npy"),
                "--valid",
                str(scene / "valid_gt.png"),
                "--pictures",
                str(tmp_path / "ev"),
            ]
        )
        == 0
    )
    assert cv2.imread(str(tmp_path / "ev" / "error.png")) is not None


def test_figures_2_and_3_from_a_data_set_and_an_onnx_model(tmp_path):
    from training import figures
    from training.dataset import write_set

    data = write_set(tmp_path / "data", "single", counts=(0, 0, 1), workers=1)
    (tmp_path / "extra").mkdir()
    cv2.imwrite(str(tmp_path / "extra" / "x.png"), np.zeros((40, 60, 3), np.uint8))
    figures.main(
        [
            "--data",
            str(data),
            "--out",
            str(tmp_path / "pics"),
            "--also",
            f"{tmp_path}/extra/x.png:0.5",
            paper_model_path(),
        ]
    )
    fig2, fig3 = (cv2.imread(str(tmp_path / "pics" / f)) for f in ("figure2.png", "figure3.png"))
    assert fig2.shape[1] > 3 * fig2.shape[0] // 2 and fig3 is not None  # input, truth, UNet in a row
    assert cv2.imread(str(tmp_path / "pics" / "extra_x.png")).shape == (20, 30, 3)


def test_pictures_import_neither_ros_nor_torch_nor_pyplot():
    """The nodes' demo draws them: no ROS or torch behind them, and no pyplot (global figure state,
    a GUI backend)."""
    code = (
        "import sys, fpp_nodes.pictures; "
        "assert not [m for m in sys.modules if m.split('.')[0] in ('rclpy', 'torch') or m == 'matplotlib.pyplot']"
    )
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
