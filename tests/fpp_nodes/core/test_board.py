"""Board calibration (core/board.py) on a simulated rig whose camera has lens distortion: the camera and
projector calibrated from a checkerboard at free poses, the depth it gives on scenes it never saw, a
plane across the whole field measured flat, and the errors a user meets."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from fpp_nodes.core.board import (
    Board,
    BoardPose,
    board_patterns,
    calibrate_from_board,
    find_corners,
    square_on_corners,
)
from fpp_nodes.core.calibration import CalibrationError, back_project
from fpp_nodes.core.metrics import depth_errors
from fpp_nodes.core.reconstruct import CompositeDecoder, PspReconstructor
from fpp_nodes.core.scenes import board_poses, board_scene, make_scene, plane_scene
from fpp_nodes.core.simulation import Rig, SceneRenderer, render, render_pose
from fpp_nodes.core.workflow import fringe_depth_mm, simulated_calibration

LENS = (-0.9, 0.0, 2e-4, -2e-4, 0.0)  # about 2.3 px of barrel distortion in the corners
BOARD = Board.parse("9x7:8")


@pytest.fixture(scope="module")
def lens_rig():
    return Rig(distortion=LENS)


def pose(rig, rotation, translation, rng, name="pose"):
    patterns = rig.pattern_set()
    image, stacks = render_pose(rig, board_scene(rig, BOARD, rotation, translation), board_patterns(patterns), rng)
    return BoardPose(name, image, *stacks)


@pytest.fixture(scope="module")
def board_calibration(lens_rig):
    rng = np.random.default_rng(0)
    poses = [pose(lens_rig, r, t, rng, f"pose {i}") for i, (r, t) in enumerate(board_poses(lens_rig, BOARD, 15, rng))]
    return calibrate_from_board(poses, BOARD, lens_rig.pattern_set())


def test_the_rendered_board_puts_its_corners_where_the_distorted_camera_projects_them(lens_rig):
    """The simulator's geometry against the closed form: OpenCV finds the printed corners within a
    few hundredths of a pixel of their projection through the lens model."""
    rng, cam = np.random.default_rng(3), lens_rig.camera()
    errors = []
    for rotation, translation in board_poses(lens_rig, BOARD, 3, rng):
        image = pose(lens_rig, rotation, translation, rng).image
        truth = np.stack(cam.project(BOARD.object_points() @ rotation.T + translation), axis=-1)
        lens, rvec = np.array(cam.distortion), cv2.Rodrigues(rotation)[0]
        square_on = square_on_corners(image, BOARD, cam.matrix(), lens, rvec, translation.reshape(3, 1))
        errors.append(
            [np.sqrt(np.mean(np.sum((c - truth) ** 2, axis=-1))) for c in (find_corners(image, BOARD), square_on)]
        )
    found, refined = np.mean(errors, axis=0)
    assert found < 0.06 and refined < 0.8 * found  # seen square-on, the corners are not bent by tilt and lens


def test_board_calibration_recovers_the_rig(lens_rig, board_calibration):
    calibration, report = board_calibration
    assert max(p.camera_px for p in report.poses) <= 0.1  # the target for the camera
    assert max(p.projector_px for p in report.poses) <= 0.3
    cam = calibration.camera
    assert abs(cam.fx / lens_rig.focal_px - 1) < 1e-3 and abs(cam.distortion[0] - LENS[0]) < 0.1
    assert abs(np.linalg.norm(report.translation_mm) - lens_rig.baseline_mm) < 1.0
    assert report.model_fit_mm < 0.01  # the rational model vs exact triangulation through that geometry


def test_board_calibration_measures_scenes_it_never_saw(lens_rig, board_calibration):
    """No fringe-order errors, and the depth scale right to 0.05% (0.6 mm at 1.2 m): the board's depth
    scale rests on its focal length, which 15 poses tell to 0.01-0.07% (docs/real-rig.md); the plane
    calibration with a stage and known intrinsics is right to 0.025 mm RMS."""
    calibration, _ = board_calibration
    planes, _ = simulated_calibration(lens_rig, lens_rig.pattern_set(), seed=7)
    for kind, seed in (("objects", 21), ("sculpture", 22)):
        capture = render(
            lens_rig, make_scene(lens_rig, kind, seed), lens_rig.pattern_set(), np.random.default_rng(seed)
        )
        for c, rmse_mm, mre in ((calibration, 0.6, 5e-4), (planes, 0.035, 3e-5)):
            rec = PspReconstructor(c)(capture.images)
            e = depth_errors(rec.depth_mm, capture.depth_mm, capture.valid, fringe_depth_mm(c, rec.phase))
            assert e.order_errors == 0 and e.coverage > 0.95 and e.rmse_mm < rmse_mm and e.mre < mre, (kind, e)


def test_a_plane_across_the_field_is_flat_not_a_bowl(lens_rig, board_calibration):
    """XYZ through the calibrated lens: a tilted plane filling the view deviates from the best-fit plane
    by at most 1.5x the noise the images alone cause (the depth-noise estimate, quality)."""
    calibration, _ = board_calibration
    capture = render(lens_rig, plane_scene(lens_rig, 1200.0, tilt_x_deg=20.0), lens_rig.pattern_set(), None)
    noisy = render(
        lens_rig, plane_scene(lens_rig, 1200.0, tilt_x_deg=20.0), lens_rig.pattern_set(), np.random.default_rng(5)
    )
    for images in (capture.images, noisy.images):
        rec = PspReconstructor(calibration)(images)
        xyz = back_project(rec.depth_mm, calibration.camera).reshape(-1, 3).astype(np.float64)
        ok = np.isfinite(xyz).all(axis=1)
        a = np.c_[xyz[ok, :2], np.ones(ok.sum())]
        residual = xyz[ok, 2] - a @ np.linalg.lstsq(a, xyz[ok, 2], rcond=None)[0]
        noise = np.sqrt(np.mean(rec.quality[np.isfinite(rec.quality)] ** 2))
        assert ok.mean() > 0.95 and np.sqrt(np.mean(residual**2)) < 1.5 * noise


def test_bad_poses_are_clear_errors(lens_rig):
    rng = np.random.default_rng(4)
    poses = [pose(lens_rig, r, t, rng, f"pose {i}") for i, (r, t) in enumerate(board_poses(lens_rig, BOARD, 4, rng))]
    patterns = lens_rig.pattern_set()
    with pytest.raises(CalibrationError, match="3 board poses; board calibration needs at least 4"):
        calibrate_from_board(poses[:3], BOARD, patterns)
    blank = replace(poses[2], image=np.zeros_like(poses[2].image))
    with pytest.raises(CalibrationError, match=r"pose pose 2: the board \(9x7 inner corners\) is not found"):
        calibrate_from_board([*poses[:2], blank, poses[3]], BOARD, patterns)
    still = np.broadcast_to(poses[1].image, poses[1].vertical.shape)  # the projector stuck on white: no fringes
    dark = replace(poses[1], vertical=still)
    with pytest.raises(CalibrationError, match="pose pose 1: only .* corners are lit by decodable fringes"):
        calibrate_from_board([poses[0], dark, *poses[2:]], BOARD, patterns)
    rotation, translation = board_poses(lens_rig, BOARD, 1, rng)[0]
    shifted = [
        pose(lens_rig, rotation, translation + [dx, dy, dz], rng)
        for dx, dy, dz in ((0, 0, 0), (5, 0, 60), (-5, 3, 120), (0, -4, -60))
    ]
    with pytest.raises(CalibrationError, match="face the same way"):
        calibrate_from_board(shifted, BOARD, patterns)
    with pytest.raises(CalibrationError, match="COLSxROWS:SQUARE_MM"):
        Board.parse("9x7")
    with pytest.raises(CalibrationError, match="lens model 'wide' is not one of k1, k1k2, full"):
        calibrate_from_board(poses, BOARD, patterns, lens="wide")


def test_a_projector_whose_light_ends_inside_the_view_calibrates_its_codes_from_a_board():
    """From a board the code models come from the projector's geometry, whatever FTP reads beside the
    light's edges (the plane calibration's trouble there: test_calibration), and exact phases decode
    separated objects with none off by more than 1 mm (measured: 95.9% of the lit pixels given, the 99th
    percentile 0.09 mm off, the board's depth scale)."""
    from test_composite import as_network_output, exact_phases  # this folder is on the path (no package)

    rig = replace(Rig(), projector_field_mm=170.0)
    rng = np.random.default_rng(0)
    poses = [pose(rig, r, t, rng, f"pose {i}") for i, (r, t) in enumerate(board_poses(rig, BOARD, 15, rng))]
    calibration, _ = calibrate_from_board(poses, BOARD, rig.pattern_set(), working_range_mm=(1100.0, 1300.0))
    scene = make_scene(rig, "objects", 21)
    renderer = SceneRenderer(rig, scene)
    lit = renderer.lit[renderer.crop]
    depth, _ = CompositeDecoder(calibration)(as_network_output(*exact_phases(renderer, rig.pattern_set())), 0.5, lit)
    given = np.isfinite(depth)
    assert given.sum() > 0.9 * lit.sum() and np.abs(depth - scene.depth_mm)[given].max() < 1.0


class RearModeRig(Rig):
    """The simulated rig with its projector in rear mode: it shows its image mirrored left-right."""

    def to_projector(self, points):
        x, y, depth = super().to_projector(points)
        return self.projector_width - 1 - x, y, depth


def test_a_projector_in_rear_mode_calibrates_from_a_board_and_measures():
    """A projector showing its image mirrored is no pinhole: its corners turn the other way than in the
    camera, so its columns are read mirrored back and mirrored again in the model. Before, the
    calibration was written without a word (corners 8-41 px off in the projector, a model 3.1 mm
    from its geometry, the working range 135 mm off) and the single-shot decoder then took minutes
    a frame. Now the multi-shot path measures a scene it never saw as on the plain rig, and the shipped
    network gives a scene of separate objects 93.7% of its lit pixels, 0.02% off by more than 1 mm. A pose
    whose fringes are another pose's is refused by its corners' error in the projector."""
    from fpp_nodes.core.model import DepthModel, default_model_path

    rig = RearModeRig()
    rng = np.random.default_rng(0)
    poses = [pose(rig, r, t, rng, f"pose {i}") for i, (r, t) in enumerate(board_poses(rig, BOARD, 15, rng))]
    calibration, report = calibrate_from_board(poses, BOARD, rig.pattern_set(), working_range_mm=(1100.0, 1300.0))
    assert report.projector_mirrored and max(p.projector_px for p in report.poses) <= 0.3
    assert abs(np.linalg.norm(report.translation_mm) - rig.baseline_mm) < 1.0 and report.model_fit_mm < 0.01
    capture = render(rig, make_scene(rig, "objects", 5), rig.pattern_set(), np.random.default_rng(5))
    rec = PspReconstructor(calibration)(capture.images)
    e = depth_errors(rec.depth_mm, capture.depth_mm, capture.valid, fringe_depth_mm(calibration, rec.phase))
    assert e.order_errors == 0 and e.coverage > 0.95 and e.rmse_mm < 0.6, e
    depth, _ = DepthModel(default_model_path(), threads=2, calibration=calibration).infer(capture.images[-1])
    truth = np.where(capture.valid, capture.depth_mm, np.nan)
    given = np.isfinite(depth) & np.isfinite(truth)
    assert given.sum() / np.isfinite(truth).sum() > 0.92
    assert np.mean(np.abs(depth - truth)[given] > 1.0) < 0.002
    swapped = replace(poses[3], vertical=poses[4].vertical, horizontal=poses[4].horizontal)
    with pytest.raises(CalibrationError, match="pose pose 3: the calibrated projector puts its corners"):
        calibrate_from_board([*poses[:3], swapped, *poses[4:]], BOARD, rig.pattern_set())


def test_a_projector_above_the_camera_calibrates_from_a_board_and_measures():
    """A projector above the camera shows horizontal fringes, and the composite with them (its codes'
    rows along the columns; refused before 2026-12-05). Emulated exactly: the rig turned a quarter (camera
    480 x 640, projector 800 x 1280 with vertical fringes) and every image turned back, so its vertical
    fringes are the upright rig's horizontal ones. The board calibration reads the poses' two fringe sets
    as columns and rows whichever way the rig measures, and the model takes the carrier across the
    rows: the multi-shot path measures a scene it never saw to the board's depth scale, and the shipped
    network, shown the frames transposed (model.network_layout), gives a scene of separate objects 95.6%
    of its lit pixels, none off by more than 1 mm."""
    from fpp_nodes.core.model import DepthModel, default_model_path
    from fpp_nodes.core.patterns import PatternSet

    side = Rig(width=480, height=640, projector_width=800, projector_height=1280)

    def turned(images):  # a quarter turn clockwise: the turned rig's projector is then above its camera
        return np.ascontiguousarray(np.rot90(images, 3, axes=(-2, -1)))

    rng = np.random.default_rng(0)
    poses = []
    for i, (rotation, translation) in enumerate(board_poses(side, BOARD, 15, rng)):
        scene = board_scene(side, BOARD, rotation, translation)
        image, (columns, rows) = render_pose(side, scene, board_patterns(side.pattern_set()), rng)
        poses.append(BoardPose(f"pose {i}", turned(image), vertical=turned(rows), horizontal=turned(columns)))
    above = PatternSet(width=1280, height=800, orientation="horizontal", gamma=side.projector_gamma)
    calibration, report = calibrate_from_board(poses, BOARD, above, working_range_mm=(1100.0, 1300.0))
    assert max(p.projector_px for p in report.poses) <= 0.3 and report.model_fit_mm < 0.01
    baseline = report.translation_mm
    assert abs(np.linalg.norm(baseline) - side.baseline_mm) < 1.0 and abs(baseline[1]) > 0.95 * side.baseline_mm
    capture = render(side, make_scene(side, "objects", 5), side.pattern_set(), np.random.default_rng(5))
    truth = turned(np.where(capture.valid, capture.depth_mm, np.nan))
    rec = PspReconstructor(calibration)(turned(capture.images))
    e = depth_errors(rec.depth_mm, truth, np.isfinite(truth), fringe_depth_mm(calibration, rec.phase))
    assert e.order_errors == 0 and e.coverage > 0.95 and e.rmse_mm < 0.6, e
    model = DepthModel(default_model_path(), threads=2, calibration=calibration)
    assert model.layout.transposed
    depth, _ = model.infer(turned(capture.images[-1]))
    given = np.isfinite(depth) & np.isfinite(truth)
    assert given.sum() / np.isfinite(truth).sum() > 0.93
    assert np.mean(np.abs(depth - truth)[given] > 1.0) < 0.002


def test_a_projector_far_below_the_cameras_axis_decodes_from_a_board():
    """50 mm below the camera's axis, the projector's rows move by 49 px over the working range, and a
    turn of the coarse code holds 6 orders instead of 36: the decoder looked for a pixel's order in two
    of its turns and found none (every pixel NaN, with a range warning); it now looks in every turn the
    working range spans (CompositeDecoder.coarse_turns: 6 here, 2 on the default rig). From a board
    (the planes, 50 mm apart, cannot follow rows that move half a turn between them: the decoder says
    so), the shipped network gives a scene of separate objects 89.4% of its lit pixels, none off by
    more than 1 mm."""
    from fpp_nodes.core.model import DepthModel, default_model_path

    rig = Rig(projector_below_mm=50.0)
    rng = np.random.default_rng(0)
    poses = [pose(rig, r, t, rng, f"pose {i}") for i, (r, t) in enumerate(board_poses(rig, BOARD, 15, rng))]
    calibration, _ = calibrate_from_board(poses, BOARD, rig.pattern_set(), working_range_mm=(1100.0, 1300.0))
    model = DepthModel(default_model_path(), threads=2, calibration=calibration)
    assert model.decoder.coarse_turns == 6
    capture = render(rig, make_scene(rig, "objects", 5), rig.pattern_set(), np.random.default_rng(5))
    truth = np.where(capture.valid, capture.depth_mm, np.nan)
    depth, _ = model.infer(capture.images[-1])
    given = np.isfinite(depth) & np.isfinite(truth)
    assert given.sum() / np.isfinite(truth).sum() > 0.85
    assert np.mean(np.abs(depth - truth)[given] > 1.0) < 0.002
