from dataclasses import replace

import cv2
import numpy as np
import pytest

from fpp_nodes.core.calibration import back_project
from fpp_nodes.core.phase import wrapped_phase
from fpp_nodes.core.scenes import make_scene, plane_scene, scene_from_file
from fpp_nodes.core.simulation import (
    AMBIENT,
    BLUR_SIGMA_PX,
    GAIN,
    NOISE_SIGMA,
    Rig,
    SimulationError,
    beyond_training_rig,
    render,
)


def analytic_plane_phase(rig: Rig, patterns, depth_mm):
    """Phase a fronto-parallel plane shows at every pixel, written out without the Rig's own helpers:
    the projector is turned about the camera's y axis to face the point (0, 0, standoff)."""
    f = rig.focal_px
    u, _ = np.meshgrid(np.arange(rig.width), np.arange(rig.height))
    X = (u - (rig.width - 1) / 2) / f * depth_mm
    theta = np.arctan2(rig.baseline_mm, rig.standoff_mm)  # the projector looks back towards -x by theta
    dx = X - rig.baseline_mm
    xp = np.cos(theta) * dx + np.sin(theta) * depth_mm
    zp = -np.sin(theta) * dx + np.cos(theta) * depth_mm
    focal_p = rig.projector_width * np.hypot(rig.baseline_mm, rig.standoff_mm) / rig.projector_field_mm
    column = focal_p * xp / zp + (rig.projector_width - 1) / 2
    return 2 * np.pi * patterns.frequencies[-1] * column / rig.projector_width


def test_plane_shows_the_analytic_phase_at_every_pixel(ideal_rig, ideal_patterns):
    for depth in (1120.0, 1200.0, 1275.0):
        capture = render(ideal_rig, plane_scene(ideal_rig, depth), ideal_patterns)
        measured = wrapped_phase(capture.images[ideal_patterns.top_frequency_frames].astype(np.float64))
        expected = analytic_plane_phase(ideal_rig, ideal_patterns, depth)
        assert np.abs(np.angle(np.exp(1j * (measured - expected)))).max() < 2e-3
        assert capture.valid.all()


def test_a_box_casts_the_shadow_geometry_predicts(ideal_rig, ideal_patterns, tmp_path):
    rig = ideal_rig
    height = np.zeros((rig.height, rig.width))
    height[180:300, 240:400] = 40.0  # a 40 mm box on the background plane
    np.save(tmp_path / "box.npy", height)
    capture = render(rig, scene_from_file(rig, tmp_path / "box.npy"), ideal_patterns)
    shadow = ~capture.valid
    # The projector is at +x, so the shadow falls on the background left of the box: from the box's
    # edge in the image (between pixels 239 and 240) to where the projector's ray over the box's top
    # left edge X_e meets the background, X_s = B + (X_e - B) Z0 / (Z0 - H).
    z0, h, cx = rig.standoff_mm, 40.0, (rig.width - 1) / 2
    x_edge = (239.5 - cx) / rig.focal_px * (z0 - h)
    x_shadow = rig.baseline_mm + (x_edge - rig.baseline_mm) * z0 / (z0 - h)
    expected_px = 239.5 - (rig.focal_px * x_shadow / z0 + cx)
    widths = shadow[200:280].sum(axis=1)
    assert np.all(np.abs(widths - expected_px) <= 1.5)
    assert not shadow[200:280, 240:].any() and not shadow[:150].any()  # nothing else is dark
    # shadowed pixels see ambient light only: no fringe modulation
    assert np.ptp(capture.images[ideal_patterns.top_frequency_frames].astype(np.int64), axis=0)[shadow].max() <= 1


def test_render_is_reproducible_and_noisy_only_with_a_generator(rig, patterns):
    scene = make_scene(rig, "sculpture", 5)
    a = render(rig, scene, patterns, np.random.default_rng(1)).images
    b = render(rig, scene, patterns, np.random.default_rng(1)).images
    clean = render(rig, scene, patterns).images
    np.testing.assert_array_equal(a, b)
    assert 0.5 < np.std(a.astype(float) - clean) < 1.5  # noise_sigma = 1 count, plus rounding


@pytest.mark.parametrize("suffix", [".npy", ".png", ".tiff"])
def test_height_maps_from_files(rig, tmp_path, suffix):
    height = np.zeros((240, 320), np.uint16)
    height[80:160, 100:220] = 40
    path = tmp_path / f"map{suffix}"
    if suffix == ".npy":
        np.save(path, height.astype(np.float32))
    else:
        cv2.imwrite(str(path), height)
    scene = scene_from_file(rig, path)
    assert scene.depth_mm.shape == (rig.height, rig.width)  # resized to the camera
    assert scene.depth_mm.max() - scene.depth_mm.min() == pytest.approx(40, abs=1)
    assert scene.depth_mm[240, 320] == pytest.approx(rig.standoff_mm - 40, abs=0.5)


def test_bad_scene_files_are_clear_errors(rig, tmp_path):
    with pytest.raises(SimulationError, match="does not exist"):
        scene_from_file(rig, tmp_path / "none.npy")
    (tmp_path / "junk.png").write_bytes(b"not a png")
    with pytest.raises(SimulationError, match="cannot decode"):
        scene_from_file(rig, tmp_path / "junk.png")
    np.save(tmp_path / "cube.npy", np.zeros((2, 3, 4)))
    with pytest.raises(SimulationError, match="2-D"):
        scene_from_file(rig, tmp_path / "cube.npy")
    np.save(tmp_path / "nan.npy", np.full((4, 4), np.nan))
    with pytest.raises(SimulationError, match="NaN"):
        scene_from_file(rig, tmp_path / "nan.npy")
    with pytest.raises(SimulationError, match="projector is"):
        render(rig, plane_scene(rig, 1200), Rig(projector_width=640).pattern_set())


def test_a_distorted_camera_sees_a_plane_where_the_lens_model_puts_it(ideal_rig):
    """Lens distortion, against closed forms: each pixel's ray projects back onto that pixel through
    OpenCV's model, a fronto-parallel plane back-projects flat, and the phase each pixel shows is the
    projector's at the point its (bent) ray meets the plane."""
    lens = (-0.9, 0.5, 3e-4, -2e-4, 0.0)
    rig = replace(ideal_rig, distortion=lens)
    cam = rig.camera()
    x, y = cam.rays()
    u, v = cam.project(np.stack([x, y, np.ones_like(x)], axis=-1))
    columns, rows = np.meshgrid(np.arange(rig.width), np.arange(rig.height))
    assert np.abs(u - columns).max() < 1e-9 and np.abs(v - rows).max() < 1e-9
    corner = cv2.projectPoints(
        np.array([[x[0, 0], y[0, 0], 1.0]]), np.zeros(3), np.zeros(3), cam.matrix(), np.array(lens)
    )
    assert np.abs(corner[0].ravel() - (0.0, 0.0)).max() < 1e-9  # the same model as OpenCV's
    ideal_u, ideal_v = cam.ideal_pixels()
    assert np.hypot(ideal_u[0, 0], ideal_v[0, 0]) > 1.5  # the corner pixel's ray is bent by over a pixel
    xyz = back_project(np.full(cam.shape, 1200.0), cam)
    assert np.abs(xyz[..., 2] - 1200).max() < 1e-3
    patterns = rig.pattern_set(bit_depth=16)
    capture = render(rig, plane_scene(rig, 1200.0), patterns)
    xp, _, _ = rig.to_projector(np.stack([x * 1200.0, y * 1200.0, np.full(x.shape, 1200.0)], axis=-1))
    expected = 2 * np.pi * patterns.frequencies[-1] * xp / rig.projector_width
    measured = wrapped_phase(capture.images[patterns.top_frequency_frames].astype(np.float64))
    assert np.abs(np.angle(np.exp(1j * (measured - expected)))).max() < 2e-3


def test_horizontal_fringes_tell_the_projector_row(ideal_rig):
    """The board calibration's second fringe set: its unwrapped phase is 2 pi f_max y_p / H."""
    from fpp_nodes.core.board import board_patterns
    from fpp_nodes.core.reconstruct import multi_frequency_phase

    _, patterns = board_patterns(ideal_rig.pattern_set(bit_depth=16))
    capture = render(ideal_rig, plane_scene(ideal_rig, 1180.0, tilt_x_deg=15.0), patterns)
    phase, valid, _, _, _ = multi_frequency_phase(capture.images, patterns)
    row = phase * ideal_rig.projector_height / (2 * np.pi * patterns.frequencies[-1])
    # 0.02 projector px: the projector's pixels, linear between centres, bend an 8-px period's sinusoid
    assert valid.mean() > 0.99 and np.abs(row - capture.projector_coord)[valid].max() < 0.02


def test_hard_validation_photometry_lies_beyond_the_training_ranges():
    """Each beyond_training_rig draw has one or two settings outside what training draws (the projector's
    gamma at least 0.2 off the 2.2 its patterns are made for), and says which."""
    trained = {"ambient": AMBIENT, "gain": GAIN, "noise_sigma": NOISE_SIGMA, "blur_sigma_px": BLUR_SIGMA_PX}
    for seed in range(40):
        rig, condition = beyond_training_rig(np.random.default_rng(seed), Rig())
        outside = [name for name, (low, high) in trained.items() if not low <= getattr(rig, name) <= high]
        outside += ["projector_gamma"] * (abs(rig.projector_gamma - 2.2) >= 0.2)
        assert 1 <= len(outside) <= 2 and sorted(outside) == sorted(part.split()[0] for part in condition.split(", "))
